"""3D Delaunay tetrahedralisation and circumcentres, the dual of the Voronoi diagram.

CGAL (exact orientation and in-sphere predicates, in the compiled ``voro3d._cgal``)
triangulates the points; everything after that is vectorised numpy. A VoroMesh's generators are
triangulated once per call (:func:`triangulate`) and the :class:`Triangulation` is handed to
every stage that needs it: cell labels, the point-cloud stray-cell pass, extraction.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .geometry import components

__all__ = ["DEFAULT_TOLERANCE", "Triangulation", "bounding_generators", "circumcenters", "delaunay_with_box",
           "triangulate"]

DEFAULT_TOLERANCE = 1e-7

_BOX_CORNERS = np.array(list(itertools.product((0.0, 1.0), repeat=3)))
# Bound on a floating-point circumcentre's error, relative to the points' extent, above which it
# is recomputed exactly: the test suite's clusters of generators 1e-6 apart have thin cells
# whose faces crossed when their vertices were 1e-11 off. About 1% of a fitted shape's
# tetrahedra exceed it, at 17 us each.
_MAX_ERROR = 1e-14


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


@dataclass(frozen=True)
class Triangulation:
    """The Delaunay tetrahedralisation of a VoroMesh's generators, snapped and merged.

    Attributes
    ----------
    points : (m + 8, 3) float64
        The ``m`` distinct generators (snapped, see :func:`triangulate`), then the eight corners of
        :func:`bounding_generators`.
    tets : (t, 4) int64
        Positively oriented tetrahedra indexing ``points``.
    cospherical : (p, 2) int64
        Face-adjacent tetrahedra with one circumsphere (one Voronoi vertex).
    site : (n,) int64
        The distinct generator (row of ``points``) each given generator became.
    tolerance : float
        The tolerance it was built with.
    """

    points: np.ndarray
    tets: np.ndarray
    cospherical: np.ndarray
    site: np.ndarray
    tolerance: float

    @property
    def n_sites(self) -> int:
        """Distinct generators (the box corners not counted)."""
        return self.points.shape[0] - 8

    def site_occupancy(self, occupancy: np.ndarray) -> np.ndarray:
        """(m + 8,) bool: a distinct generator is inside if any generator merged into it is; corners outside."""
        inside = np.zeros(self.points.shape[0], bool)
        inside[self.site[occupancy]] = True
        return inside


def triangulate(generators: np.ndarray, *, tolerance: float = DEFAULT_TOLERANCE) -> Triangulation:
    """Snap generators to a grid of spacing ~``tolerance``, merge those closer than it, triangulate.

    Snapping turns a lattice jittered below the tolerance back into an exact lattice, whose
    degeneracies the exact predicates resolve. What is left is either exactly degenerate or
    has features far above float64 rounding, so rounded Voronoi vertices cannot make thin
    neighbouring faces cross.

    Parameters
    ----------
    generators : (n, 3) float64
        Finite (checked by the caller).
    tolerance : float
        Relative to the generators' bounding-box diagonal, in [0, 0.01): the snapping grid's
        spacing (a power of two) and the distance under which generators are one.

    Returns
    -------
    Triangulation

    Raises
    ------
    ValueError
        Fewer than 4 distinct generators, or a tolerance out of range.
    """
    if not np.isfinite(tolerance) or not 0 <= tolerance < 1e-2:
        raise ValueError(f"tolerance must be in [0, 0.01), got {tolerance}")
    points = generators
    scale = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    quantum = None
    if scale > 0 and tolerance > 0:
        # A power of two, so the snapped coordinates are exact multiples of it.
        quantum = float(2.0 ** np.floor(np.log2(tolerance * scale)))
        points = np.round(points / quantum) * quantum
    # Pairs within the radius include exact duplicates (distance 0).
    pairs = cKDTree(points).query_pairs(tolerance * scale, output_type="ndarray")
    n = points.shape[0]
    label = np.arange(n)
    if pairs.size:
        label = components(n, pairs)[1]
    _, first, site = np.unique(label, return_index=True, return_inverse=True)
    if first.size < 4:
        raise ValueError(f"generators must hold at least 4 distinct points, got {first.size}")
    all_points, tets, cospherical = delaunay_with_box(points[first], quantum=quantum)
    return Triangulation(all_points, tets, cospherical, site.reshape(-1).astype(np.int64), float(tolerance))


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

    Computed relative to each tetrahedron's first vertex, which keeps the terms small. Where a
    forward error bound of that formula exceeds ``_MAX_ERROR`` of the points' extent (slivers,
    and tetrahedra with near-coincident corners such as generators 1e-6 apart), the
    circumcentre is recomputed with exact constructions and rounded.

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
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        offset = numerator / (2 * det[:, None])
        centres = a + offset
        # |error of offset| <= eps (S + 2 R P) / (2 |det|): P = |u||v||w| bounds the determinant's
        # terms, S = P (|u| + |v| + |w|) the numerator's (|u|^2 |v||w| and so on), R = |offset|.
        # Doubled for the terms it drops. Adding a rounds by eps |a| / 2, as rounding the exact
        # centre does: far from the origin (survey coordinates, 5e6 m for a 64 m object) that
        # alone passed the bound, and every tetrahedron went the exact way for nothing.
        lengths = np.sqrt(np.stack([uu, vv, ww], axis=1))
        products = lengths.prod(axis=1)
        spread = products * lengths.sum(axis=1)
        error = np.finfo(np.float64).eps * (spread + 2 * np.linalg.norm(offset, axis=1) * products) / np.abs(det)
        extent = float(np.ptp(points, axis=0).max()) if points.size else 0.0
        inexact = ~(error <= _MAX_ERROR * extent)
    if inexact.any():
        centres[inexact] = _cgal.exact_circumcenters(points, tets[inexact])
    return centres
