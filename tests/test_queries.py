"""Tests for voro3d.queries: inside/outside, signed distances, winding numbers."""
import igl
import numpy as np
import open3d as o3d
import pytest

from voro3d.frames import fit_frame

from voro3d.io import load_mesh, mesh_arrays
from voro3d.queries import FAST_WINDING_MARGIN, InsideOutside, sdf_grid, winding_number
from voro3d.sampling import grid_nodes
from voro3d.topology import open_edge_count


def sphere_arrays(radius=0.5, resolution=40):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)


def brute_force_winding(vertices, triangles, queries):
    """Reference: the Van Oosterom-Strackee formula on explicit (n, t, 3) differences."""
    a, b, c = (vertices[triangles[:, i]][None] - queries[:, None] for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    numerator = np.einsum("qti,qti->qt", a, np.cross(b, c))
    denominator = la * lb * lc + (a * b).sum(2) * lc + (b * c).sum(2) * la + (c * a).sum(2) * lb
    return np.arctan2(numerator, denominator).sum(axis=1) / (2 * np.pi)


@pytest.fixture(scope="module")
def sphere():
    return sphere_arrays()


@pytest.fixture(scope="module")
def cube():
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    return np.asarray(box.vertices).copy(), np.asarray(box.triangles).astype(np.int64)


# -- winding_number -------------------------------------------------------------------------------

def test_winding_number_inside_outside_and_inverted(sphere):
    vertices, triangles = sphere
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(300, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = rng.uniform(0, 1.5, size=(300, 1))
    radii = radii[np.abs(radii[:, 0] - 0.5) > 0.02]  # the polyhedron is within 0.002 of the sphere
    queries = directions[:radii.shape[0]] * radii
    inside = radii[:, 0] < 0.5
    winding = winding_number(vertices, triangles, queries)
    np.testing.assert_allclose(winding[inside], 1.0, atol=1e-9)
    np.testing.assert_allclose(winding[~inside], 0.0, atol=1e-9)
    flipped = winding_number(vertices, triangles[:, ::-1], queries)
    np.testing.assert_allclose(flipped, -winding, atol=1e-9)


def test_winding_number_matches_brute_force_and_ignores_chunking(sphere):
    vertices, triangles = sphere_arrays(radius=0.5, resolution=8)
    queries = np.random.default_rng(1).uniform(-0.8, 0.8, size=(200, 3))
    expected = brute_force_winding(vertices, triangles, queries)
    np.testing.assert_allclose(winding_number(vertices, triangles, queries), expected, atol=1e-10)
    np.testing.assert_allclose(winding_number(vertices, triangles, queries, chunk=7), expected, atol=1e-10)


def test_winding_number_of_an_open_hemisphere_is_half_at_the_centre(sphere):
    vertices, triangles = sphere
    upper = triangles[vertices[triangles].mean(axis=1)[:, 2] > 0]
    # libigl's igl.winding_number gives 0.26-0.99 here, varying with the call (benchmarks/bench_winding.py).
    for n in (1, 2, 1000):
        points = np.vstack([np.zeros((1, 3)), np.random.default_rng(n).uniform(-1, 1, (n - 1, 3))])
        assert winding_number(vertices, upper, points)[0] == pytest.approx(0.5, abs=1e-9)


def test_winding_number_errors(sphere):
    vertices, triangles = sphere
    with pytest.raises(ValueError, match="mesh_triangles must be an integer array"):
        winding_number(vertices, triangles.astype(float), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="mesh_triangles index vertices outside"):
        winding_number(vertices, triangles + 1000, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="mesh_triangles holds no triangles"):
        winding_number(vertices, np.zeros((0, 3), int), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="queries must have shape"):
        winding_number(vertices, triangles, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="chunk must be >= 1"):
        winding_number(vertices, triangles, np.zeros((1, 3)), chunk=0)
    assert winding_number(vertices, triangles, np.zeros((0, 3))).shape == (0,)


# -- InsideOutside --------------------------------------------------------------------------------

def test_inside_outside_on_a_sphere(sphere):
    queries = InsideOutside(sphere)
    points = np.random.default_rng(2).uniform(-1, 1, size=(5000, 3))
    radius = np.linalg.norm(points, axis=1)
    signed = queries.signed_distance(points)
    assert signed.shape == (5000,) and signed.dtype == np.float64
    # The resolution-40 polyhedron lies within 0.002 of the sphere.
    np.testing.assert_allclose(signed, radius - 0.5, atol=2e-3)
    np.testing.assert_array_equal(queries.occupancy(points), signed < 0)
    np.testing.assert_allclose(queries.unsigned_distance(points), np.abs(signed))
    far = np.abs(radius - 0.5) > 0.01
    np.testing.assert_array_equal(queries.occupancy(points)[far], radius[far] < 0.5)


def test_closest_points_and_outward_normals(sphere):
    queries = InsideOutside(sphere)
    points = np.random.default_rng(3).normal(size=(500, 3))
    closest, normals = queries.closest(points)
    np.testing.assert_allclose(np.linalg.norm(closest, axis=1), 0.5, atol=3e-3)
    direction = closest / np.linalg.norm(closest, axis=1, keepdims=True)
    assert (np.einsum("ij,ij->i", normals, direction) > 0.99).all()


def test_inside_outside_accepts_open3d_mesh_and_empty_queries():
    queries = InsideOutside(o3d.geometry.TriangleMesh.create_box())
    assert queries.occupancy(np.array([[0.5, 0.5, 0.5], [2, 2, 2]])).tolist() == [True, False]
    assert queries.occupancy(np.zeros((0, 3))).shape == (0,)
    assert queries.signed_distance(np.zeros((0, 3))).shape == (0,)
    assert queries.closest(np.zeros((0, 3)))[0].shape == (0, 3)


def test_grid_aligned_queries_on_a_grid_aligned_mesh():
    # Queries on the planes of a box's edges are where a single ray most easily grazes an edge.
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    box.translate([-0.5, -0.5, -0.5])
    box = box.subdivide_midpoint(2)
    nodes = grid_nodes(17)
    expected = (np.abs(nodes) < 0.5 - 1e-9).all(axis=1)
    on_surface = np.isclose(np.abs(nodes).max(axis=1), 0.5)
    got = InsideOutside(box).occupancy(nodes)
    np.testing.assert_array_equal(got[~on_surface], expected[~on_surface])


def test_open_mesh_is_refused_unless_allowed(sphere):
    vertices, triangles = sphere
    upper = triangles[vertices[triangles].mean(axis=1)[:, 2] > -0.3]  # a bowl, open at the bottom
    with pytest.raises(ValueError, match="open boundary or non-manifold edges"):
        InsideOutside((vertices, upper))
    queries = InsideOutside((vertices, upper), allow_open=True)
    assert not queries.closed
    inside = queries.occupancy(np.array([[0.0, 0.0, 0.2], [0.0, 0.0, 0.8], [0.0, 0.0, -0.45]]))
    assert inside.tolist() == [True, False, False]


def test_prepare_builds_ahead_and_answers_the_same(sphere):
    """prepare() does ahead of time what the first inside test would (a split Poisson target's half,
    while the other half is solved): the same answers, closed or not."""
    vertices, triangles = sphere
    bowl = triangles[vertices[triangles].mean(axis=1)[:, 2] > -0.3]
    points = np.random.default_rng(2).uniform(-0.7, 0.7, (400, 3))
    for mesh, closed in (((vertices, triangles), True), ((vertices, bowl), False)):
        ready = InsideOutside(mesh, allow_open=True)
        assert ready.prepare() is ready
        fresh = InsideOutside(mesh, allow_open=True)
        np.testing.assert_array_equal(ready.occupancy(points), fresh.occupancy(points))
        np.testing.assert_array_equal(ready.unsigned_distance(points), fresh.unsigned_distance(points))
        assert ready.closed is fresh.closed is closed


def test_open_mesh_occupancy_equals_the_exact_winding_number_test(sphere):
    vertices, triangles = sphere
    bowl = triangles[vertices[triangles].mean(axis=1)[:, 2] > -0.3]
    rng = np.random.default_rng(5)
    # Random points, and points near the bowl's opening, where the winding number is near 0.5
    # and the fast estimate hands over to the exact sum.
    opening = np.column_stack([rng.uniform(-0.3, 0.3, (500, 2)), rng.uniform(-0.33, -0.27, 500)])
    points = np.vstack([rng.uniform(-0.7, 0.7, (1500, 3)), opening])
    exact = winding_number(vertices, bowl, points)
    assert (np.abs(exact - 0.5) < FAST_WINDING_MARGIN).sum() > 20
    inside = InsideOutside((vertices, bowl), allow_open=True).occupancy(points)
    np.testing.assert_array_equal(inside, exact > 0.5)
    # The margin stands well clear of the fast estimate's error, so that no sign it leaves alone is wrong.
    fast = igl.fast_winding_number(vertices, bowl.astype(np.int64), points)
    assert np.abs(fast - exact).max() < FAST_WINDING_MARGIN / 2


def test_non_manifold_edge_is_refused(cube):
    vertices, triangles = cube
    extra = np.vstack([vertices, [[0.5, 0.5, 3.0]]])
    fin = np.vstack([triangles, [[triangles[0, 0], triangles[0, 1], 8]]])  # a third face on one edge
    assert open_edge_count(extra, fin) > 0
    with pytest.raises(ValueError, match="inside/outside is undefined"):
        InsideOutside((extra, fin))


def test_welding_makes_a_soup_closed(cube):
    vertices, triangles = cube
    soup = vertices[triangles].reshape(-1, 3)
    assert open_edge_count(soup, np.arange(soup.shape[0]).reshape(-1, 3)) == 0
    InsideOutside((soup, np.arange(soup.shape[0]).reshape(-1, 3)))


def test_inside_outside_input_errors(sphere):
    with pytest.raises(ValueError, match="points must have shape"):
        InsideOutside(sphere).occupancy(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN or inf"):
        InsideOutside(sphere).signed_distance(np.full((1, 3), np.nan))
    with pytest.raises(ValueError, match="no triangles"):
        InsideOutside((np.zeros((3, 3)), np.zeros((0, 3), int)))


# -- sdf_grid -------------------------------------------------------------------------------------

def test_sdf_grid_of_a_sphere(sphere):
    sdf = sdf_grid(sphere, 16)
    assert sdf.shape == (16, 16, 16) and sdf.dtype == np.float32
    exact = (np.linalg.norm(grid_nodes(16), axis=1) - 0.5).reshape(16, 16, 16)
    np.testing.assert_allclose(sdf, exact, atol=2e-3)


def test_sdf_grid_errors(sphere):
    with pytest.raises(ValueError, match="grid must be >= 2"):
        sdf_grid(sphere, 1)
    vertices, triangles = sphere
    with pytest.raises(ValueError, match="allow_open=True"):
        sdf_grid((vertices, triangles[10:]), 4)


# -- dev meshes -----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["organic_bunny.off", "cad_fandisk.obj"])
def test_dev_sdf_sign_agrees_with_winding_number(name, dev_meshes):
    mesh = load_mesh(dev_meshes / name)
    mesh = fit_frame(mesh).apply_mesh(mesh)
    sdf = sdf_grid(mesh, 32).reshape(-1)
    assert 0.01 < (sdf < 0).mean() < 0.5
    vertices, triangles = mesh_arrays(mesh)
    pick = np.random.default_rng(0).choice(sdf.size, 300, replace=False)
    pick = np.concatenate([pick, np.flatnonzero(sdf < 0)[:100]])
    winding = winding_number(vertices, triangles, grid_nodes(32)[pick])
    np.testing.assert_array_equal(sdf[pick] < 0, winding > 0.5)


def test_dev_grid_nodes_where_open3d_occupancy_is_wrong(dev_meshes):
    # On this self-intersecting Thingi32 mesh, Open3D's compute_occupancy (rays all near (1, 1, 1))
    # calls some 64^3 grid nodes far outside the shape "inside"; InsideOutside must not.
    mesh = load_mesh(dev_meshes / "thingi32_76277.obj")
    mesh = fit_frame(mesh).apply_mesh(mesh)
    queries = InsideOutside(mesh)
    nodes = grid_nodes(64)
    ours = queries.occupancy(nodes)
    theirs = queries.scene.compute_occupancy(o3d.core.Tensor(nodes.astype(np.float32)), nsamples=3).numpy() > 0.5
    differ = np.flatnonzero(ours != theirs)
    assert differ.size > 0
    np.testing.assert_array_equal(ours[differ], queries.winding_number(nodes[differ]) > 0.5)


def test_dev_open_mesh_needs_allow_open(dev_meshes):
    mesh = load_mesh(dev_meshes / "thingi32_96481.obj")
    with pytest.raises(ValueError, match="open boundary"):
        InsideOutside(mesh)
    queries = InsideOutside(mesh, allow_open=True)
    center = (mesh.get_min_bound() + mesh.get_max_bound()) / 2
    far = center + 10 * (mesh.get_max_bound() - mesh.get_min_bound())
    assert queries.occupancy(np.array([far])).tolist() == [False]


def test_inside_out_closed_mesh_keeps_its_inside(sphere):
    vertices, triangles = sphere
    points = np.random.default_rng(4).uniform(-1, 1, size=(2000, 3))
    far = np.abs(np.linalg.norm(points, axis=1) - 0.5) > 0.01
    inverted = InsideOutside((vertices, triangles[:, ::-1]))
    np.testing.assert_array_equal(inverted.occupancy(points)[far], InsideOutside(sphere).occupancy(points)[far])


# -- chunked kNN queries and point-cloud winding numbers -------------------------------------------

def _cloud(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    return points, points.copy()


def test_knn_blocks_answer_one_query_in_any_block_size():
    from scipy.spatial import cKDTree

    from voro3d.queries import knn_blocks

    points, _ = _cloud()
    tree = cKDTree(points)
    distance, neighbour = tree.query(points, k=9)
    for block in (1, 7, 500, None):
        seen = np.zeros(len(points), int)
        for rows, found_distance, found in knn_blocks(tree, 9, block=block):
            seen[rows] += 1
            assert np.array_equal(found, neighbour[rows]) and np.array_equal(found_distance, distance[rows])
        assert (seen == 1).all()
    rows = np.concatenate([rows for rows, _, _ in knn_blocks(tree, 9, sample=400, block=64)])
    again = np.concatenate([rows for rows, _, _ in knn_blocks(tree, 9, sample=400)])
    assert len(np.unique(rows)) == 400 and np.array_equal(np.sort(rows), np.sort(again))
    with pytest.raises(ValueError, match="block"):
        next(knn_blocks(tree, 9, block=0))


def test_point_areas_do_not_depend_on_the_block():
    from scipy.spatial import cKDTree

    from voro3d.queries import point_areas

    points, _ = _cloud()
    distance, _ = cKDTree(points).query(points, k=17)
    expected = np.pi * distance[:, -1] ** 2 / 16
    assert np.array_equal(point_areas(points, block=100), expected)
    assert np.array_equal(point_areas(points, tree=cKDTree(points)), expected)


def test_point_areas_with_normals_count_only_their_own_side():
    from scipy.spatial import cKDTree

    from voro3d.queries import neighbour_table, point_areas

    rng = np.random.default_rng(3)
    side = rng.choice([0, 1], 4000)
    plate = np.c_[rng.uniform(-1, 1, (4000, 2)), 0.01 * side]  # two sheets far closer than r_16
    normals = np.zeros_like(plate)
    normals[:, 2] = np.where(side == 1, 1.0, -1.0)
    # Each side covers the 2 x 2 square: with the far side counted, its areas sum to about half of it.
    both = point_areas(plate)
    assert abs(both[side == 1].sum() / 4.0 - 0.5) < 0.1
    areas = point_areas(plate, normals=normals)
    for one in (0, 1):
        assert 1.8 < areas[side == one].sum() / both[side == one].sum() < 2.2
    tree = cKDTree(plate)
    distance, index = neighbour_table(tree, 21)
    assert np.array_equal(point_areas(plate, distances=distance, indices=index, normals=normals, block=300), areas)
    assert np.array_equal(point_areas(plate, tree=tree, distances=distance, indices=index, normals=normals, block=300),
                          areas)  # rows in the tree's order
    # One side, all normals agreeing: the areas of no normals.
    assert np.array_equal(point_areas(plate, normals=np.tile([0.0, 0.0, 1.0], (4000, 1))), point_areas(plate))


def _exact_point_winding(points, normals, areas, queries):
    difference = points[None] - queries[:, None]
    length = np.linalg.norm(difference, axis=2)
    terms = np.einsum("qni,ni->qn", difference, areas[:, None] * normals) / np.where(length > 0, length, np.inf) ** 3
    return terms.sum(axis=1) / (4 * np.pi)


def test_point_winding_number_is_the_exact_sum_within_its_expansion_error():
    from voro3d import _fitkernel
    from voro3d.queries import point_areas, point_winding_number

    points, normals = _cloud(4000)
    areas = point_areas(points)
    rng = np.random.default_rng(1)
    queries = np.vstack([rng.uniform(-1.5, 1.5, (300, 3)), points[:100] * 0.97, points[:100] * 1.03, points[:20]])
    exact = _exact_point_winding(points, normals, areas, queries)
    fast = point_winding_number(points, normals, queries, areas=areas)
    assert np.abs(fast - exact).max() < 0.01
    assert np.abs(_fitkernel.point_winding_number(points, normals, areas, queries, beta=1e9) - exact).max() < 1e-10
    # Inside a closed sampled sphere about 1, outside about 0, on it about a half.
    assert np.allclose(fast[np.linalg.norm(queries, axis=1) < 0.9], 1.0, atol=0.05)
    assert np.allclose(fast[np.linalg.norm(queries, axis=1) > 1.1], 0.0, atol=0.05)
    assert np.allclose(fast[-20:], 0.5, atol=0.1)
    one = _fitkernel.point_winding_number(points, normals, areas, queries, threads=1)
    assert np.array_equal(one, _fitkernel.point_winding_number(points, normals, areas, queries, threads=3))


def test_point_winding_number_errors():
    from voro3d import _fitkernel
    from voro3d.queries import point_winding_number

    points, normals = _cloud(100)
    areas = np.ones(100)
    with pytest.raises(ValueError, match="normals"):
        point_winding_number(points, normals[:50], points)
    with pytest.raises(ValueError, match="normals"):
        _fitkernel.point_winding_number(points, normals[:50], areas, points)
    with pytest.raises(ValueError, match="areas"):
        _fitkernel.point_winding_number(points, normals, areas[:3], points)
    with pytest.raises(ValueError, match="queries"):
        _fitkernel.point_winding_number(points, normals, areas, points[:, :2])
    with pytest.raises(ValueError, match="beta"):
        _fitkernel.point_winding_number(points, normals, areas, points, beta=1.0)
    with pytest.raises(ValueError, match="threads"):
        _fitkernel.point_winding_number(points, normals, areas, points, threads=0)
    with pytest.raises(ValueError, match="at least one"):
        _fitkernel.point_winding_number(points[:0], normals[:0], areas[:0], points)
    assert point_winding_number(points, normals, points[:0]).shape == (0,)


def test_neighbour_table_is_one_query_with_int32_indices():
    from scipy.spatial import cKDTree

    from voro3d.queries import neighbour_table

    points, _ = _cloud(500)
    tree = cKDTree(points)
    distance, neighbour = tree.query(points, k=6)
    found_distance, found = neighbour_table(tree, 6)
    assert found.dtype == np.int32 and np.array_equal(found, neighbour) and np.array_equal(found_distance, distance)


def test_two_boxes_touching_along_an_edge_are_read_by_ray_parity(monkeypatch):
    """An edge of 4 triangles (two sheets touching, as Poisson leaves) keeps every edge even: ray
    parity stays valid there, and the winding number everywhere would take seconds on a target."""
    first = o3d.geometry.TriangleMesh.create_box()
    second = o3d.geometry.TriangleMesh.create_box().translate([1.0, 1.0, 0.0])
    both = first + second
    queries = InsideOutside(both, allow_open=True)
    assert not queries.closed
    monkeypatch.setattr(InsideOutside, "_winding_inside", lambda self, points: pytest.fail("winding everywhere"))
    inside = queries.occupancy(np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 0.5], [1.5, 0.5, 0.5], [0.5, 1.5, 0.5]]))
    assert inside.tolist() == [True, True, False, False]


def test_nearest_distance_is_the_exact_nearest_point_distance():
    from scipy.spatial import cKDTree

    from voro3d.queries import nearest_distance

    rng = np.random.default_rng(0)
    # A dense sheet and queries far off it, where the two searches differ most in speed.
    points = np.c_[rng.uniform(-1, 1, (20000, 2)), rng.normal(0, 1e-3, 20000)]
    queries = np.r_[rng.uniform(-1, 1, (500, 3)) + [0, 0, 2], points[:100]]
    found = nearest_distance(points, queries)
    assert found.shape == (600,) and np.allclose(found, cKDTree(points).query(queries)[0], rtol=1e-12, atol=0)
    assert np.all(found[500:] == 0.0)
