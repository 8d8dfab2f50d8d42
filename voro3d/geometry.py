"""Geometry shared by the stages: face and vertex normals, triangle angles, graph components,
Open3D's raycasting scene, the voxel of a grid, midpoint subdivision."""
from __future__ import annotations

import numpy as np

__all__ = ["components", "face_area_vectors", "face_normals", "grid_voxel", "raycasting_scene", "smallest_angles",
           "subdivide_midpoint", "vertex_normals"]


def grid_voxel(grid: int) -> float:
    """The voxel of a ``grid^3`` grid of nodes spanning ``[-1, 1]^3`` (``2 / (grid - 1)``), in those units."""
    return 2.0 / (grid - 1)


def components(n_nodes: int, edges: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the graph on ``n_nodes`` nodes with ``edges`` ((e, 2) int): (count, (n_nodes,) label)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.asarray(edges).reshape(-1, 2)
    # bool: repeated edges (one per tetrahedron around a Delaunay edge) OR together, where int8 would wrap.
    graph = coo_matrix((np.ones(len(edges), bool), (edges[:, 0], edges[:, 1])), shape=(n_nodes, n_nodes))
    return connected_components(graph, directed=False)


def raycasting_scene(vertices: np.ndarray, triangles: np.ndarray):
    """Open3D's ``RaycastingScene`` over one triangle mesh (float32, as Open3D computes)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(triangles, np.uint32)))
    return scene


def face_area_vectors(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Each triangle's normal scaled by twice its area (the cross product of two sides), ``(t, 3)`` float64."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles)
    a = vertices[triangles[:, 0]]
    return np.cross(vertices[triangles[:, 1]] - a, vertices[triangles[:, 2]] - a)


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals of the triangles, ``(t, 3)`` float64; zero for a triangle of no area."""
    face = face_area_vectors(vertices, triangles)
    length = np.linalg.norm(face, axis=1, keepdims=True)
    return np.divide(face, length, out=np.zeros_like(face), where=length > 0)


def smallest_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The smallest angle of each triangle, ``(t,)`` degrees; 0 for a triangle with a side of length 0."""
    corners = np.asarray(vertices, np.float64)[np.asarray(triangles)]
    sides = np.linalg.norm(corners - corners[:, [1, 2, 0]], axis=2)  # side k joins corners k and k+1
    smallest = np.full(len(corners), 180.0)
    for k in range(3):
        a, b, c = sides[:, k], sides[:, (k + 1) % 3], sides[:, (k + 2) % 3]  # angle opposite side a
        with np.errstate(invalid="ignore", divide="ignore"):
            angle = np.degrees(np.arccos(np.clip((b**2 + c**2 - a**2) / (2 * b * c), -1, 1)))
        smallest = np.minimum(smallest, np.nan_to_num(angle, nan=0.0))
    return smallest


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(v, 3)`` float64; zero at vertices of no triangle of positive area."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles)
    face = face_area_vectors(vertices, triangles)
    corners = triangles.reshape(-1)
    n = vertices.shape[0]
    summed = np.stack([np.bincount(corners, weights=np.repeat(face[:, d], 3), minlength=n) for d in range(3)], axis=1)
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)


def subdivide_midpoint(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle split in four at the midpoints of its sides, the same surface with four times the triangles.

    A side shared by two triangles gets one midpoint, so a closed manifold stays closed and
    manifold; the children keep their parent's orientation. Returns ``(vertices, triangles)``: the
    ``(v, 3)`` input vertices first, then one midpoint per side; ``(4 t, 3)`` int64 triangles.
    """
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles, np.int64)
    sides = triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)  # side k of a triangle joins corners k, k+1
    unique, side_index = np.unique(np.sort(sides, axis=1), axis=0, return_inverse=True)
    middle = vertices.shape[0] + side_index.reshape(-1, 3)
    a, b, c = triangles.T
    ab, bc, ca = middle.T
    children = np.stack([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]], axis=1)
    midpoints = 0.5 * (vertices[unique[:, 0]] + vertices[unique[:, 1]])
    return np.vstack([vertices, midpoints]), children.reshape(-1, 3)
