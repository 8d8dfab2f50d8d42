"""Bilateral normal filtering of a target mesh: the bumps a heavily noisy cloud leaves, taken out.

The IMLS pass and Poisson average the noise over a kernel a few noise deviations wide; what is
left is a surface that undulates at about that scale (fandisk at 0.5% noise: a lumpy top and
sides). Filtering the face normals (Zheng et al. 2011, "Bilateral normal filtering for mesh
denoising") averages each over the faces near it whose normals are close to its own, so flat
parts come out flat while sharp edges, where the normals differ by more than the range width,
stay sharp; the vertices then move to fit the filtered normals' planes (their least-squares
update, which unlike Laplacian smoothing does not shrink the surface).
"""
from __future__ import annotations

import numpy as np

from ..geometry import face_area_vectors

__all__ = ["bilateral_filter"]

# Faces that enter one normal's average: the spatial Gaussian is cut off there.
NEIGHBOURS = 64
# Width of the range Gaussian on |n_i - n_j|: faces across an edge sharper than ~40 degrees
# (|n_i - n_j| over 0.7, two widths) barely count.
NORMAL_WIDTH = 0.35
NORMAL_PASSES = 10
VERTEX_PASSES = 10


def _face_frames(vertices, triangles):
    """Centroids (t, 3), unit normals (t, 3) and areas (t,) of the triangles."""
    corners = vertices[triangles]
    normals = face_area_vectors(vertices, triangles)
    length = np.linalg.norm(normals, axis=1)
    return corners.mean(axis=1), normals / np.maximum(length, 1e-300)[:, None], length / 2


def bilateral_filter(vertices, triangles, *, width: float, normal_width: float = NORMAL_WIDTH,
                     neighbours: int = NEIGHBOURS, normal_passes: int = NORMAL_PASSES,
                     vertex_passes: int = VERTEX_PASSES) -> np.ndarray:
    """Vertices of a mesh moved to fit its bilaterally filtered face normals.

    Parameters
    ----------
    vertices : (v, 3) float64
    triangles : (t, 3) int64
    width : float
        Standard deviation of the spatial Gaussian, in the vertices' units (about twice the
        cloud's noise deviation).
    normal_width : float
        Standard deviation of the range Gaussian on the difference of unit normals.
    neighbours : int
        Nearest faces (by centroid) averaged over, the face itself included.
    normal_passes, vertex_passes : int
        Filtering passes over the normals, then update passes over the vertices.

    Returns
    -------
    (v, 3) float64
        The triangles are unchanged.
    """
    from scipy.spatial import cKDTree

    from .. import _fitkernel
    from .._system import available_cpus

    vertices = np.array(vertices, np.float64)
    triangles = np.asarray(triangles, np.int64)
    centroids, normals, areas = _face_frames(vertices, triangles)
    k = min(neighbours, len(triangles))
    distance, near = (found.reshape(len(triangles), k)
                      for found in cKDTree(centroids).query(centroids, k=k, workers=-1))
    spatial = (np.exp(-0.5 * (distance / width) ** 2) * areas[near]).astype(np.float32)
    # The compiled passes (float32 normals, double sums): 95k faces of a noisy bunny's target, 10
    # passes, 0.2 s against numpy's 2.1 s, whose (t, k, 3) gathers took the time.
    filtered = _fitkernel.bilateral_normals(normals.astype(np.float32), near, spatial, normal_width=normal_width,
                                            passes=normal_passes, threads=available_cpus())
    filtered = filtered.astype(np.float64)
    n = len(vertices)
    faces_at = np.maximum(np.bincount(triangles.ravel(), minlength=n), 1).astype(np.float64)
    for _ in range(vertex_passes):
        centroids = vertices[triangles].mean(axis=1)
        move = np.zeros_like(vertices)
        for corner in range(3):
            along = np.einsum("td,td->t", filtered, centroids - vertices[triangles[:, corner]])[:, None] * filtered
            for axis in range(3):
                move[:, axis] += np.bincount(triangles[:, corner], along[:, axis], minlength=n)
        vertices += move / faces_at[:, None]
    return vertices
