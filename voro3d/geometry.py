"""Geometry shared by the stages: face and vertex normals, triangle angles, graph components,
Open3D's raycasting scene, the voxel of a grid, midpoint splits."""
from __future__ import annotations

import numpy as np

__all__ = ["centred_scene", "components", "face_area_vectors", "face_normals", "grid_voxel", "raycasting_scene", "smallest_angles",
           "split_triangles", "vertex_normals"]


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


def centred_scene(vertices: np.ndarray, triangles: np.ndarray):
    """:func:`raycasting_scene` of the mesh moved by minus its bounding box's centre, and that centre
    (3,): query it with points minus the centre. Open3D computes in float32, whose step is 0.5 at
    5e6 (map coordinates); about the centre it is relative to the mesh's size."""
    vertices = np.asarray(vertices, np.float64)
    origin = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return raycasting_scene(vertices - origin, triangles), origin


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



def split_triangles(vertices: np.ndarray, triangles: np.ndarray, times: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The mesh with each triangle split in four at the midpoints of its sides (Open3D's
    ``subdivide_midpoint``: one midpoint per shared side, the children facing as their parent),
    ``times`` times, or fewer, down to none, while that makes triangles cross (exact test).

    A split moves no surface, but its midpoints are rounded, and a fold the mesh held (which the
    exact test once let through between neighbours) is split into pairs that are no longer
    neighbours: 3 of 12 dev meshes at 20k points, coloured (:func:`voro3d.pointcloud.colored_mesh`).

    Returns ``(vertices, triangles, splits)``: ``(v, 3)`` float64, ``(4^splits t, 3)`` int64, and
    the splits made. The first vertices are the input's, and the pieces of triangle ``i`` are
    triangles ``4^splits i`` to ``4^splits (i + 1) - 1``.
    """
    from .io import mesh_arrays, to_triangle_mesh
    from .watertight import self_intersections

    mesh = to_triangle_mesh(vertices, triangles)
    while times:
        split = mesh_arrays(mesh.subdivide_midpoint(number_of_iterations=times))
        if not len(self_intersections(*split)[0]):
            return (*split, times)
        times -= 1
    return np.asarray(vertices, np.float64), np.asarray(triangles, np.int64), 0
