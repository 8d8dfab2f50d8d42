"""Surface samples and grid nodes: where the fit and the SDF grids look at a shape."""
from __future__ import annotations

import numpy as np

from ._validate import positive_int
from .geometry import face_area_vectors
from .io import mesh_arrays
from .rowblocks import map_rows

__all__ = ["sample_surface", "grid_nodes", "node_coordinates"]


def sample_surface(mesh, n_samples: int, *, seed: int = 0, density=None) -> tuple[np.ndarray, np.ndarray]:
    """Uniform area-weighted samples on a triangle mesh, with the normals of their faces.

    Faces are drawn with probability proportional to their area (times ``density``), then a point
    uniformly inside the face (square-root barycentric map). Unlike Open3D's sampler this is
    reproducible with ``seed``.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or (vertices, triangles)
    n_samples : int
        Number of samples, ``>= 1``.
    seed : int
        Seed of ``numpy.random.default_rng``; the same seed and mesh give the same samples.
    density : (t,) float, optional
        Relative samples per area of each face, ``>= 0`` (an adaptive fit's finer and coarser
        parts); default uniform.

    Returns
    -------
    points : (n_samples, 3) float64
        In the mesh's units.
    normals : (n_samples, 3) float64
        Unit face normals (right-hand rule over the triangle's vertex order).

    Raises
    ------
    ValueError
        ``mesh`` has no triangles or zero total area (weighted by ``density``); ``n_samples < 1``;
        ``density`` is not one finite number ``>= 0`` per face.
    """
    vertices, triangles = mesh_arrays(mesh)
    n = positive_int(n_samples, "n_samples")
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    cross = face_area_vectors(vertices, triangles)
    double_area = np.linalg.norm(cross, axis=1)
    if density is not None:
        density = np.asarray(density, dtype=np.float64)
        if density.shape != double_area.shape or not (np.isfinite(density).all() and (density >= 0).all()):
            raise ValueError(f"density must be {double_area.shape[0]} finite numbers >= 0, one per face")
    cdf = np.cumsum(double_area if density is None else double_area * density)
    if not cdf[-1] > 0:
        raise ValueError("mesh has zero surface area; nothing to sample")
    rng = np.random.default_rng(seed)
    draws = rng.random(n) * cdf[-1]
    r1, r2 = rng.random((2, n, 1))

    def samples(draw, r1, r2):
        # side="right" never selects a zero-area face: its cdf step is empty.
        face = np.searchsorted(cdf, draw, side="right")
        face = np.minimum(face, triangles.shape[0] - 1)  # guards the measure-zero draw of exactly cdf[-1]
        root = np.sqrt(r1)
        points = (1 - root) * a[face] + root * (1 - r2) * b[face] + root * r2 * c[face]
        return points, cross[face] / double_area[face, None]

    return map_rows(samples, draws, r1, r2)


def grid_nodes(grid: int) -> np.ndarray:
    """Nodes of a ``grid^3`` lattice spanning ``[-1, 1]^3`` inclusive.

    Node ``[i, j, k]`` sits at ``-1 + 2 * (i, j, k) / (grid - 1)`` and is row ``(i * grid + j) * grid + k``
    (C order), so ``values.reshape(grid, grid, grid)[i, j, k]`` is the value at x_i, y_j, z_k.

    Returns
    -------
    (grid**3, 3) float64
    """
    grid = positive_int(grid, "grid", minimum=2)
    axis = np.linspace(-1.0, 1.0, grid)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def node_coordinates(nodes: np.ndarray, grid: int) -> np.ndarray:
    """Positions of some nodes of the :func:`grid_nodes` lattice, without building the whole of it.

    Parameters
    ----------
    nodes : (n,) int
        C-order node indices.
    grid : int
        Nodes per axis.

    Returns
    -------
    (n, 3) float64
        ``grid_nodes(grid)[nodes]``, bit for bit.
    """
    ijk = np.stack([nodes // (grid * grid), (nodes // grid) % grid, nodes % grid], axis=1)
    return np.linspace(-1.0, 1.0, grid)[ijk]
