"""VoroMesh extraction: Voronoi faces between inside and outside generators, as a mesh.

The faces come from the dual of the Delaunay tetrahedralisation: every Delaunay edge (i, j)
whose ends differ in occupancy is a Voronoi polygon whose corners are the circumcentres of the
tetrahedra around that edge. All of it is vectorised over tetrahedra and edges. Extraction only extracts: cleaning
(:mod:`voro3d.cleaning`) and fitting to a surface (:mod:`voro3d.snapping`) are later stages,
which :meth:`voro3d.VoroMesh.to_open3d` runs in turn.

How extraction works, and its guarantees
----------------------------------------
1. Generators are snapped to a grid of spacing about ``tolerance`` (1e-7 of the bounding-box
   diagonal; float32 precision is 6e-8) and generators closer than that become one (inside if
   any of them is). Eight far box corners are added as outside generators, so every inside cell
   is bounded.
2. CGAL builds the 3D Delaunay tetrahedralisation with exact predicates (``src/voro3d_cgal.cpp``);
   it also reports which face-adjacent tetrahedra are exactly co-spherical.
3. Every Delaunay edge between an inside and an outside generator is a Voronoi polygon whose
   corners are the circumcentres of the tetrahedra around the edge. The ring order comes from
   the tetrahedra's orientation (no angles, no loops over cells): vectorised numpy.
   Polygons are fan-triangulated, normals point from the inside generator to the outside one.
4. Tetrahedra with one circumsphere (exactly, by CGAL's predicate) are one Voronoi vertex;
   triangles that collapse are dropped. No distance tolerance decides what merges.
5. Where inside cells meet only at an edge or a corner the solid is non-manifold: the shared
   vertices are duplicated, so the output is a manifold whose sheets touch there.
6. Circumcentres are computed relative to a tetrahedron corner in float64; where a forward error
   bound of that formula exceeds 1e-14 of the extent (slivers, and tetrahedra with corners 1e-6
   apart, whose thin cells' faces crossed when their vertices were 1e-11 off) they are recomputed
   with CGAL's exact constructions and rounded (about 1% of a fitted shape's tetrahedra).

The result is checked (every edge in two triangles, consistently oriented, one fan per vertex,
positive volume) before it is returned. ``check_watertight`` adds Open3D's orientability test
and a triangle-pair intersection test in the CGAL extension: the pairs whose bounding boxes meet
(CGAL's box intersection) are tested with CGAL's exact predicates (closed triangles, so touching
counts; pairs sharing a vertex index are neighbours and not tested); pairs that only touch at a
duplicated vertex are counted apart. At 10^5 triangles that takes well under a second
(``benchmarks/results/watertight.md``).
"""
from __future__ import annotations

import numpy as np
from ._validate import as_mask, as_points
from .delaunay import DEFAULT_TOLERANCE, Triangulation, circumcenters, triangulate
from .geometry import components
from .topology import split_nonmanifold

__all__ = ["DEFAULT_TOLERANCE", "extract_mesh", "voronoi_polygons", "voronoi_surface"]

# The six edges of a positively oriented tetrahedron (a, b, c, d), each written as an even
# permutation (i, j, k, l): turning about i->j, the tetrahedron spans from face ijk to face ijl.
_EDGE_PERMUTATIONS = np.array(
    [[0, 1, 2, 3], [0, 2, 3, 1], [0, 3, 1, 2], [1, 2, 0, 3], [1, 3, 2, 0], [2, 3, 0, 1]]
)


def extract_mesh(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE,
                 triangulation: Triangulation | None = None):
    """Watertight surface of a VoroMesh as an Open3D triangle mesh: its Voronoi faces, fan-triangulated.

    Parameters
    ----------
    generators : (n, 3) float array
        Generator positions; at least 4 distinct ones.
    occupancy : (n,) bool
        True inside. At least one generator inside and one outside.
    tolerance : float
        Relative to the generators' bounding-box diagonal: generators are snapped to a grid of
        about this spacing (float32 precision is 6e-8), and generators closer than it are one
        generator (inside if any of them is). Voronoi vertices merge only where their
        tetrahedra are exactly co-spherical (decided by CGAL's exact predicate), never by
        distance.
    triangulation : voro3d.delaunay.Triangulation, optional
        The generators' triangulation (:func:`voro3d.delaunay.triangulate`) when the caller has
        it already, built with ``tolerance``.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, edge- and vertex-manifold, outward-oriented, with vertex normals; not cleaned
        (:func:`voro3d.clean` removes its slivers). Where inside cells meet only at an edge or
        corner, the shared vertices are duplicated.

    Raises
    ------
    ValueError
        On bad input (shape, dtype, NaN/inf, too few distinct generators, no inside or no
        outside generator, a triangulation of other generators).
    RuntimeError
        If the result fails the cheap watertightness checks (a bug, reported loudly).
    """
    from .io import to_triangle_mesh
    from .watertight import assert_closed_manifold

    vertices, triangles = voronoi_surface(generators, occupancy, tolerance=tolerance, triangulation=triangulation)
    assert_closed_manifold(vertices, triangles)
    return to_triangle_mesh(vertices, triangles, normals=True)


def voronoi_surface(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE,
                    triangulation: Triangulation | None = None):
    """Arrays behind :func:`extract_mesh`: the Voronoi faces, fan-triangulated, not cleaned.

    Returns
    -------
    vertices : (v, 3) float64
    triangles : (t, 3) int64
        Outward-oriented; not yet checked.
    """
    all_points, tets, cospherical, inside = _delaunay_dual(generators, occupancy, tolerance, triangulation)
    tet_ids, triangles = _dual_faces(tets, inside, all_points.shape[0])
    vertices, vertex_of, merged = _voronoi_vertices(all_points, tets, cospherical, tet_ids)
    triangles = vertex_of[triangles]
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & (triangles[:, 0] != triangles[:, 2])
    # Without merged Voronoi vertices the surface is the dual of a marching-tetrahedra surface
    # on a triangulated ball: a closed 2-manifold by construction. Only merges can pinch it.
    return split_nonmanifold(vertices, triangles[keep]) if merged else (vertices, triangles[keep])


def voronoi_polygons(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE,
                     triangulation: Triangulation | None = None):
    """The surface of a VoroMesh as its Voronoi faces: one polygon per face, not triangulated.

    Parameters
    ----------
    generators, occupancy, tolerance, triangulation
        As for :func:`extract_mesh`.

    Returns
    -------
    vertices : (v, 3) float64
        The Voronoi vertices of the surface (co-spherical tetrahedra give one vertex).
    polygons : list of (k,) int64 arrays, k >= 3
        One convex planar polygon per face between an inside and an outside cell, its corners in
        order, counter-clockwise seen from outside (normal from the inside cell to the outside
        one). Unlike :func:`extract_mesh`, vertices are not duplicated where inside cells meet
        only at an edge or a corner. Write them with :func:`voro3d.io.save_polygons`.

    Raises
    ------
    ValueError
        As :func:`extract_mesh`.
    """
    all_points, tets, cospherical, inside = _delaunay_dual(generators, occupancy, tolerance, triangulation)
    tet_of, starts, nxt = _rings(tets, inside, all_points.shape[0])
    vertices, vertex_of, _ = _voronoi_vertices(all_points, tets, cospherical, tet_of)
    lengths = np.diff(np.append(starts, tet_of.size))
    # Walk every ring at once: its k-th corner goes to position starts + k.
    ring = np.empty(tet_of.size, np.int64)
    at = starts.copy()
    for k in range(int(lengths.max())):
        active = lengths > k
        ring[starts[active] + k] = at[active]
        at[active] = nxt[at[active]]
    corners = vertex_of[tet_of[ring]]
    face = np.repeat(np.arange(starts.size), lengths)
    previous = np.arange(corners.size) - 1
    previous[starts] = starts + lengths - 1
    keep = corners != corners[previous]  # merged (co-spherical) neighbours become one corner
    kept = np.bincount(face[keep], minlength=starts.size)
    pieces = np.split(corners[keep], np.cumsum(kept)[:-1])
    return vertices, [piece for piece, count in zip(pieces, kept) if count >= 3]


def _delaunay_dual(generators, occupancy, tolerance, triangulation):
    """Checked inputs and their triangulation: (points, tets, cospherical, inside of every point)."""
    points = as_points(generators, "generators")
    occupancy = as_mask(occupancy, "occupancy", points.shape[0])
    if triangulation is None:
        triangulation = triangulate(points, tolerance=tolerance)
    elif triangulation.site.shape[0] != points.shape[0] or triangulation.tolerance != tolerance:
        raise ValueError(f"triangulation is of {triangulation.site.shape[0]} generators at tolerance "
                         f"{triangulation.tolerance}, not of these {points.shape[0]} at {tolerance}")
    inside = triangulation.site_occupancy(occupancy)
    if inside[: triangulation.n_sites].all():
        raise ValueError("occupancy has no outside generator; the surface would be empty")
    if not inside.any():
        raise ValueError("occupancy has no inside generator; the surface would be empty")
    return triangulation.points, triangulation.tets, triangulation.cospherical, inside


def _rings(tets, inside, n_points):
    """Voronoi polygons of mixed Delaunay edges, as rings of tetrahedra.

    Returns
    -------
    tet_of : (k,) int64
        Tetrahedron of each incidence (one per polygon corner), grouped by polygon.
    starts : (f,) int64
        Position in ``tet_of`` of each polygon's first incidence.
    nxt : (k,) int64
        Position of the next corner around the polygon, turning so that the normal points from
        the inside generator to the outside one.
    """
    inner, outer, turn_from, turn_to, tet_of = [], [], [], [], []
    for i, j, k, l in _EDGE_PERMUTATIONS:
        mixed = np.flatnonzero(inside[tets[:, i]] != inside[tets[:, j]])
        vi, vj, vk, vl = (tets[mixed, c] for c in (i, j, k, l))
        # Orient every edge inside -> outside; reversing the axis reverses the turn k -> l.
        flip = ~inside[vi]
        inner.append(np.where(flip, vj, vi))
        outer.append(np.where(flip, vi, vj))
        turn_from.append(np.where(flip, vl, vk))
        turn_to.append(np.where(flip, vk, vl))
        tet_of.append(mixed)
    inner, outer, turn_from, turn_to, tet_of = map(np.concatenate, (inner, outer, turn_from, turn_to, tet_of))

    # Sort incidences by face (inner, outer), then by the vertex the turn starts from.
    n = np.int64(n_points)
    if n_points < 2_000_000:  # n^3 fits in int64
        order = np.argsort((inner * n + outer) * n + turn_from)
    else:
        order = np.lexsort((turn_from, outer, inner))
    inner, outer = inner[order], outer[order]
    turn_from, turn_to, tet_of = turn_from[order], turn_to[order], tet_of[order]
    is_start = np.empty(order.size, bool)
    is_start[:1] = True
    is_start[1:] = (inner[1:] != inner[:-1]) | (outer[1:] != outer[:-1])
    face = np.cumsum(is_start) - 1
    key = face * n + turn_from
    target = face * n + turn_to
    nxt = np.searchsorted(key, target)
    if nxt.size and (nxt.max() >= key.size or (key[nxt] != target).any()):
        raise RuntimeError("a ring of tetrahedra around a Delaunay edge is not closed")
    return tet_of, np.flatnonzero(is_start), nxt


def _dual_faces(tets, inside, n_points):
    """Voronoi polygons of mixed Delaunay edges, fan-triangulated.

    Returns
    -------
    tet_ids : (k,) int64
        Tetrahedron of each incidence (one per polygon corner).
    triangles : (t, 3) int64
        Triangles as tetrahedron ids, normal from the inside generator to the outside one.
    """
    tet_of, starts, nxt = _rings(tets, inside, n_points)
    first = np.repeat(starts, np.diff(np.append(starts, tet_of.size)))
    position = np.arange(tet_of.size)
    fan = (position != first) & (nxt != first)
    triangles = np.stack([tet_of[first[fan]], tet_of[fan], tet_of[nxt[fan]]], axis=1)
    return tet_of, triangles


def _voronoi_vertices(points, tets, cospherical, tet_ids):
    """One vertex per Voronoi vertex: tetrahedra with one circumsphere become one vertex.

    Co-spherical generators (a lattice) give many tetrahedra with the same circumsphere; the
    exact predicate found them, so no tolerance decides what merges and near-degenerate
    (jittered) configurations keep their true, tiny faces. Triangles and polygon sides that
    collapse are the callers' to drop.

    Returns
    -------
    vertices : (v, 3) float64
    vertex_of : (m,) int64
        The vertex of each of the ``m`` tetrahedra; -1 for those that share no circumsphere with
        a tetrahedron of ``tet_ids``.
    merged : bool
        Whether any two tetrahedra of the surface became one vertex.
    """
    n = tets.shape[0]
    label = np.arange(n)
    if cospherical.size:
        # All pairs, not only mixed ones: the tetrahedra of one Delaunay polytope may connect
        # through tetrahedra with no surface face.
        label = components(n, cospherical)[1]
    # One tetrahedron per vertex (any: they share the circumsphere), found without sorting.
    representative = np.full(n, -1, np.int64)
    representative[label[tet_ids]] = tet_ids
    used = np.flatnonzero(representative >= 0)
    vertices = circumcenters(points, tets[representative[used]])
    vertex_of = np.full(n, -1, np.int64)
    vertex_of[used] = np.arange(used.size)
    is_mixed = np.zeros(n, bool)
    is_mixed[tet_ids] = True
    merged = used.size < np.count_nonzero(is_mixed)
    return vertices, vertex_of[label], merged
