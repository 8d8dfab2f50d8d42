"""Shared geometry helpers: normals, angles, components, the raycasting scene, the grid voxel."""
import numpy as np
import pytest

from voro3d.geometry import (components, face_area_vectors, face_normals, grid_voxel, raycasting_scene,
                             smallest_angles, vertex_normals)

TRIANGLE = (np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0], [5, 5, 5]]), np.array([[0, 1, 2], [3, 3, 3]]))


def test_face_normals_and_areas():
    area = face_area_vectors(*TRIANGLE)
    np.testing.assert_array_equal(area, [[0, 0, 2], [0, 0, 0]])  # twice the area along +z; a point has none
    np.testing.assert_array_equal(face_normals(*TRIANGLE), [[0, 0, 1], [0, 0, 0]])
    np.testing.assert_allclose(vertex_normals(*TRIANGLE), [[0, 0, 1]] * 3 + [[0, 0, 0]])
    np.testing.assert_allclose(smallest_angles(*TRIANGLE)[0], np.degrees(np.arctan(0.5)))


def test_grid_voxel():
    assert grid_voxel(3) == 1.0 and grid_voxel(33) == pytest.approx(2 / 32)


def test_components_with_repeated_edges():
    """An edge repeated 300 times (one per tetrahedron around it) still joins its ends."""
    edges = np.array([[0, 1]] * 300 + [[2, 3]])
    count, label = components(5, edges)
    assert count == 3 and label[0] == label[1] and label[2] == label[3] and len(set(label.tolist())) == 3


def test_raycasting_scene_distance():
    scene = raycasting_scene(*TRIANGLE)
    import open3d as o3d

    distance = scene.compute_distance(o3d.core.Tensor(np.array([[0.5, 0.25, 3.0]], np.float32))).numpy()
    assert distance[0] == pytest.approx(3.0)


def test_split_triangles_splits_each_triangle_in_four_and_keeps_the_surface():
    import trimesh

    from voro3d.geometry import split_triangles

    sphere = trimesh.creation.icosphere(1)
    vertices, triangles, splits = split_triangles(sphere.vertices, sphere.faces, 1)
    split = trimesh.Trimesh(vertices, triangles, process=False)
    assert splits == 1 and len(triangles) == 4 * len(sphere.faces)
    assert len(vertices) == len(sphere.vertices) + len(sphere.edges_unique)
    np.testing.assert_array_equal(vertices[: len(sphere.vertices)], sphere.vertices)
    assert split.is_watertight and split.is_winding_consistent  # one midpoint per shared side
    assert split.area == pytest.approx(sphere.area) and split.volume == pytest.approx(sphere.volume)  # outward still
    # The four children of triangle i, rows 4i to 4i + 3, face as their parent does.
    np.testing.assert_allclose(face_normals(vertices, triangles),
                               np.repeat(face_normals(sphere.vertices, sphere.faces), 4, axis=0), atol=1e-12)
    assert len(split_triangles(sphere.vertices, sphere.faces, 2)[1]) == 16 * len(sphere.faces)
    unsplit = split_triangles(sphere.vertices, sphere.faces, 0)
    assert unsplit[2] == 0 and np.array_equal(unsplit[1], sphere.faces)
