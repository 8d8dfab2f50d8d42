"""Bilateral normal filtering: noisy flat faces come out flat, sharp edges stay sharp."""
import numpy as np
import open3d as o3d
import pytest

from voro3d.io import mesh_arrays
from voro3d.pointcloud.denoise import bilateral_filter


def noisy_cube(noise=0.01, subdivisions=4):
    """A unit cube of ~3k triangles, its vertices moved along random directions by ``noise``."""
    mesh = o3d.geometry.TriangleMesh.create_box().subdivide_midpoint(subdivisions)
    vertices, triangles = mesh_arrays(mesh)
    rng = np.random.default_rng(0)
    return vertices, vertices + rng.normal(scale=noise, size=vertices.shape), triangles


def off_axis_degrees(vertices, triangles):
    """(t,) angle of each face normal to the nearest axis direction (the cube's true normals)."""
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    return np.degrees(np.arccos(np.clip(np.abs(normals).max(axis=1), -1, 1)))


def test_noisy_cube_faces_come_out_flat_and_its_edges_sharp():
    true, noisy, triangles = noisy_cube()
    filtered = bilateral_filter(noisy, triangles, width=0.05)
    before, after = off_axis_degrees(noisy, triangles), off_axis_degrees(filtered, triangles)
    assert np.median(after) < 0.3 * np.median(before)  # flat faces
    assert (after > 30).mean() < 0.5 * (before > 30).mean() + 1e-9
    # Sharp edges and corners: the cube's corners stay within the noise of where they were, where
    # Laplacian smoothing would round them off.
    corner = np.all(np.isin(true, (0.0, 1.0)), axis=1)
    assert np.abs(filtered[corner] - true[corner]).max() < 0.05
    # No shrinking: the box of the vertices stays the unit cube's.
    assert np.abs(np.ptp(filtered, axis=0) - 1).max() < 0.05


def test_a_clean_mesh_stays_where_it_is():
    # Faces at right angles weigh exp(-1 / 0.35^2) = 3e-4 in each other's normal: the vertices near
    # the edges move by under 1e-4 of the cube (measured 8.5e-5).
    true, _, triangles = noisy_cube()
    moved = np.linalg.norm(bilateral_filter(true, triangles, width=0.05) - true, axis=1)
    assert moved.max() < 2e-4


def test_a_mesh_smaller_than_the_neighbourhood_is_filtered_too():
    vertices, triangles = mesh_arrays(o3d.geometry.TriangleMesh.create_tetrahedron())
    assert np.allclose(bilateral_filter(vertices, triangles[:1], width=1.0, neighbours=64), vertices)
    assert np.isfinite(bilateral_filter(vertices, triangles, width=1.0)).all()


def _numpy_normal_passes(normals, near, spatial, normal_width, passes):
    """The passes as numpy states them: the kernel's reference."""
    filtered = normals.astype(np.float64)
    for _ in range(passes):
        gathered = filtered[near]
        weight = spatial * np.exp((np.einsum("tkd,td->tk", gathered, filtered) - 1.0) / normal_width**2)
        summed = np.einsum("tk,tkd->td", weight, gathered)
        filtered = summed / np.linalg.norm(summed, axis=1)[:, None]
    return filtered


def test_the_compiled_normal_passes_match_numpy_on_any_thread_count():
    from voro3d import _fitkernel

    rng = np.random.default_rng(0)
    normals = rng.normal(size=(500, 3))
    normals = (normals / np.linalg.norm(normals, axis=1)[:, None]).astype(np.float32)
    near = np.concatenate([np.arange(500)[:, None], rng.integers(0, 500, size=(500, 11))], axis=1)
    spatial = rng.random((500, 12)).astype(np.float32)
    expected = _numpy_normal_passes(normals, near, spatial, 0.35, 3)
    one = _fitkernel.bilateral_normals(normals, near, spatial, normal_width=0.35, passes=3, threads=1)
    assert np.abs(one - expected).max() < 1e-5
    np.testing.assert_array_equal(_fitkernel.bilateral_normals(normals, near, spatial, normal_width=0.35, passes=3,
                                                               threads=3), one)
    np.testing.assert_array_equal(_fitkernel.bilateral_normals(normals, near, spatial, normal_width=0.35, passes=0),
                                  normals)


@pytest.mark.parametrize("change, message", [
    (dict(near=np.full((4, 2), 4)), "near holds 4"),
    (dict(spatial=np.ones((4, 3), np.float32)), "spatial must have"),
    (dict(normal_width=0.0), "normal_width"),
    (dict(passes=-1), "passes"),
    (dict(threads=0), "threads"),
])
def test_the_compiled_normal_passes_refuse_bad_input(change, message):
    from voro3d import _fitkernel

    arguments = dict(normals=np.eye(3, dtype=np.float32)[[0, 1, 2, 0]], near=np.zeros((4, 2), np.int64),
                     spatial=np.ones((4, 2), np.float32), normal_width=0.35, passes=1, threads=1) | change
    with pytest.raises(ValueError, match=message):
        _fitkernel.bilateral_normals(**arguments)
