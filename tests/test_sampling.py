"""Tests for voro3d.sampling: surface samples and grid nodes."""
import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from voro3d.io import mesh_arrays
from voro3d.sampling import grid_nodes, sample_surface


@pytest.fixture(scope="module")
def sphere():
    return mesh_arrays(o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=40))


@pytest.fixture(scope="module")
def cube():
    return mesh_arrays(o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0))


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


def test_density_weights_the_faces():
    # Equal areas, density 3:1; a zero density is never sampled.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [10, 0, 0], [11, 0, 0], [10, 1, 0], [20, 0, 0], [21, 0, 0],
                         [20, 1, 0]], float)
    triangles = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    points, _ = sample_surface((vertices, triangles), 40_000, seed=0, density=[3.0, 1.0, 0.0])
    assert (points[:, 0] < 5).mean() == pytest.approx(0.75, abs=0.01)
    assert not (points[:, 0] > 15).any()
    np.testing.assert_array_equal(sample_surface((vertices, triangles), 100, seed=1, density=[1.0, 1.0, 1.0])[0],
                                  sample_surface((vertices, triangles), 100, seed=1)[0])
    for bad in ([1.0, 1.0], [1.0, -1.0, 1.0], [1.0, np.nan, 1.0]):
        with pytest.raises(ValueError, match="density must be 3 finite numbers >= 0"):
            sample_surface((vertices, triangles), 10, density=bad)


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
    with pytest.raises(ValueError, match="n_samples must be >= 1"):
        sample_surface(sphere, 0)
    with pytest.raises(TypeError, match="n_samples must be an integer"):
        sample_surface(sphere, 10.0)
    with pytest.raises(ValueError, match="zero surface area"):
        sample_surface((np.zeros((3, 3)), np.array([[0, 1, 2]])), 10)
    with pytest.raises(ValueError, match="no triangles"):
        sample_surface((np.zeros((3, 3)), np.zeros((0, 3), int)), 10)


# -- grid_nodes -----------------------------------------------------------------------------------

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
