"""Tests for voro3d.sampling: surface samples, inside/outside, signed distances, winding numbers."""
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from voro3d.io import fit_frame, load_mesh, mesh_arrays
from voro3d.sampling import (InsideOutside, grid_nodes, open_edge_count, sample_surface, sdf_grid,
                             winding_number)

DEV = Path(__file__).resolve().parents[2] / "shared" / "data" / "dev"
needs_dev = pytest.mark.skipif(not DEV.is_dir(), reason=f"dev meshes not found at {DEV}")


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


# -- sample_surface -------------------------------------------------------------------------------

def test_samples_lie_on_the_surface_with_outward_face_normals(cube):
    points, normals = sample_surface(cube, 5000, seed=3)
    assert points.shape == normals.shape == (5000, 3)
    assert points.dtype == normals.dtype == np.float64
    np.testing.assert_allclose(np.abs(points - 0.5).max(axis=1), 0.5, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    # Each normal is the axis of the face the point lies on, pointing away from the centre.
    np.testing.assert_allclose(np.abs(normals).max(axis=1), 1.0)
    assert (np.einsum("ij,ij->i", normals, points - 0.5) > 0.49).all()


def test_samples_are_area_weighted_and_uniform():
    # Two triangles of areas 0.5 and 1.5; points are uniform inside the unit right triangle.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [10, 0, 0], [13, 0, 0], [10, 1, 0]], float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    points, _ = sample_surface((vertices, triangles), 40_000, seed=0)
    first = points[:, 0] < 5
    assert first.mean() == pytest.approx(0.25, abs=0.01)
    # In the right triangle x + y <= 1, E[x] = E[y] = 1/3.
    np.testing.assert_allclose(points[first, :2].mean(axis=0), 1 / 3, atol=0.01)
    assert (points[first, :2].sum(axis=1) <= 1 + 1e-12).all()


def test_zero_area_faces_are_never_sampled():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    triangles = np.array([[0, 1, 3], [0, 1, 2], [1, 3, 0]])  # first and last are collinear
    _, normals = sample_surface((vertices, triangles), 2000)
    np.testing.assert_array_equal(normals, np.tile([0.0, 0.0, 1.0], (2000, 1)))


def test_sampling_is_deterministic(sphere):
    first = sample_surface(sphere, 1000, seed=7)
    again = sample_surface(sphere, 1000, seed=7)
    other = sample_surface(sphere, 1000, seed=8)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])
    assert not np.array_equal(first[0], other[0])


def test_sample_surface_errors(sphere):
    with pytest.raises(ValueError, match="n must be >= 1"):
        sample_surface(sphere, 0)
    with pytest.raises(TypeError, match="n must be an integer"):
        sample_surface(sphere, 10.0)
    with pytest.raises(ValueError, match="zero surface area"):
        sample_surface((np.zeros((3, 3)), np.array([[0, 1, 2]])), 10)
    with pytest.raises(ValueError, match="no triangles"):
        sample_surface((np.zeros((3, 3)), np.zeros((0, 3), int)), 10)


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
    assert winding_number(vertices, upper, np.zeros((1, 3)))[0] == pytest.approx(0.5, abs=1e-3)


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


# -- grid_nodes / sdf_grid ------------------------------------------------------------------------

def test_grid_nodes_layout():
    nodes = grid_nodes(5)
    assert nodes.shape == (125, 3) and nodes.dtype == np.float64
    grid = nodes.reshape(5, 5, 5, 3)
    np.testing.assert_array_equal(grid[4, 1, 2], [1.0, -0.5, 0.0])
    np.testing.assert_array_equal(grid[0, 0, 0], [-1, -1, -1])
    np.testing.assert_array_equal(grid[-1, -1, -1], [1, 1, 1])
    with pytest.raises(ValueError, match="grid must be >= 2"):
        grid_nodes(1)


@settings(max_examples=10, deadline=None)
@given(grid=st.integers(2, 12))
def test_grid_nodes_index_formula(grid):
    index = np.arange(grid**3)
    i, j, k = np.unravel_index(index, (grid,) * 3)
    np.testing.assert_allclose(grid_nodes(grid), -1 + 2 * np.stack([i, j, k], axis=1) / (grid - 1))


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

@needs_dev
@pytest.mark.parametrize("name", ["organic_bunny.off", "cad_fandisk.obj"])
def test_dev_sdf_sign_agrees_with_winding_number(name):
    mesh = load_mesh(DEV / name)
    mesh = fit_frame(mesh).apply_mesh(mesh)
    sdf = sdf_grid(mesh, 32).reshape(-1)
    assert 0.01 < (sdf < 0).mean() < 0.5
    vertices, triangles = mesh_arrays(mesh)
    pick = np.random.default_rng(0).choice(sdf.size, 300, replace=False)
    pick = np.concatenate([pick, np.flatnonzero(sdf < 0)[:100]])
    winding = winding_number(vertices, triangles, grid_nodes(32)[pick])
    np.testing.assert_array_equal(sdf[pick] < 0, winding > 0.5)


@needs_dev
def test_dev_grid_nodes_where_open3d_occupancy_is_wrong():
    # On this self-intersecting Thingi32 mesh, Open3D's compute_occupancy (rays all near (1, 1, 1))
    # calls some 64^3 grid nodes far outside the shape "inside"; InsideOutside must not.
    mesh = load_mesh(DEV / "thingi32_76277.obj")
    mesh = fit_frame(mesh).apply_mesh(mesh)
    queries = InsideOutside(mesh)
    nodes = grid_nodes(64)
    ours = queries.occupancy(nodes)
    theirs = queries._scene.compute_occupancy(o3d.core.Tensor(nodes.astype(np.float32)), nsamples=3).numpy() > 0.5
    differ = np.flatnonzero(ours != theirs)
    assert differ.size > 0
    np.testing.assert_array_equal(ours[differ], queries.winding_number(nodes[differ]) > 0.5)


@needs_dev
def test_dev_open_mesh_needs_allow_open():
    mesh = load_mesh(DEV / "thingi32_96481.obj")
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
