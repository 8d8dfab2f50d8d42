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
"""
from __future__ import annotations

import numpy as np

from .preprocess import stride
from .sightlines import CarvedSurface, carved_mesh
from .tuning import HULL_MARGIN_NODES

__all__ = ["ClippedSurface", "clip_to_hull", "reach_past_hull"]

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
