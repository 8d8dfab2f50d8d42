"""3D Delaunay tetrahedralisation and circumcentres, the dual of the Voronoi diagram.

CGAL (exact orientation and in-sphere predicates, in the compiled ``voro3d._cgal``)
triangulates the points; everything after that is vectorised numpy.
"""
from __future__ import annotations

import itertools

import numpy as np

__all__ = ["bounding_generators", "circumcenters", "delaunay_with_box"]

_BOX_CORNERS = np.array(list(itertools.product((0.0, 1.0), repeat=3)))
# Relative |det| below which a circumcentre is recomputed exactly (slivers).
_SLIVER_RATIO = 1e-3


def bounding_generators(points: np.ndarray, *, scale: float = 3.0) -> np.ndarray:
    """Eight box corners that hold every point strictly inside their convex hull.

    The half-size is a power of two and the centre is the midpoint of the bounding box, so the
    corners are exact and mirror-symmetric about it: a symmetric input (a lattice) stays
    exactly co-spherical with them instead of becoming nearly so.

    Parameters
    ----------
    points : (n, 3) float64
    scale : float
        Half-size of the box as a multiple (at least) of the points' largest half-extent.

    Returns
    -------
    (8, 3) float64
        Corners of an axis-aligned cube centred on the points' bounding box.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    extent = float((hi - lo).max()) / 2
    half = 2.0 ** np.ceil(np.log2(scale * extent)) if extent > 0 else 1.0
    return centre + (2 * _BOX_CORNERS - 1) * half


def delaunay_with_box(points: np.ndarray, *, quantum: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Delaunay tetrahedralisation of ``points`` plus eight bounding corners.

    CGAL computes it with exact predicates, so degenerate (co-spherical, co-planar) inputs
    still give a valid triangulation with no flat tetrahedra.

    Parameters
    ----------
    points : (n, 3) float64
        Distinct points.
    quantum : float, optional
        A power of two that every coordinate is a multiple of (snapped points): the
        triangulation then runs on exact integers.

    Returns
    -------
    all_points : (n + 8, 3) float64
        ``points`` followed by the corners of :func:`bounding_generators`.
    tets : (m, 4) int64
        Positively oriented tetrahedra (``det[b-a, c-a, d-a] > 0``) indexing ``all_points``.
    cospherical : (p, 2) int64
        Pairs of face-adjacent tetrahedra whose circumspheres coincide exactly (decided with
        exact predicates): they share one Voronoi vertex.
    """
    from . import _cgal

    all_points = np.ascontiguousarray(np.vstack([points, bounding_generators(points)]), dtype=np.float64)
    tets, cospherical = _cgal.delaunay_tetrahedra(_integer_frame(all_points, quantum))
    return all_points, tets, cospherical


def _integer_frame(points: np.ndarray, quantum: float | None) -> np.ndarray:
    """Points on a grid of spacing ``quantum`` (a power of two), as exact small integers.

    Delaunay is invariant under translation and scaling, both exact here, and CGAL's exact
    fallback (taken at every degenerate predicate, all over a lattice) is about twice as
    fast on small integers.
    """
    if quantum is None:
        return points
    origin = np.round(points.min(axis=0) / quantum) * quantum
    scaled = (points - origin) / quantum
    return scaled if np.array_equal(scaled, np.round(scaled)) else points


def circumcenters(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Circumcentres of tetrahedra (the Voronoi vertices).

    Computed relative to each tetrahedron's first vertex, which keeps the terms small;
    slivers (near-zero volume relative to their edge lengths), whose circumcentre is
    ill-conditioned, are recomputed with exact constructions and rounded.

    Parameters
    ----------
    points : (n, 3) float64
    tets : (m, 4) int

    Returns
    -------
    (m, 3) float64
    """
    from . import _cgal

    a = points[tets[:, 0]]
    u, v, w = (points[tets[:, i]] - a for i in (1, 2, 3))
    vw, wu, uv = np.cross(v, w), np.cross(w, u), np.cross(u, v)
    det = np.einsum("ij,ij->i", u, vw)
    uu, vv, ww = (np.einsum("ij,ij->i", x, x) for x in (u, v, w))
    numerator = uu[:, None] * vw + vv[:, None] * wu + ww[:, None] * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        centres = a + numerator / (2 * det[:, None])
        sliver = ~(np.abs(det) >= _SLIVER_RATIO * np.sqrt(uu * vv * ww))
    if sliver.any():
        centres[sliver] = _cgal.exact_circumcenters(points, tets[sliver])
    return centres
