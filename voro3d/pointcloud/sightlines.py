"""Lines of sight: a closed target must leave every point a line along which it was seen.

A scanner sees a point along a line that crosses no surface. Poisson closes what no view saw with
the smoothest surface it can, and where that is the mouth of a container whose inside was partly
seen (a cup scanned from six directions: its outside, rim and one side of its inner wall, not the
mouth), the closure fills the cavity and buries the inner wall it saw: no line leaves those points
without crossing the target. Clouds come without their viewpoints, but a point is seen from within
``SIGHT_ANGLE`` of its normal. A point every line of whose cone meets the target is *hidden*; a
line of it that crosses only surface no point lies near (``SIGHT_GAP`` spacings off: a closure) is
a line it may have been seen along, and the target's solid along it is carved away. Where every
line is blocked by surface the points hold (a crease between two seen parts), nothing is carved; nor
where the carve would part the solid into pieces the points support, which the closure joined (a
mushroom's cap from its stem, under the gills no view saw): the lines say what was seen through, not
where an object holds together.

How many points are hidden with such a line, on which dev clouds it carves and what that does
(including where points were sampled rather than seen, and the carve is wrong): beside
``MIN_REVEALING`` in :mod:`voro3d.pointcloud.tuning`.
"""
from __future__ import annotations

import numpy as np

from .preprocess import stride
from .tuning import MIN_REVEALING, SIGHT_ANGLE, SIGHT_GAP, SIGHT_LINES, SIGHT_POINTS

__all__ = ["CarvedSurface", "carve_sightlines", "carved_mesh", "sight_directions"]

# Crossings followed along a line before it counts as blocked (a line through a closure leaves it
# after one or two).
MAX_CROSSINGS = 4
# Every PROBE-th line of a cone is cast first (carve_sightlines).
PROBE = 8


class CarvedSurface:
    """A closed target with the space its points were seen through carved out.

    Attributes
    ----------
    vertices, triangles : (v, 3) float64, (t, 3) int64
        The base target's triangles outside the carved space, and the boundary of the carved space
        inside the base's solid (Marching Cubes at the carve grid): a soup that is only sampled,
        measured against and snapped to; :meth:`inside` decides inside.
    resolution : int
        The base target's.
    carved : (r, r, r) bool
        Carved nodes of a grid over ``[-1, 1]^3``.
    why : str
        What was carved, for the plan's report: ``"carved where it hid points"`` here.
    """

    def __init__(self, base, vertices, triangles, carved, *, why: str = "carved where it hid points"):
        from ..queries import InsideOutside

        self.base, self.vertices, self.triangles, self.carved, self.why = base, vertices, triangles, carved, why
        self.resolution, self.dense = base.resolution, base.dense
        self._query = InsideOutside((vertices, triangles), allow_open=True)

    def inside(self, queries: np.ndarray) -> np.ndarray:
        """(q, 3) fit-frame points -> (q,) bool: inside the base target, not at a carved node (the nearest)."""
        queries = np.asarray(queries, np.float64)
        return self.base.inside(queries) & ~_at(self.carved, queries)

    def distance(self, queries: np.ndarray) -> np.ndarray:
        return self._query.unsigned_distance(queries)

    @property
    def carves(self) -> list:
        """What was carved, this carve's base's first."""
        return getattr(self.base, "carves", []) + [self.why]

    def project(self, queries: np.ndarray) -> np.ndarray:
        """Its vertices are on the surface already (the base's were projected before the carve)."""
        return np.asarray(queries, np.float64)


def sight_directions(count: int, half_angle: float) -> np.ndarray:
    """(count, 3) unit directions spread evenly (a Fibonacci spiral) over the cone of ``half_angle``
    degrees about +z."""
    k = np.arange(count) + 0.5
    cos = 1.0 - k / count * (1.0 - np.cos(np.radians(half_angle)))
    angle = np.pi * (3.0 - np.sqrt(5.0)) * k
    sin = np.sqrt(1.0 - cos**2)
    return np.c_[sin * np.cos(angle), sin * np.sin(angle), cos]


def carve_sightlines(target, points, normals, spacing: float, resolution: int):
    """``(surface, why)``: ``target``, or a :class:`CarvedSurface` of it where it hides points it
    should not; ``why`` says, for the plan's report, where a carve was left out because it would
    part the solid (empty otherwise).

    Parameters
    ----------
    target : PoissonSurface
        Closed, fit frame; the lines are cast into its ``scene``.
    points, normals : (n, 3) float64
        Fit frame, unit outward normals; every k-th point, at most ``SIGHT_POINTS``, is tested.
    spacing : float
        Median point spacing, fit frame.
    resolution : int
        Nodes per side of the carve grid over ``[-1, 1]^3``.
    """
    from scipy.spatial import cKDTree

    step = stride(len(points), SIGHT_POINTS)
    tested, axes = points[::step], normals[::step]
    starts = tested + spacing * axes
    scene = target.scene
    cone = sight_directions(SIGHT_LINES, SIGHT_ANGLE)
    # Every PROBE-th line first: a point that one of them leaves free is not hidden (the same
    # outcome, at a fraction of the lines for a target that hides nothing); the others' lines are
    # made for the points it leaves (a complete cloud of 10^5 points: 0.26 -> 0.03 s).
    candidate = _meets(scene, *_lines(starts, axes, cone[::PROBE])).reshape(len(tested), -1).all(axis=1)
    if np.count_nonzero(candidate) < MIN_REVEALING * len(tested):
        return target, ""
    tree = cKDTree(points)
    origins, directions = _lines(starts[candidate], axes[candidate], cone)
    blocked, possible, length = _crossings(scene, origins, directions, tree, SIGHT_GAP * spacing)
    hidden = blocked.reshape(-1, SIGHT_LINES).all(axis=1)
    revealing = possible & np.repeat(hidden, SIGHT_LINES)
    if np.count_nonzero(revealing.reshape(-1, SIGHT_LINES).any(axis=1)) < MIN_REVEALING * len(tested):
        return target, ""
    # The target's inside at the carve grid's nodes, read once for the carve, the parting test and the mesh.
    solid = _solid(target, resolution)
    carved = _carve_grid(target, solid, origins[revealing], directions[revealing], length[revealing], points, normals,
                         tree, SIGHT_GAP * spacing, resolution)
    if not carved.any():
        return target, ""
    # Of the 13 carves over range scans of the 38 dev meshes from 1 / 3 / 6 views and with a third
    # missing (grid 64, no normals, 2026-12-06), two would part the solid, both of thingi32_53159
    # (mushrooms); left uncarved, from 3 views CD 52.5 -> 49.1, NC 0.840 -> 0.905, F1 0.520 -> 0.585,
    # two pieces -> one; a third missing 234 -> 145, 0.862 -> 0.884, 0.531 -> 0.677, one piece either
    # way (the IMLS target instead: 12.7 and 366, two pieces). Scenes, thin walls, real scans: no carve.
    if _parted(solid, carved, points):
        return target, "not carved where it hid points, as that would part it"
    # carved_mesh reads the inside at nodes of the same grid.
    surface = CarvedSurface(target, *carved_mesh(lambda queries: _at(solid, queries), target.vertices, target.triangles,
                                                 carved), carved)
    return surface, ""


def _solid(target, resolution: int) -> np.ndarray:
    """(r, r, r) bool: ``target.inside`` at the nodes of a grid over ``[-1, 1]^3``; outside its box: outside."""
    from ..sampling import grid_nodes

    nodes = grid_nodes(resolution)
    box = np.all((nodes >= target.vertices.min(axis=0)) & (nodes <= target.vertices.max(axis=0)), axis=1)
    solid = np.zeros(len(nodes), bool)
    solid[box] = target.inside(nodes[box])
    return solid.reshape((resolution,) * 3)


def _parted(solid, carved, points) -> bool:
    """Whether taking the ``carved`` nodes out of a ``solid`` on the same grid leaves it in more
    pieces that the points support (:func:`~voro3d.pointcloud.fields.supported_regions`)."""
    from .fields import supported_regions

    return bool(supported_regions(solid & ~carved, points)[1].sum() > supported_regions(solid, points)[1].sum())


def _lines(origins, axes, cone):
    """(n * c, 3) origins and directions: the (c, 3) ``cone`` (:func:`sight_directions`) about each point's normal."""
    helper = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(axes, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(axes, first)
    directions = (cone[None, :, :1] * first[:, None] + cone[None, :, 1:2] * second[:, None]
                  + cone[None, :, 2:] * axes[:, None]).reshape(-1, 3)
    return np.repeat(origins, len(cone), axis=0), directions


def _meets(scene, origins, directions) -> np.ndarray:
    """(m,) bool: the line from each origin along its direction meets the surface of ``scene``."""
    import open3d as o3d

    rays = np.hstack([origins, directions]).astype(np.float32)
    return np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())


def _crossings(scene, origins, directions, tree, gap: float):
    """Each line's ``(blocked, possible, length)``: it meets the target (``scene``); it crosses only
    surface more than ``gap`` from every point and leaves within ``MAX_CROSSINGS``; how far to its last
    crossing."""
    import open3d as o3d

    m = len(origins)
    blocked, possible = np.zeros(m, bool), np.ones(m, bool)
    length = np.zeros(m)
    active = np.arange(m)
    for crossing in range(MAX_CROSSINGS + 1):
        start = origins[active] + (length[active] + 1e-6)[:, None] * directions[active]
        rays = np.hstack([start, directions[active]]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
        met = np.isfinite(hit)
        if crossing == 0:
            blocked[active] = met
        if crossing == MAX_CROSSINGS:
            possible[active[met]] = False  # still crossing: counted as blocked
            break
        active, hit = active[met], hit[met]
        length[active] += hit + 1e-6
        near = tree.query(origins[active] + length[active, None] * directions[active], workers=-1)[0] <= gap
        possible[active[near]] = False
        active = active[~near]
        if not active.size:
            break
    return blocked, possible & blocked, length


def _carve_grid(target, solid, origins, directions, length, points, normals, tree, radius: float, resolution: int):
    """(r, r, r) bool: the target's ``solid`` (:func:`_solid`) that a ball of ``radius`` reaches from
    outside without touching a point (as an alpha wrap carves), in the pieces the lines pass through
    to their last crossing; less the nodes behind a point (against its normal) within two nodes of
    it, the wall under the points."""
    from scipy import ndimage

    from ..sampling import grid_nodes

    node = 2.0 / (resolution - 1)
    counts = np.ceil((length + node) / (0.5 * node)).astype(np.int64)
    line = np.repeat(np.arange(len(origins)), counts)
    along = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)) * (0.5 * node)
    index = np.rint((origins[line] + along[:, None] * directions[line] + 1.0) / node).astype(np.int64)
    index = index[np.all((index >= 0) & (index < resolution), axis=1)]
    seen = np.zeros((resolution,) * 3, bool)
    seen[tuple(index.T)] = True
    nodes = grid_nodes(resolution)
    free = np.isinf(tree.query(nodes, distance_upper_bound=radius, workers=-1)[0]).reshape(seen.shape)
    piece, _ = ndimage.label(free)
    edge = np.unique(np.concatenate([np.take(piece, [0, -1], axis=a).ravel() for a in range(3)]))
    outside = _among(piece, edge)
    reach = ndimage.distance_transform_edt(~outside) * node <= radius
    low, high = target.vertices.min(axis=0), target.vertices.max(axis=0)
    reach &= np.all((nodes >= low) & (nodes <= high), axis=1).reshape(reach.shape)  # outside its box: outside
    solid = solid & reach
    piece, _ = ndimage.label(solid | (seen & reach))
    carved = _among(piece, np.unique(piece[seen])) & solid
    where = np.argwhere(carved)
    position = where * node - 1.0
    # Bounded: the carve reaches deep into the solid, where an exact nearest point is slow to find
    # (0.9 of 2.2 s on a 3-view scan of thingi32_72960) and not needed.
    distance, nearest = tree.query(position, distance_upper_bound=2.0 * node, workers=-1)
    near = np.flatnonzero(distance < 2.0 * node)
    behind = np.einsum("ij,ij->i", position[near] - points[nearest[near]], normals[nearest[near]]) < 0
    carved[tuple(where[near[behind]].T)] = False
    return carved


def carved_mesh(inside, vertices, triangles, carved, *, past=None):
    """The triangles of a target with the ``carved`` nodes (a grid over ``[-1, 1]^3``) taken out of
    its solid: its own (``vertices``, ``triangles``) away from the carved nodes, and the Marching Cubes
    boundary of the carved space inside its solid (the ``inside`` test), near the carve only.

    ``past``, where the carve is a smooth cut: (q, 3) fit-frame points -> (q,) signed distance past
    it (fit frame, positive where carved), read near the carve so that the cut is meshed where it
    lies, not as the staircase of the carved nodes."""
    from scipy import ndimage

    from .fields import _marching_cubes
    from .poisson import _reindexed

    size = carved.shape[0]
    node = 2.0 / (size - 1)
    grown = ndimage.binary_dilation(carved, iterations=2)
    low = np.maximum(np.argwhere(grown).min(axis=0) - 1, 0)
    high = np.minimum(np.argwhere(grown).max(axis=0) + 2, size)
    box = tuple(slice(a, b) for a, b in zip(low, high))
    axes = [np.arange(a, b) * node - 1.0 for a, b in zip(low, high)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if past is None:
        solid = inside(nodes).reshape(grown[box].shape) & ~carved[box]
        field = ndimage.gaussian_filter(np.where(solid, -1.0, 1.0), 0.7)
    else:
        field = ndimage.gaussian_filter(np.where(inside(nodes).reshape(grown[box].shape), -1.0, 1.0), 0.7)
        # Further than the grown carve the cut is at least two nodes away: its field saturates.
        cut = np.full(field.shape, -1.0)
        cut[grown[box]] = np.clip(past(nodes[grown[box].ravel()]) / node, -1.0, 1.0)
        field = np.maximum(field, cut)
    field = np.pad(field, 1, constant_values=1.0)  # closed at the sub-grid's faces
    cut_vertices, cut_triangles = _marching_cubes(field)
    cut_vertices = (cut_vertices - 1.0 + low) * node - 1.0
    near = ndimage.binary_dilation(carved)
    new = cut_triangles[_at(near, cut_vertices[cut_triangles].mean(axis=1))]
    old = triangles[~_at(near, vertices[triangles].mean(axis=1))]
    triangles = np.vstack([old, new + len(vertices)])
    vertices = np.vstack([vertices, cut_vertices])
    used = np.zeros(len(vertices), bool)
    used[triangles] = True
    return _reindexed(vertices, triangles, used)


def _among(labels, chosen) -> np.ndarray:
    """``labels`` (an ndimage.label array) in ``chosen``, background (0) never."""
    table = np.zeros(labels.max() + 1, bool)
    table[chosen] = True
    table[0] = False
    return table[labels]


def _at(mask, queries) -> np.ndarray:
    """(q,) bool: ``mask`` (a grid over ``[-1, 1]^3``) at the nearest node of each (q, 3) fit-frame
    point (False outside)."""
    size = mask.shape[0]
    index = np.rint((queries + 1.0) / (2.0 / (size - 1))).astype(np.int64)
    within = np.all((index >= 0) & (index < size), axis=1)
    out = np.zeros(len(index), bool)
    out[within] = mask[tuple(index[within].T)]
    return out
