"""Mesh geometry shared by the stages: face and vertex normals, triangle angles."""
from __future__ import annotations

import numpy as np

__all__ = ["face_area_vectors", "face_normals", "smallest_angles", "vertex_normals"]


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
