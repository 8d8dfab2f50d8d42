"""A coloured cloud's colours carried onto its reconstruction.

A VoroMesh has few, large faces (a 20k-point cloud: about 6k vertices), and vertex colours are
interpolated across a face, so colours that vary faster than the faces are blurred away. The
coloured mesh is therefore split flat (each triangle into four at its edge midpoints:
``TriangleMesh.subdivide_midpoint``, which moves no surface, so it stays closed) until it has
about as many vertices as the cloud has points, at most ``MAX_COLOUR_SPLITS`` times, and each
vertex takes the colour of the points around it. A split whose pieces cross (see
:func:`colored_mesh`) is not kept: fewer splits are.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MAX_COLOUR_SPLITS", "colored_mesh", "transfer_colors"]

# Midpoint splits of a coloured mesh at most (each quadruples the faces).
MAX_COLOUR_SPLITS = 3


def colored_mesh(mesh, points: np.ndarray, colors: np.ndarray):
    """``mesh`` split flat until it has about one vertex per point, its vertices coloured from the cloud.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh
        Closed; not modified.
    points : (n, 3) float64
    colors : (n, 3) float64
        RGB in [0, 1].

    Returns
    -------
    open3d.geometry.TriangleMesh
        The same surface, with ``4^s`` times the faces for the fewest ``s <= MAX_COLOUR_SPLITS``
        that give at least ``n`` vertices, vertex colours (:func:`transfer_colors`) and normals.
    """
    import open3d as o3d

    from ..geometry import split_triangles
    from ..io import mesh_arrays, to_triangle_mesh

    vertices = max(len(mesh.vertices), 1)
    # Each split adds about three vertices per old one (a closed mesh has half as many vertices as faces).
    splits = int(np.clip(np.ceil(np.log(max(points.shape[0] / vertices, 1.0)) / np.log(4.0)), 0, MAX_COLOUR_SPLITS))
    # A split whose pieces cross is not kept: fewer splits are, down to none.
    split = to_triangle_mesh(*split_triangles(*mesh_arrays(mesh), splits)[:2])
    split.vertex_colors = o3d.utility.Vector3dVector(transfer_colors(np.asarray(split.vertices), points, colors))
    split.compute_vertex_normals()
    return split


def transfer_colors(vertices: np.ndarray, points: np.ndarray, colors: np.ndarray, *, k: int = 8) -> np.ndarray:
    """Colours at mesh vertices from a coloured cloud: inverse-distance mean of the ``k`` nearest points.

    Parameters
    ----------
    vertices : (v, 3) float64
    points : (n, 3) float64
    colors : (n, 3) float64
        RGB in [0, 1].

    Returns
    -------
    (v, 3) float64
    """
    from scipy.spatial import cKDTree

    distance, neighbour = cKDTree(points).query(vertices, k=min(k, points.shape[0]), workers=-1)
    distance, neighbour = distance.reshape(len(vertices), -1), neighbour.reshape(len(vertices), -1)
    weight = 1.0 / np.maximum(distance, 1e-12 * max(float(np.ptp(points)), 1e-300))
    return np.clip(np.einsum("vk,vkc->vc", weight, colors[neighbour]) / weight.sum(axis=1, keepdims=True), 0.0, 1.0)
