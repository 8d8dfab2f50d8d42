"""Clean a VoroMesh surface: no slivers, no specks, fewer faces, every guarantee kept.

A VoroMesh surface is made of Voronoi faces, fan-triangulated, and many of them are tiny or thin:
Voronoi vertices that nearly coincide (nearly co-spherical generators) and faces a sliver wide.
They look like dark flecks and scales on a rendered mesh and trouble simulators and printers.
:func:`clean` removes them in the compiled extension (``src/voro3d_clean.cpp``), in ``PASSES``
passes of:

1. ends of edges shorter than ``merge_length`` voxels merged at their midpoint (near-coincident
   Voronoi vertices);
2. edges shorter than ``collapse_length`` voxels collapsed, shortest first, as CGAL's
   ``Surface_mesh_simplification`` does (Lindstrom-Turk placement, which keeps volume and sharp edges);
3. edges flipped where that raises the smallest angle of their two triangles by
   ``min_angle_gain`` degrees (caps and the thin fans of long Voronoi faces).

No change moves the surface farther than ``max_distance`` voxels from the input (a bound carried
per face, both ways: every point of the result is that close to the input and every point of the
input that close to the result) or takes the enclosed volume more than ``max_volume_change`` from
the input's. Then the result is tested: closed, edge- and vertex-manifold, consistently oriented
(by construction: every change is a CGAL Euler operation under the link condition) and free of
crossing triangles (CGAL's exact predicates). Where triangles cross, the input vertices behind their
corners are frozen and the first round's changes are made again from the input, in
order, less those that touch a frozen vertex (a change whose patch differs from the first round's
is checked again as in the first round), until nothing crosses. Frozen vertices are never moved,
merged or flipped around, so a triangle all of whose corners are frozen is an input triangle and
the loop ends (a pair of input triangles that already crossed is left as it was).

In numbers; where it runs; its voxel; CGAL
------------------------------------------
Every path that returns a mesh cleans it by default
(``clean=True`` in ``VoroMesh.to_open3d``, ``reconstruct``, ``VoroMeshStage``,
``run_batch``; ``--no-clean`` on the command line; where the path knows what the shape approximates,
an input mesh or a cloud's target, the cleaned vertices are then fitted to it: :mod:`voro3d.snapping`)
with ``voro3d.clean(mesh)``. In numbers (the defaults):

1. Two passes, each with half of the budgets below, of: the ends of edges shorter than 0.05 voxel
   merged at their midpoint; edges shorter than 0.4 voxel collapsed, shortest first, as CGAL's
   ``Surface_mesh_simplification`` does (its tests, in a loop of our own that queues only short
   edges; Lindstrom–Turk placement, which keeps volume and sharp edges;
   the midpoint where it lands over an edge length away), no face turned over; edges flipped
   where that raises the smallest angle of their two triangles by over 1°.
2. **Distance**: every face carries a bound on how far it is from the input and the input from it.
   A change replaces a disk of triangles by another with the same boundary; its new faces get the
   largest height gap between the two disks over the overlay of their projections (where both are
   graphs along the mean normal; else how far the moved vertex went) plus the bounds of the faces
   they replace. A change that would take a bound past ``max_distance`` (0.2 voxel) is not made, nor
   one that would take the volume change past ``max_volume_change`` (0.5%).
3. **Topology** by construction: only Euler operations under the link condition, so the result is
   closed, manifold and consistently oriented (checked again). **Crossings** are tested exactly
   (CGAL's predicates, as ``check_watertight``); where triangles cross, the input vertices behind
   them are frozen and the first round's changes are made again without touching them (a change
   whose patch differs is checked again), until nothing crosses. Frozen vertices are never moved,
   merged or flipped around, so the loop ends; vertices where sheets touch stay in place.

The voxel is the grid's (``VoroMesh.voxel``: a VoroMesh carries its grid and frame, and ``to_open3d``
passes it on); ``clean(mesh)`` without ``voxel=`` estimates it from the triangles (``cleaning.voxel_size``:
the square root of the mean triangle area over 0.29, 0.9-1.2 of the grid's voxel on the dev meshes).
CGAL's own pieces are used where they fit; the code says, with measurements, where they did not
(the exact ``Polyhedral_envelope`` test costs 107 µs a triangle, more than the fit; ``edge_collapse``'s
geometric test refuses collapses next to faces 10⁴ times smaller, which left 85% of the edges under
0.001 voxel). ``voronoi_polygons`` / ``VoroMesh.to_polygons()`` give the Voronoi faces themselves, one
polygon each, and ``io.save_polygons`` writes them (``.ply``, ``.obj``, ``.off``; ``--polygons`` on the
command line).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from .io import mesh_arrays, to_triangle_mesh
from .watertight import assert_closed_manifold, self_intersections, signed_volume

__all__ = ["CleanInfo", "clean", "clean_surface", "voxel_size"]

# Defaults, in voxels of the grid the surface was fitted on (see benchmarks/bench_clean.py).
MAX_DISTANCE = 0.2
COLLAPSE_LENGTH = 0.4
MERGE_LENGTH = 0.05
MIN_ANGLE_GAIN = 1.0  # degrees
MAX_VOLUME_CHANGE = 0.005  # of the input's volume
# Passes, each with its share of max_distance and max_volume_change (src/voro3d_clean.cpp says why).
PASSES = 2

# sqrt(mean triangle area) of a VoroMesh surface, in voxels: 0.26-0.32 on 13 fits of the dev meshes
# at 32^3 and 64^3; the estimate is 0.90-1.21 of the grid's voxel over all 76 (bench_clean.py).
_TRIANGLE_SIDE_PER_VOXEL = 0.29


@dataclass(frozen=True)
class CleanInfo:
    """What :func:`clean_surface` did.

    Attributes
    ----------
    n_triangles_before, n_triangles_after : int
    voxel : float
        The voxel the lengths are relative to, in mesh units.
    max_distance : float
        The distance bound, in mesh units: every point of the result is within it of the input, and
        every point of the input within it of the result.
    volume_change : float
        Signed, relative to the input's volume.
    rounds : int
        Cleaning rounds; more than one when triangles crossed and a patch was frozen.
    input_crossings : int
        Pairs of crossing triangles the input already had, left as they were.
    frozen_vertices : int
        Input vertices frozen in the last round (shared positions included).
    collapses, flips : int
        Edges collapsed (vertices merged) and flipped in the last round.
    seconds : float
    """

    n_triangles_before: int
    n_triangles_after: int
    voxel: float
    max_distance: float
    volume_change: float
    rounds: int
    input_crossings: int
    frozen_vertices: int
    collapses: int
    flips: int
    seconds: float

    def as_dict(self) -> dict:
        return asdict(self)


def voxel_size(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """The voxel of the grid a VoroMesh surface was fitted on, estimated from its triangles.

    Parameters
    ----------
    vertices : (n, 3) float64
    triangles : (t, 3) int64

    Returns
    -------
    float
        ``sqrt(area / t) / 0.29``: the square root of the mean triangle area is 0.26-0.32 voxel
        on VoroMesh surfaces of the dev meshes at 32^3 and 64^3.

    Raises
    ------
    ValueError
        Bad arrays (see :func:`voro3d.io.mesh_arrays`), or triangles of zero total area.
    """
    vertices, triangles = mesh_arrays((vertices, triangles))
    # Coordinate by coordinate (np.cross and np.linalg.norm's arithmetic, in their order, at a third
    # of their time).
    x, y, z = (np.ascontiguousarray(vertices[:, k]) for k in range(3))
    i, j, k = (np.ascontiguousarray(triangles[:, m]) for m in range(3))
    ux, uy, uz = x[j] - x[i], y[j] - y[i], z[j] - z[i]
    vx, vy, vz = x[k] - x[i], y[k] - y[i], z[k] - z[i]
    cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    area = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz).sum()
    if not area > 0:
        raise ValueError("mesh has zero area: no voxel to estimate (pass voxel=)")
    return float(np.sqrt(area / triangles.shape[0]) / _TRIANGLE_SIDE_PER_VOXEL)


def shared_positions(vertices: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices whose position another vertex has too. Only vertices that share
    their x with another go through ``np.unique``'s row comparison (30 ms at 50k vertices)."""
    x = vertices[:, 0]
    order = np.argsort(x, kind="stable")
    same_x = x[order[1:]] == x[order[:-1]]
    candidates = np.zeros(len(vertices), bool)
    candidates[order[1:][same_x]] = True
    candidates[order[:-1][same_x]] = True
    shared = np.zeros(len(vertices), bool)
    if candidates.any():
        _, first, counts = np.unique(vertices[candidates], axis=0, return_inverse=True, return_counts=True)
        shared[candidates] = counts[first.reshape(-1)] > 1
    return shared


def _changed_triangles(vertices, triangles, last_vertices, last_triangles, last_crossing, shared):
    """(t,) bool: the triangles whose crossings a round must test, given the last round's surface.

    A pair of triangles both of which the last round had too (the same corner positions in the same
    cyclic order) was tested then: it crosses only if it crossed then. So only the triangles new to
    this round, those of the last round's crossing pairs and those at a ``shared`` vertex
    (duplicated positions, where equal positions need not mean equal indices) are changed.
    """
    def hashed(points, faces):
        # A hash of each corner position; faces turned to start at their smallest one, and keyed
        # by the sum (the same for any starting corner).
        bits = np.ascontiguousarray(points).view(np.uint64).reshape(-1, 3)
        mixed = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F) \
            ^ bits[:, 2] * np.uint64(0x165667B19E3779F9)
        corner = mixed[faces]
        turn = (np.argmin(corner, axis=1)[:, None] + np.arange(3)) % 3
        return np.take_along_axis(faces, turn, axis=1), corner.sum(axis=1, dtype=np.uint64)

    old = np.ones(len(last_triangles), bool)
    old[last_crossing.reshape(-1)] = False
    last_faces, last_keys = hashed(last_vertices, last_triangles[old])
    order = np.argsort(last_keys)
    last_faces, last_keys = last_faces[order], last_keys[order]
    faces, keys = hashed(vertices, triangles)
    changed = np.ones(len(triangles), bool)
    if len(last_keys):
        found = np.minimum(np.searchsorted(last_keys, keys), len(last_keys) - 1)
        candidate = np.flatnonzero(last_keys[found] == keys)
        # Equal keys, then equal corners, checked exactly.
        same = (vertices[faces[candidate]] == last_vertices[last_faces[found[candidate]]]).all(axis=(1, 2))
        changed[candidate[same]] = False
    at_shared = np.zeros(len(vertices), bool)
    at_shared[shared[shared >= 0]] = True
    changed |= at_shared[triangles].any(axis=1)
    return changed


def clean(mesh, *, voxel: float | None = None, max_distance: float = MAX_DISTANCE,
          collapse_length: float = COLLAPSE_LENGTH, merge_length: float = MERGE_LENGTH,
          min_angle_gain: float = MIN_ANGLE_GAIN, max_volume_change: float = MAX_VOLUME_CHANGE):
    """A cleaned copy of a watertight surface: no slivers or specks, fewer faces, same guarantees.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or (vertices, triangles)
        Closed, edge-manifold, consistently oriented, no crossing triangles (a VoroMesh surface).
    voxel, max_distance, collapse_length, merge_length, min_angle_gain, max_volume_change
        See :func:`clean_surface`.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, edge- and vertex-manifold, outward-oriented, no crossing triangles (tested
        exactly), with vertex normals; within ``max_distance`` voxels of ``mesh`` both ways and
        within ``max_volume_change`` of its volume.

    Raises
    ------
    ValueError
        See :func:`clean_surface`.
    """
    vertices, triangles, _ = clean_surface(*mesh_arrays(mesh), voxel=voxel, max_distance=max_distance,
                                           collapse_length=collapse_length, merge_length=merge_length,
                                           min_angle_gain=min_angle_gain, max_volume_change=max_volume_change)
    return to_triangle_mesh(vertices, triangles, normals=True)


def clean_surface(vertices, triangles, *, voxel: float | None = None, max_distance: float = MAX_DISTANCE,
                  collapse_length: float = COLLAPSE_LENGTH, merge_length: float = MERGE_LENGTH,
                  min_angle_gain: float = MIN_ANGLE_GAIN, max_volume_change: float = MAX_VOLUME_CHANGE):
    """Arrays behind :func:`clean`, and a report.

    Parameters
    ----------
    vertices : (n, 3) float
    triangles : (t, 3) int
        Closed, edge-manifold, consistently oriented (outward), no crossing triangles.
    voxel : float, optional
        The unit of the lengths below, in mesh units: the voxel of the grid the VoroMesh was fitted
        on. Default: estimated from the triangles (:func:`voxel_size`).
    max_distance : float
        Largest distance, in voxels, between the result and the input (both ways).
    collapse_length : float
        Edges shorter than this, in voxels, are collapsed where the bounds allow.
    merge_length : float
        Ends of edges shorter than this, in voxels, are merged first (nearly coincident Voronoi
        vertices, whose thin faces CGAL's collapse refuses to touch).
    min_angle_gain : float
        An edge is flipped when that raises the smallest angle of its two triangles by more than
        this, in degrees.
    max_volume_change : float
        Largest change of the enclosed volume, relative to the input's.

    Returns
    -------
    vertices : (m, 3) float64
    triangles : (s, 3) int64
    info : CleanInfo

    Raises
    ------
    ValueError
        A bad parameter (named), or a surface that is not closed, edge-manifold and consistently
        oriented with a positive volume. A surface whose own triangles cross is cleaned elsewhere:
        the crossing pairs stay as they were (``info.input_crossings``).
    RuntimeError
        If the result fails the closed/manifold/orientation checks (a bug, reported loudly).
    """
    from . import _cgal

    start = time.perf_counter()
    vertices, triangles = mesh_arrays((vertices, triangles))
    lengths = {"max_distance": max_distance, "collapse_length": collapse_length, "merge_length": merge_length,
               "min_angle_gain": min_angle_gain, "max_volume_change": max_volume_change}
    for name, value in lengths.items():
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {value}")
    if voxel is None:
        voxel = voxel_size(vertices, triangles)
    elif not np.isfinite(voxel) or voxel <= 0:
        raise ValueError(f"voxel must be finite and > 0, got {voxel}")
    volume = signed_volume(vertices, triangles)
    if not volume > 0:
        raise ValueError(f"mesh must enclose a positive volume with outward normals, got volume {volume:.4g}")

    # Sheets of a non-manifold solid touch at vertices duplicated by the extraction: kept in place.
    shared = shared_positions(vertices)
    frozen = shared.copy()
    new_vertices, new_triangles, label, collapses, flips, log = _cgal.clean_surface(
        vertices, triangles, frozen, merge_length * voxel, collapse_length * voxel, max_distance * voxel,
        max_volume_change * volume, np.radians(min_angle_gain), PASSES)
    rounds = 1
    changed = None
    while True:
        crossing, _ = self_intersections(new_vertices, new_triangles, changed=changed)
        last = (new_vertices, new_triangles, crossing)
        # An output vertex is an input one left in place when exactly one frozen input vertex maps
        # to it; new triangles always have a corner that is not, so a crossing pair of triangles
        # whose corners all are is a pair of the input, left as it was.
        mapped = label >= 0
        sources = np.bincount(label[mapped], minlength=new_vertices.shape[0])
        unfrozen = np.bincount(label[mapped], weights=~frozen[mapped], minlength=new_vertices.shape[0])
        kept = (sources == 1) & (unfrozen == 0)
        original = kept[new_triangles[crossing]].all(axis=(1, 2))
        crossing = crossing[~original]
        if not len(crossing):
            break
        # Freeze the input vertices behind the corners of the crossing triangles. (With their
        # neighbours too, a thin CAD part, abc_00000001 at 64^3, froze 1157 vertices instead of 287
        # and kept 19% slivers instead of 8%.)
        patch = np.zeros(new_vertices.shape[0], bool)
        patch[new_triangles[crossing.reshape(-1)]] = True
        grow = mapped & patch[np.where(mapped, label, 0)] & ~frozen
        if not grow.any():  # a crossing pair of new triangles has a merged or unfrozen corner
            raise RuntimeError("clean_surface: a crossing left no vertex to freeze (a bug)")
        frozen |= grow
        # The first round's changes again, less those near frozen vertices: a search of its own
        # would cost a whole round, for a few crossing pairs (2-11 on the dev meshes at 64^3).
        new_vertices, new_triangles, label, collapses, flips = _cgal.replay_clean(vertices, triangles, frozen, log)
        changed = _changed_triangles(new_vertices, new_triangles, *last, label[shared])
        rounds += 1
    assert_closed_manifold(new_vertices, new_triangles)
    info = CleanInfo(n_triangles_before=int(triangles.shape[0]), n_triangles_after=int(new_triangles.shape[0]),
                     voxel=float(voxel), max_distance=float(max_distance * voxel),
                     volume_change=signed_volume(new_vertices, new_triangles) / volume - 1, rounds=rounds,
                     input_crossings=int(original.sum()),
                     frozen_vertices=int(frozen.sum()), collapses=int(collapses), flips=int(flips),
                     seconds=time.perf_counter() - start)
    return new_vertices, new_triangles, info
