"""VoroMesh extraction: Voronoi faces between inside and outside generators, as a mesh.

The faces come from the dual of the Delaunay tetrahedralisation: every Delaunay edge (i, j)
whose ends differ in occupancy is a Voronoi polygon whose corners are the circumcentres of the
tetrahedra around that edge. All of it is vectorised over tetrahedra and edges.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ._validate import as_mask, as_points
from .delaunay import circumcenters, delaunay_with_box
from .topology import split_nonmanifold

__all__ = ["DEFAULT_TOLERANCE", "VoroMesh", "extract_mesh", "voronoi_polygons", "voronoi_surface"]

DEFAULT_TOLERANCE = 1e-7

# The six edges of a positively oriented tetrahedron (a, b, c, d), each written as an even
# permutation (i, j, k, l): turning about i->j, the tetrahedron spans from face ijk to face ijl.
_EDGE_PERMUTATIONS = np.array(
    [[0, 1, 2, 3], [0, 2, 3, 1], [0, 3, 1, 2], [1, 2, 0, 3], [1, 3, 2, 0], [2, 3, 0, 1]]
)


@dataclass
class VoroMesh:
    """A shape as Voronoi generators with a binary occupancy.

    Attributes
    ----------
    generators : (n, 3) float64
        Generator positions.
    occupancy : (n,) bool
        True for generators whose Voronoi cell is inside the shape.
    """

    generators: np.ndarray
    occupancy: np.ndarray

    def __post_init__(self):
        self.generators = as_points(self.generators, "generators")
        self.occupancy = as_mask(self.occupancy, "occupancy", self.generators.shape[0])

    def to_open3d(self, *, tolerance: float = DEFAULT_TOLERANCE, clean: bool = True, surface=None,
                  smoothing: float = 0.0):
        """The watertight surface, cleaned unless ``clean=False`` and fitted to ``surface`` when
        given, see :func:`extract_mesh`."""
        return extract_mesh(self.generators, self.occupancy, tolerance=tolerance, clean=clean, surface=surface,
                            smoothing=smoothing)

    def to_polygons(self, *, tolerance: float = DEFAULT_TOLERANCE):
        """The Voronoi faces of the surface as polygons, see :func:`voronoi_polygons`."""
        return voronoi_polygons(self.generators, self.occupancy, tolerance=tolerance)

    def save(self, path) -> None:
        """Write ``generators`` and ``occupancy`` to a ``.npz`` file (atomically)."""
        from .io import atomic_path

        with atomic_path(path, suffix=".npz") as tmp:
            with open(tmp, "wb") as handle:
                np.savez_compressed(handle, generators=self.generators, occupancy=self.occupancy)

    @classmethod
    def load(cls, path) -> "VoroMesh":
        """Read a file written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no such VoroMesh file: {path}")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
        except Exception as error:  # zip, pickle and OS errors of a corrupt or foreign file
            raise ValueError(f"{path} is not a readable .npz file: {error}") from error
        missing = {"generators", "occupancy"} - set(arrays)
        if missing:
            raise ValueError(f"{path} lacks arrays {sorted(missing)}; it holds {sorted(arrays)}")
        return cls(arrays["generators"], arrays["occupancy"])


def extract_mesh(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE, clean: bool = True, surface=None,
                 smoothing: float = 0.0):
    """Watertight surface of a VoroMesh as an Open3D triangle mesh.

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
    clean : bool
        Remove slivers, tiny faces and nearly coincident Voronoi vertices with
        :func:`voro3d.cleaning.clean` (its defaults: within 0.2 voxel of the Voronoi faces,
        volume within 0.5%; every guarantee below checked again). ``False`` gives the Voronoi
        faces themselves, fan-triangulated.
    surface : open3d.geometry.TriangleMesh or (vertices, triangles), optional
        What the shape approximates, in the generators' units: the input mesh of a fit, a
        cloud's target surface. With ``clean``, the cleaned vertices are then fitted to it
        (:func:`voro3d.snapping.snap_to_surface`: at most a quarter voxel each, where no guarantee
        breaks), which straightens the facets the VoroLoss fit left tilted (dev meshes at 32^3:
        triangles over 30 degrees off the input's normal 9.1% -> 6.4%, CD -2.6%;
        ``benchmarks/results/clean_32_64.md``). Ignored without ``clean``.
    smoothing : float
        The fit's pull of each vertex towards its neighbours (``snap_to_surface``), for a noisy
        ``surface``.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, edge- and vertex-manifold, outward-oriented, with vertex normals. Where
        inside cells meet only at an edge or corner, the shared vertices are duplicated.

    Raises
    ------
    ValueError
        On bad input (shape, dtype, NaN/inf, too few distinct generators, no inside or no
        outside generator; an empty or non-finite ``surface``, a negative ``smoothing``).
    RuntimeError
        If the result fails the cheap watertightness checks (a bug, reported loudly).
    """
    vertices, triangles = voronoi_surface(generators, occupancy, tolerance=tolerance)
    from .io import to_triangle_mesh
    from .watertight import assert_closed_manifold

    assert_closed_manifold(vertices, triangles)
    if clean:
        from .cleaning import clean_surface

        vertices, triangles, info = clean_surface(vertices, triangles)
        if surface is not None:
            from .snapping import snap_to_surface

            vertices, _ = snap_to_surface(vertices, triangles, surface, voxel=info.voxel, smoothing=smoothing)
    return to_triangle_mesh(vertices, triangles, normals=True)


def voronoi_surface(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE):
    """Arrays behind :func:`extract_mesh`: the Voronoi faces, fan-triangulated, not cleaned.

    Returns
    -------
    vertices : (v, 3) float64
    triangles : (t, 3) int64
        Outward-oriented; not yet checked.
    """
    all_points, tets, cospherical, inside = _delaunay_dual(generators, occupancy, tolerance)
    tet_ids, triangles = _dual_faces(tets, inside, all_points.shape[0])
    vertices, vertex_of, merged = _voronoi_vertices(all_points, tets, cospherical, tet_ids)
    triangles = vertex_of[triangles]
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & (triangles[:, 0] != triangles[:, 2])
    # Without merged Voronoi vertices the surface is the dual of a marching-tetrahedra surface
    # on a triangulated ball: a closed 2-manifold by construction. Only merges can pinch it.
    return split_nonmanifold(vertices, triangles[keep]) if merged else (vertices, triangles[keep])


def voronoi_polygons(generators, occupancy, *, tolerance: float = DEFAULT_TOLERANCE):
    """The surface of a VoroMesh as its Voronoi faces: one polygon per face, not triangulated.

    Parameters
    ----------
    generators, occupancy, tolerance
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
    all_points, tets, cospherical, inside = _delaunay_dual(generators, occupancy, tolerance)
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


def _delaunay_dual(generators, occupancy, tolerance):
    """Checked, snapped generators with the bounding box's: (points, tets, cospherical, inside)."""
    points = as_points(generators, "generators")
    inside = as_mask(occupancy, "occupancy", points.shape[0])
    if not np.isfinite(tolerance) or not 0 <= tolerance < 1e-2:
        raise ValueError(f"tolerance must be in [0, 0.01), got {tolerance}")
    points, inside, quantum = _prepare_generators(points, inside, tolerance)
    if points.shape[0] < 4:
        raise ValueError(f"generators must hold at least 4 distinct points, got {points.shape[0]}")
    if inside.all():
        raise ValueError("occupancy has no outside generator; the surface would be empty")
    if not inside.any():
        raise ValueError("occupancy has no inside generator; the surface would be empty")

    all_points, tets, cospherical = delaunay_with_box(points, quantum=quantum)
    inside_all = np.concatenate([inside, np.zeros(all_points.shape[0] - points.shape[0], bool)])
    return all_points, tets, cospherical, inside_all


def _prepare_generators(points, inside, tolerance):
    """Snap generators to a grid of spacing ~``tolerance`` and merge those closer than it.

    Returns the generators, their occupancy and the grid spacing (a power of two, or None).

    Snapping turns a lattice jittered below the tolerance back into an exact lattice, whose
    degeneracies the exact predicates resolve. What is left is either exactly degenerate or
    has features far above float64 rounding, so rounded Voronoi vertices cannot make thin
    neighbouring faces cross.
    """
    scale = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    if scale == 0:
        return points[:1], inside[:1], None
    quantum = None
    if tolerance > 0:
        # A power of two, so the snapped coordinates are exact multiples of it.
        quantum = float(2.0 ** np.floor(np.log2(tolerance * scale)))
        points = np.round(points / quantum) * quantum
    # Pairs within the radius include exact duplicates (distance 0).
    pairs = cKDTree(points).query_pairs(tolerance * scale, output_type="ndarray")
    n = points.shape[0]
    label = np.arange(n)
    if pairs.size:
        graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        label = connected_components(graph, directed=False)[1]
    _, first, label = np.unique(label, return_index=True, return_inverse=True)
    merged_inside = np.bincount(label.reshape(-1), weights=inside.astype(float)) > 0
    return points[first], merged_inside, quantum


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
        graph = coo_matrix((np.ones(len(cospherical), np.int8), (cospherical[:, 0], cospherical[:, 1])),
                           shape=(n, n))
        label = connected_components(graph, directed=False)[1]
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
