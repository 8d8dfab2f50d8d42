"""Watertightness checks catch each kind of defect, and only that."""
import numpy as np
import open3d as o3d
import pytest

from voro3d.topology import edge_counts, open_edge_count, split_nonmanifold
from voro3d.watertight import assert_closed_manifold, check_watertight, self_intersections, signed_volume

# A unit tetrahedron with outward normals.
TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_closed_tetrahedron_passes():
    report = check_watertight((TET_V, TET_F))
    assert report.watertight and report.volume == pytest.approx(1 / 6)
    assert report.self_intersecting_pairs == 0 and report.touching_pairs == 0


def test_open_mesh_fails_closed():
    report = check_watertight((TET_V, TET_F[:3]))
    assert not report.closed and not report.watertight


def test_flipped_triangle_fails_orientation():
    faces = TET_F.copy()
    faces[0] = faces[0, ::-1]
    report = check_watertight((TET_V, faces))
    assert report.closed and not report.consistently_oriented and not report.watertight


def test_inward_normals_fail_volume():
    report = check_watertight((TET_V, TET_F[:, ::-1]))
    assert report.volume < 0 and not report.watertight


def test_non_manifold_edge_and_vertex():
    # Two tetrahedra sharing one edge: the edge has four triangles.
    other = TET_V * [-1, -1, 1]
    vertices = np.vstack([TET_V, other[[1, 2]]])
    faces = np.vstack([TET_F, [[0, 4, 5], [0, 3, 4], [0, 5, 3], [4, 3, 5]]])
    report = check_watertight((vertices, faces))
    assert not report.edge_manifold and not report.watertight
    # Two tetrahedra sharing only a vertex: edges fine, vertex not.
    vertices = np.vstack([TET_V, -TET_V[1:]])
    faces = np.vstack([TET_F, [[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]])
    report = check_watertight((vertices, faces))
    assert report.closed and report.edge_manifold and not report.vertex_manifold


@pytest.mark.parametrize("seed", range(5))
def test_open_edges_are_counted_once_for_both_checks(seed):
    # Random fans over few vertices: edges in 1, 2 and 3+ triangles, duplicated positions.
    rng = np.random.default_rng(seed)
    triangles = np.array([t for t in rng.integers(0, 9, (40, 3)) if len(set(t)) == 3])
    vertices = rng.uniform(-1, 1, (9, 3))
    vertices[8] = vertices[7]  # welded by open_edge_count, kept apart by check_watertight
    edges = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert sorted(edge_counts(triangles)) == sorted(counts)
    welded = np.where(triangles == 8, 7, triangles)
    welded = welded[(welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 2] != welded[:, 0])]
    _, welded_counts = np.unique(np.sort(welded[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0,
                                 return_counts=True)
    assert open_edge_count(vertices, triangles) == (welded_counts != 2).sum()
    assert check_watertight((vertices, triangles), self_intersection=False).closed == bool((counts == 2).all())


def test_split_nonmanifold_separates_sheets_that_share_a_vertex():
    vertices = np.vstack([TET_V, -TET_V[1:]])
    faces = np.vstack([TET_F, [[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]])
    new_vertices, new_faces = split_nonmanifold(vertices, faces)
    report = check_watertight((new_vertices, new_faces))
    assert report.watertight and len(new_vertices) == 8 and report.touching_pairs > 0


def test_crossing_triangles_are_found_exactly():
    cube = o3d.geometry.TriangleMesh.create_box()
    moved = o3d.geometry.TriangleMesh.create_box().translate((0.5, 0.5, 0.5))
    both = cube + moved
    report = check_watertight(both)
    assert report.self_intersecting_pairs > 0 and not report.watertight
    # Near-touching but separate triangles (10^-12 apart) do not intersect.
    a = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    assert _pairs(a, a + [0, 0, 1e-12]) == ([], [])
    assert _pairs(a, np.array([[0.2, 0.2, -1], [0.2, 0.2, 1], [2, 2, 0]], float)) == ([(0, 1)], [])


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)


def _pairs(*triangles):
    """Crossing and touching pairs of a soup of separately indexed triangles, as lists of tuples."""
    vertices = np.vstack(triangles)
    crossing, touching = self_intersections(vertices, np.arange(len(vertices)).reshape(-1, 3))
    return [tuple(p) for p in crossing.tolist()], [tuple(p) for p in touching.tolist()]


@pytest.mark.parametrize("other, expected", [
    # A shared corner position under other indices: touching, not crossing.
    (np.array([[0, 0, 0], [-1, 0, 0.5], [0, -1, 0.5]]), ([], [(0, 1)])),
    # Touching at a point inside an edge, and an edge lying on the face: crossing (closed triangles).
    (np.array([[0.5, 0, 0], [0.5, -1, 1], [0.5, -1, -1]]), ([(0, 1)], [])),
    (np.array([[0.2, 0.2, 0], [0.4, 0.2, 0], [0.3, 0.3, 1]]), ([(0, 1)], [])),
    # Coplanar: overlapping, one inside the other, and apart by one ulp-sized gap.
    (np.array([[0.5, 0.5, 0], [-0.5, 0.2, 0], [0.2, -0.5, 0]]), ([(0, 1)], [])),
    (np.array([[0.1, 0.1, 0], [0.3, 0.1, 0], [0.1, 0.3, 0]]), ([(0, 1)], [])),
    (np.array([[0.5 + 1e-15, 0.5 + 1e-15, 0], [1, 1, 0], [2, 0.5, 0]]), ([], [])),
    (np.array([[0.5, 0.5, 0], [1, 1, 0], [2, 0.5, 0]]), ([(0, 1)], [])),
    # Degenerate triangles: collinear corners are their segment, three equal corners a point.
    (np.array([[0.25, 0.25, -1], [0.25, 0.25, 0.5], [0.25, 0.25, 1]]), ([(0, 1)], [])),
    (np.array([[0.25, 0.25, 1], [0.25, 0.25, 2], [0.25, 0.25, -1]]), ([(0, 1)], [])),
    (np.array([[0.25, 0.25, -1], [0.25, 0.25, 2], [0.25, 0.25, 1.5]]), ([(0, 1)], [])),
    (np.array([[0.75, 0.75, -1], [0.75, 0.75, 0.5], [0.75, 0.75, 1]]), ([], [])),
    (np.array([[0.3, 0.3, 0]] * 3), ([(0, 1)], [])),
    (np.array([[0.3, 0.3, 1e-300]] * 3), ([], [])),
])
def test_exact_pair_cases(other, expected):
    assert _pairs(TRIANGLE, np.asarray(other, float)) == expected


def test_neighbours_that_meet_beyond_a_shared_vertex_cross():
    # Two coplanar triangles that overlap and share vertex 0 (by index) cross; given a copy of
    # that vertex instead, they are sheets touching there.
    vertices = np.vstack([TRIANGLE, [[0.5, 0.5, 0], [-0.5, 0.2, 0]]])
    crossing, touching = self_intersections(vertices, np.array([[0, 1, 2], [0, 3, 4]]))
    assert crossing.tolist() == [[0, 1]] and touching.size == 0
    copied = np.vstack([vertices, vertices[:1]])
    crossing, touching = self_intersections(copied, np.array([[0, 1, 2], [5, 3, 4]]))
    assert crossing.size == 0 and touching.tolist() == [[0, 1]]
    # A fold through the shared vertex, out of the plane, crosses too; neighbours that only meet
    # at their shared vertex, or along their shared edge, do not.
    fold = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.4, 0.4, 1], [0.4, 0.4, -1], [-1, -1, 0.5], [1, 1, 0]], float)
    assert self_intersections(fold, np.array([[0, 1, 2], [0, 3, 4]]))[0].tolist() == [[0, 1]]
    assert self_intersections(fold, np.array([[0, 1, 2], [0, 5, 3]]))[0].size == 0
    assert self_intersections(fold, np.array([[0, 1, 2], [1, 6, 2]]))[0].size == 0
    # Two triangles on one edge folded flat onto each other cross.
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0]], float)
    assert self_intersections(flat, np.array([[0, 1, 2], [1, 0, 3]]))[0].tolist() == [[0, 1]]


@pytest.mark.parametrize("seed", range(10))
def test_random_soups_agree_with_open3d(seed):
    # Generic random triangles (no degeneracy closer than float rounding): Open3D's
    # floating-point test must find the same pairs as the exact one.
    rng = np.random.default_rng(seed)
    corners = rng.uniform(0, 1, (60, 1, 3)) + rng.uniform(-0.3, 0.3, (60, 3, 3))
    vertices, triangles = corners.reshape(-1, 3), np.arange(180).reshape(-1, 3)
    crossing, touching = self_intersections(vertices, triangles)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    expected = np.sort(np.asarray(mesh.get_self_intersecting_triangles()), axis=1)
    assert touching.size == 0 and len(crossing) > 10
    assert sorted(map(tuple, crossing.tolist())) == sorted(map(tuple, expected.tolist()))


@pytest.mark.parametrize("seed", range(5))
def test_changed_tests_only_the_pairs_that_hold_a_changed_triangle(seed):
    rng = np.random.default_rng(seed)
    corners = rng.uniform(0, 1, (80, 1, 3)) + rng.uniform(-0.3, 0.3, (80, 3, 3))
    vertices, triangles = corners.reshape(-1, 3), np.arange(240).reshape(-1, 3)
    triangles[1] = [0, 4, 5]  # a neighbour of triangle 0: never tested
    crossing, touching = self_intersections(vertices, triangles)
    changed = rng.random(80) < 0.2
    part, part_touching = self_intersections(vertices, triangles, changed=changed)
    assert len(part) and np.array_equal(part, crossing[changed[crossing].any(axis=1)])
    assert part_touching.size == touching.size == 0
    everything, _ = self_intersections(vertices, triangles, changed=np.ones(80, bool))
    assert np.array_equal(everything, crossing)
    assert self_intersections(vertices, triangles, changed=np.zeros(80, bool))[0].shape == (0, 2)
    with pytest.raises(ValueError, match="changed"):
        self_intersections(vertices, triangles, changed=np.ones(79, bool))


def test_assert_closed_manifold_names_the_failures():
    with pytest.raises(RuntimeError, match="closed"):
        assert_closed_manifold(TET_V, TET_F[:3])
    with pytest.raises(RuntimeError, match="positive volume"):
        assert_closed_manifold(TET_V, TET_F[:, ::-1])


def test_signed_volume_is_translation_invariant():
    assert signed_volume(TET_V + 1e6, TET_F) == pytest.approx(1 / 6, rel=1e-9)


def test_check_accepts_tensor_meshes():
    legacy = o3d.geometry.TriangleMesh.create_sphere()
    report = check_watertight(o3d.t.geometry.TriangleMesh.from_legacy(legacy), self_intersection=False)
    assert report.watertight and report.self_intersecting_pairs is None


def test_bad_mesh_type():
    with pytest.raises(TypeError, match="mesh must be"):
        check_watertight("not a mesh")


@pytest.mark.parametrize("mesh, match", [
    ((TET_V, np.zeros((0, 3), int)), "mesh has no triangles"),
    ((np.where(TET_V == 1, np.nan, TET_V), TET_F), "mesh vertices holds 3 rows with NaN or inf"),
    ((TET_V, TET_F + 1), r"mesh triangles index vertices outside \[0, 4\)"),
    ((TET_V[:, :2], TET_F), r"mesh vertices must have shape \(n, 3\)"),
])
def test_bad_mesh_arrays(mesh, match):
    with pytest.raises(ValueError, match=match):
        check_watertight(mesh)
