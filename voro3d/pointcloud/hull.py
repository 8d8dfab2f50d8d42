"""A closure cut back to the points' convex hull.

Where no point was seen, the target's solid is a guess: Poisson's smoothest closure, or the IMLS
solid held within ``SHELL_DEPTH`` of an open scan. Nothing any point bounds lies outside their
convex hull, yet such guesses swell past it: a hand whose fingers were seen from one side comes
back as a ball around them, the underside of a lid scanned from above as a slab below its rim.
Where a plan's ``hull`` is ``"on"`` the solid is cut back to the hull, a margin of
``HULL_MARGIN_NODES`` nodes of the target's grid out (a VoroMesh voxel), so that a scan the hull
leaves flat keeps a solid the grid resolves. The guess can be right, though: a cloud with a part cut
away loses the closure's continuation past the cut, so ``"auto"`` leaves it off. The measurement:
beside ``HULL_MARGIN_NODES`` in :mod:`voro3d.pointcloud.tuning`.
"""
from __future__ import annotations

import numpy as np

from .sightlines import CarvedSurface, carved_mesh
from .tuning import HULL_MARGIN_NODES

__all__ = ["ClippedSurface", "clip_to_hull"]

# Queries x planes tested at once: BLOCK x 256, 16 MB of float32.
BLOCK = 16384


class ClippedSurface(CarvedSurface):
    """A closed target without its solid more than ``margin`` outside a convex hull.

    As :class:`~voro3d.pointcloud.sightlines.CarvedSurface`, whose soup it samples from; but inside
    is decided at the query itself, not at the nearest node: a cell labelled inside at a point in a
    sliver of the base's solid past the cut, thinner than a node, would reach out as a spike.
    """

    def __init__(self, base, vertices, triangles, carved, cells, planes, margin: float):
        super().__init__(base, vertices, triangles, carved, why="cut back to the points' hull")
        self.cells, self.planes, self.margin = cells, planes, margin

    def inside(self, queries: np.ndarray) -> np.ndarray:
        """(q, 3) fit-frame points -> (q,) bool: inside the base target, within the margin of the hull."""
        queries = np.asarray(queries, np.float64)
        return self.base.inside(queries) & ~_beyond(queries, self.cells, self.planes, self.margin)


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
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    try:
        hull = ConvexHull(points)
        # Outside the hull or not, for many queries (its 10^3-10^4 planes are for the few outside).
        cells = Delaunay(points[hull.vertices])
    except QhullError:  # flat or degenerate: refused with the reason by the cloud's own checks
        return target
    size, node = resolution, 2.0 / (resolution - 1)
    margin = HULL_MARGIN_NODES * node
    vertices = target.project(target.vertices)
    if not np.any(_beyond(vertices, cells, hull.equations, margin)):
        # The solid's boundary is within the margin of the hull, so is the solid.
        return target
    # The solid outside the hull is bounded by the triangles that leave it and the hull's faces
    # between them: within the box of those triangles.
    outside = cells.find_simplex(vertices) < 0
    leaving = vertices[target.triangles[np.any(outside[target.triangles], axis=1)]]
    low = np.clip(np.floor((leaving.min(axis=(0, 1)) + 1.0) / node).astype(np.int64) - 1, 0, size - 1)
    high = np.clip(np.ceil((leaving.max(axis=(0, 1)) + 1.0) / node).astype(np.int64) + 2, 1, size)
    index = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(low, high)], indexing="ij"), axis=-1).reshape(-1, 3)
    index = index[cells.find_simplex(index * node - 1.0) < 0]
    index = index[target.inside(index * node - 1.0)]
    index = index[_height(index * node - 1.0, hull.equations) > margin]
    if not len(index):
        return target
    carved = np.zeros((size,) * 3, bool)
    carved[tuple(index.T)] = True
    # Triangles past the cut go too, with slivers of solid thinner than a node that no node marked.
    beyond = _beyond(vertices[target.triangles].mean(axis=1), cells, hull.equations, margin + node)
    return ClippedSurface(target, *carved_mesh(target.inside, vertices, target.triangles[~beyond], carved), carved,
                          cells, hull.equations, margin)


def _beyond(queries, cells, planes, margin: float) -> np.ndarray:
    """(q,) bool: each query more than ``margin`` outside the hull of the Delaunay ``cells`` and ``planes``."""
    beyond = np.zeros(len(queries), bool)
    outside = np.flatnonzero(cells.find_simplex(queries) < 0)
    beyond[outside] = _height(queries[outside], planes) > margin
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
