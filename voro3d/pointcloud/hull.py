"""A closure cut back to the points' convex hull.

Where no point was seen, the target's solid is a guess: Poisson's smoothest closure, or the IMLS
solid held within the shell depth of an open scan. Nothing any point bounds lies outside their
convex hull, yet such guesses swell past it: a hand whose fingers were seen from one side comes
back as a ball around them, the underside of a lid scanned from above as a slab below its rim.
Where a plan's ``hull`` is ``"on"`` the solid is cut back to the hull, a margin of
``HULL_MARGIN_NODES`` nodes of the target's grid out (a VoroMesh voxel), so that a scan the hull
leaves flat keeps a solid the grid resolves. ``"auto"`` cuts an open cloud's (a one-sided scan's
solid is a guess behind what was seen), whose solid the hull then bounds in place of the shell
depth, and leaves a closed cloud's: there the guess can be right, a cloud with a part cut away
losing the closure's continuation past the cut. The measurements: beside ``HULL_MARGIN_NODES`` and
``SHELL_DEPTH`` in :mod:`voro3d.pointcloud.tuning`.

A one-sided scan whose rim is a crop, not a silhouette (:func:`rim_facing`: a terrain, a facade, a
plate seen face on), is held by its hull and within ``THINNEST_SHELL_NODES`` of its points: nothing
says which side of it a body lies on, and the hull alone fills a valley up to its rim, a flat
outline out to its convex polygon.
"""
from __future__ import annotations

import numpy as np

from .preprocess import stride
from .sightlines import CarvedSurface, carved_mesh
from .tuning import HULL_MARGIN_NODES

__all__ = ["ClippedSurface", "clip_to_hull", "cropped_rim", "reach_past_hull", "rim_facing"]

# Neighbours a point's rim test reads (rim_facing), and the widest gap between them, seen round its normal, inside a
# surface (radians): 24 neighbours drawn at random leave 150 degrees empty about once in 10^4 points (16 leave 120
# degrees once in 28: on a cap of a sphere, more points inside than on its rim read as rim), a point half a spacing in
# from an edge about 160.
RIM_NEIGHBOURS = 24
RIM_GAP = 5.0 * np.pi / 6.0
# Points whose rim test is read, at most (evenly): on 300k-point one-view scans (bunny, fandisk, abc_00000005) 20k
# read within 0.03 of 100k's, in 0.1-0.3 s instead of 0.7-1.2 s (2026-12-08, a loaded machine).
RIM_SAMPLE = 20_000
# An open cloud whose rim_facing is over this is a crop: its solid held THINNEST_SHELL_NODES deep behind its points, not
# by its hull alone. Read (2026-12-08, no normals): one-view scans of the 12 benchmark meshes 0.57-0.71 (0.3% depth
# noise 0.54-0.68, 300k points 0.46-0.62), objects on a table (bench_scenes) 0.57-0.72, containers.py's from one view
# 0.44-0.78, hippo2 0.79; terrain.py's hill, valley, saddle and map 0.87-1.00 (0.87-0.94 at 0.25% noise), poste_france
# 0.92. A LiDAR's lines read as rims throughout (0.16-0.96). Noise as deep as the spacing turns the plane fits every
# way: the terrains at 0.5% / 1% noise read 0.63-0.67 / 0.48-0.53 (at 0.5% all four take the shell around the points,
# SHEET_POINTS_GATE, CD 7.8-10.6; at 1% two the shell, the map Poisson, the saddle the hull, CD 17.8-51.9). Read on the
# IMLS gradients after the smoothing: 0.57-0.89 / 0.43-0.45, the rims curled; on normals averaged over the neighbours
# the card from one view reads 0.92. Off (inf) against 0.85, grid 64, one run each: 48 dev clouds (the 12 meshes from 1
# view, 1 view with 0.3% noise, 1 LiDAR position, 3 views), 28 of containers.py (1, 3, 6 views, clean 5k), 24 table
# scenes (1, 3 views) and hippo2, point_set_3, radar: no change (at 0.82 abc_00000005 from 1 LiDAR position turns a crop
# and loses, CD 4944 -> 6983); terrain.py's 16 clouds (clean 5k / 20k, 0.25% noise, 1 view) CD / NC / F1 275.1 / 0.961 /
# 0.553 -> 48.3 / 0.975 / 0.594 (the valley at 5k 463.5 -> 44.1: its hull filled it to its rim, a lid seen from above; 1
# view NC 0.960 -> 0.956, the scan's occlusion gaps now holes through the shell), poste_france its outline, not its
# hull's (kept points' distance 2.28e-6 -> 1.74e-5, Poisson 3.25e-5). Rerun: bench_pointcloud.py or bench_scenes.py
# --rim-crop inf. The thin shell's limit closed by 12 field nodes (its gaps filled, a smooth dimple): the valley from
# one view NC 0.966 -> 0.974 but CD 50.2 -> 51.4, the clean terrains CD +4-15%: not kept. Nor a thinner shell
# (tuning.THINNEST_SHELL_NODES 4 -> 3 nodes on the 16 clouds, 2026-12-08): CD 48.3 -> 33.1, F1 0.594 -> 0.608, but NC
# 0.975 -> 0.966, the hill at 5k pitted with scales across its top (rendered; NC 0.980 -> 0.960); at 2 nodes the 5k
# clouds fall apart (one piece 1 of 4, NC 0.658). F1 stays: any back face a VoroMesh voxel holds lies over 0.003 off.
RIM_CROP = 0.85
# Queries x planes tested at once: BLOCK x 256, 16 MB of float32.
BLOCK = 16384
# Target vertices read for reach_past_hull, at most (evenly).
REACH_VERTICES = 20_000


class ClippedSurface(CarvedSurface):
    """A closed target without its solid more than ``margin`` outside a convex hull.

    As :class:`~voro3d.pointcloud.sightlines.CarvedSurface`, whose soup it samples from; but inside
    is decided at the query itself, not at the nearest node: a cell labelled inside at a point in a
    sliver of the base's solid past the cut, thinner than a node, would reach out as a spike.
    """

    def __init__(self, base, vertices, triangles, carved, scene, planes, margin: float):
        super().__init__(base, vertices, triangles, carved, why="cut back to the points' hull")
        self.scene, self.planes, self.margin = scene, planes, margin

    def inside(self, queries: np.ndarray) -> np.ndarray:
        """(q, 3) fit-frame points -> (q,) bool: inside the base target, within the margin of the hull."""
        queries = np.asarray(queries, np.float64)
        return self.base.inside(queries) & ~_beyond(queries, self.scene, self.planes, self.margin)


def clip_to_hull(target, points, resolution: int):
    """``target``, or a :class:`~voro3d.pointcloud.sightlines.CarvedSurface` of it without its solid
    more than ``HULL_MARGIN_NODES`` nodes of a grid outside the convex hull of ``points``.

    Parameters
    ----------
    target
        Closed target surface (fit frame): ``vertices``, ``triangles``, ``inside``, ``project``.
    points : (n, 3) float64
        Fit frame.
    resolution : int
        Nodes per side of the grid over ``[-1, 1]^3`` the cut is made on.
    """
    found = _hull(points)
    if found is None:  # flat or degenerate: refused with the reason by the cloud's own checks
        return target
    hull, scene = found
    size, node, margin = resolution, 2.0 / (resolution - 1), _margin(resolution)
    vertices = target.project(target.vertices)
    outside = _outside(scene, vertices)
    if not np.any(_height_within(vertices[outside], scene, hull.equations, margin, margin) > margin):
        # The solid's boundary is within the margin of the hull, so is the solid.
        return target
    # The solid outside the hull is bounded by the triangles that leave it and the hull's faces
    # between them: within the box of those triangles.
    leaving = vertices[target.triangles[np.any(outside[target.triangles], axis=1)]]
    low = np.clip(np.floor((leaving.min(axis=(0, 1)) + 1.0) / node).astype(np.int64) - 1, 0, size - 1)
    high = np.clip(np.ceil((leaving.max(axis=(0, 1)) + 1.0) / node).astype(np.int64) + 2, 1, size)
    index = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(low, high)], indexing="ij"), axis=-1).reshape(-1, 3)
    nodes = index * node - 1.0
    keep = _outside(scene, nodes)
    keep[keep] = target.inside(nodes[keep])
    heights = np.full((size,) * 3, np.nan, np.float32)

    def past(queries):
        # Signed distance past the cut, bounded (exact within a node of it); read once per node: the
        # mesh of the cut reads the nodes the carve read (poste_france: 0.9 of 1.0 million again).
        index = np.rint((queries + 1.0) / node).astype(np.int64)
        value = heights[tuple(index.T)]
        unknown = np.isnan(value)
        value[unknown] = _height_within(queries[unknown], scene, hull.equations, margin - node, margin + node)
        heights[tuple(index[unknown].T)] = value[unknown]
        return value - margin

    keep[keep] = past(nodes[keep]) > 0
    if not keep.any():
        return target
    index = index[keep]
    carved = np.zeros((size,) * 3, bool)
    carved[tuple(index.T)] = True
    # Triangles past the cut go too, with slivers of solid thinner than a node that no node marked.
    beyond = _beyond(vertices[target.triangles].mean(axis=1), scene, hull.equations, margin + node)
    mesh = carved_mesh(target.inside, vertices, target.triangles[~beyond], carved, past=past)
    return ClippedSurface(target, *mesh, carved, scene, hull.equations, margin)


def reach_past_hull(target, points, resolution: int) -> float:
    """How far ``target``'s vertices (every k-th, at most ``REACH_VERTICES``) reach past the convex hull
    of ``points``, fit frame, where :func:`clip_to_hull` at ``resolution`` would cut (further than its
    margin); else 0, and for a flat or degenerate cloud. For the report of a run that did not ask for the cut."""
    found = _hull(points)
    if found is None:
        return 0.0
    hull, scene = found
    vertices = target.vertices[::stride(len(target.vertices), REACH_VERTICES)]
    reach = float(_height(vertices[_outside(scene, vertices)], hull.equations).max(initial=0.0))
    return reach if reach > _margin(resolution) else 0.0


def _margin(resolution: int) -> float:
    """``HULL_MARGIN_NODES`` nodes of a grid of ``resolution`` nodes a side over ``[-1, 1]^3``."""
    return HULL_MARGIN_NODES * 2.0 / (resolution - 1)


def _hull(points):
    """``(hull, scene)``: the qhull convex hull of ``points`` and a ray-casting scene of its triangles
    (outside or not, for many queries: the hull's 10^3-10^5 planes are for the few outside; Delaunay
    cells of its vertices took 50 s for 12,000 points of a sphere, all on the hull), or None for a
    flat or degenerate cloud."""
    import open3d as o3d
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except QhullError:
        return None
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(points.astype(np.float32)), o3d.core.Tensor(hull.simplices.astype(np.uint32)))
    return hull, scene


def _outside(scene, queries) -> np.ndarray:
    """(q,) bool: each query outside the closed surface of ``scene``."""
    import open3d as o3d

    return scene.compute_occupancy(o3d.core.Tensor(np.asarray(queries, np.float32))).numpy() < 0.5


def _beyond(queries, scene, planes, margin: float) -> np.ndarray:
    """(q,) bool: each query more than ``margin`` outside the hull (``scene``, its ``planes``)."""
    beyond = np.zeros(len(queries), bool)
    outside = np.flatnonzero(_outside(scene, queries))
    beyond[outside] = _height_within(queries[outside], scene, planes, 0.5 * margin, 1.5 * margin) > margin
    return beyond


def _height(queries, planes) -> np.ndarray:
    """(q,) float32: how far each query lies outside the polytope of the ``planes`` (outward unit
    normals and offsets, as qhull's), along the normal of the face it is furthest out of; negative inside."""
    normals, offsets = planes[:, :3].T.astype(np.float32), planes[:, 3].astype(np.float32)
    queries = np.asarray(queries, np.float32)
    height = np.empty(len(queries), np.float32)
    block = max(1, BLOCK * 256 // len(planes))
    for start in range(0, len(queries), block):
        height[start:start + block] = (queries[start:start + block] @ normals + offsets).max(axis=1)
    return height


def _height_within(queries, scene, planes, low: float, high: float) -> np.ndarray:
    """(q,) float32: :func:`_height` where it lies within ``[low, high]``, exactly; elsewhere a value
    beyond the bound it passes (``low - 1`` or ``high + 1``). Without testing every query against every
    plane (a noisy flat scan is all hull: 9,000 points, 18,000 planes): the plane of the nearest face
    bounds the height from below and the distance to the hull from above (inside, both are the height);
    only queries whose bounds straddle the range are tested against all."""
    import open3d as o3d

    queries = np.asarray(queries, np.float32)
    height = np.empty(len(queries), np.float32)
    if len(queries) == 0:
        return height
    closest = scene.compute_closest_points(o3d.core.Tensor(queries))
    face = planes[closest["primitive_ids"].numpy().astype(np.int64)]
    # A hair of slack each way: the bounds and the exact sum round differently in float32.
    slack = 1e-5 * max(1.0, abs(low), abs(high))
    lower = np.einsum("ij,ij->i", queries, face[:, :3]) + face[:, 3]
    distance = np.where(_outside(scene, queries), np.linalg.norm(closest["points"].numpy() - queries, axis=1), lower)
    above, below = lower - slack >= high, distance + slack <= low
    height[above], height[below] = high + 1.0, low - 1.0
    unsure = ~(above | below)
    height[unsure] = _height(queries[unsure], planes)
    return height


def rim_facing(points: np.ndarray, normals: np.ndarray, *, tree=None) -> float:
    """How far the rim of a one-sided scan faces the way the scan does: the mean of ``|n . m|``
    over its rim points, ``m`` the points' mean normal.

    Where a scan's view of a surface ended because the surface turned away from the sensor (an
    object's silhouette; grazing hits are not kept) its rim faces across the view; where the surface
    just stops (a terrain's or a facade's crop, a plate seen face on), along it: one-view scans of
    objects read 0.44-0.78, terrains and a flat map 0.87-1.00 (``RIM_CROP``'s measurement).
    A rim point's ``RIM_NEIGHBOURS`` nearest neighbours, seen round its normal, leave over ``RIM_GAP``
    of the circle empty; ``RIM_SAMPLE`` points, evenly, are read.

    Parameters
    ----------
    points, normals : (n, 3) float64
        Fit frame; unit normals, signs consistent between neighbours.
    tree : scipy.spatial.cKDTree, optional
        Of ``points``.

    Returns
    -------
    float
        In [0, 1]; 0 with no rim.
    """
    from scipy.spatial import cKDTree

    mean = normals.mean(axis=0)
    if len(points) <= RIM_NEIGHBOURS or not np.linalg.norm(mean) > 0.0:
        return 0.0
    every = slice(None, None, stride(len(points), RIM_SAMPLE))
    tree = cKDTree(points) if tree is None else tree
    neighbours = tree.query(points[every], RIM_NEIGHBOURS + 1, workers=-1)[1][:, 1:]
    points, normals = points[every], normals[every]
    across = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(normals, across)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(normals, first)
    offsets = tree.data[neighbours] - points[:, None]
    turn = np.sort(np.arctan2(np.einsum("ikj,ij->ik", offsets, second), np.einsum("ikj,ij->ik", offsets, first)), axis=1)
    rim = np.diff(np.c_[turn, turn[:, :1] + 2.0 * np.pi], axis=1).max(axis=1) > RIM_GAP
    if not rim.any():
        return 0.0
    return float(np.mean(np.abs(normals[rim] @ (mean / np.linalg.norm(mean)))))


def cropped_rim(points: np.ndarray, normals: np.ndarray, *, tree=None) -> bool:
    """Whether a one-sided scan's rim is a crop (:func:`rim_facing` over ``RIM_CROP``), not a silhouette."""
    return rim_facing(points, normals, tree=tree) > RIM_CROP
