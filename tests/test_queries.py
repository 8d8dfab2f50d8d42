"""Tests for voro3d.queries: inside/outside, signed distances, winding numbers."""
import numpy as np
import open3d as o3d
import pytest

from voro3d.frames import fit_frame

from voro3d.io import load_mesh, mesh_arrays
from voro3d.queries import InsideOutside, sdf_grid, winding_number
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


def test_open_mesh_occupancy_equals_the_exact_winding_number_test(sphere):
    vertices, triangles = sphere
    bowl = triangles[vertices[triangles].mean(axis=1)[:, 2] > -0.3]
    rng = np.random.default_rng(5)
    # Random points, and points near the bowl's opening, where the winding number is near 0.5
    # and the fast estimate hands over to the exact sum.
    opening = np.column_stack([rng.uniform(-0.3, 0.3, (500, 2)), rng.uniform(-0.33, -0.27, 500)])
    points = np.vstack([rng.uniform(-0.7, 0.7, (1500, 3)), opening])
    exact = winding_number(vertices, bowl, points)
    assert (np.abs(exact - 0.5) < 0.05).sum() > 50
    inside = InsideOutside((vertices, bowl), allow_open=True).occupancy(points)
    np.testing.assert_array_equal(inside, exact > 0.5)


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
    theirs = queries._scene.compute_occupancy(o3d.core.Tensor(nodes.astype(np.float32)), nsamples=3).numpy() > 0.5
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
