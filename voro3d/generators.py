"""Initial Voronoi generators: the grid nodes around the surface samples."""
from __future__ import annotations

import numpy as np

from ._validate import as_points, positive_int
from .geometry import grid_voxel
from .sampling import grid_nodes

__all__ = ["grid_nodes", "initial_generators"]

# Offsets of a voxel's 8 corners from its lowest corner, in node steps.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int64)


def initial_generators(samples, grid: int) -> np.ndarray:
    """Corners of every grid voxel that holds at least one surface sample.

    The official VoroMesh rule (``mask_relevant_voxels``): the optimisation starts from the nodes
    of :func:`grid_nodes` that bound an occupied voxel, a band one voxel thick on each side of the
    surface, instead of all ``grid**3`` nodes, most of which no sample would ever pull.

    Parameters
    ----------
    samples : (m, 3) float
        Surface samples in the fit frame (:func:`voro3d.frames.fit_frame`), inside ``[-1, 1]^3``.
        Samples outside are clipped into the boundary voxels.
    grid : int
        Nodes per axis, ``>= 2``; voxels have side ``h = 2 / (grid - 1)``.

    Returns
    -------
    (n, 3) float64
        Distinct nodes, in increasing C-order node index (the row order of :func:`grid_nodes`);
        ``n <= grid**3``.

    Raises
    ------
    ValueError
        ``samples`` is not a finite ``(m, 3)`` array with ``m >= 1``, or ``grid < 2``.
    """
    points = as_points(samples, "samples")
    grid = positive_int(grid, "grid", minimum=2)
    h = grid_voxel(grid)
    voxel = np.clip(np.floor((points + 1.0) / h).astype(np.int64), 0, grid - 2)
    voxel = np.unique((voxel[:, 0] * grid + voxel[:, 1]) * grid + voxel[:, 2])
    # A voxel's lowest corner has the voxel's own index; the others add C-order node strides.
    strides = _CORNERS @ np.array([grid * grid, grid, 1], dtype=np.int64)
    nodes = np.unique((voxel[:, None] + strides).reshape(-1))
    ijk = np.stack([nodes // (grid * grid), (nodes // grid) % grid, nodes % grid], axis=1)
    # The coordinates of grid_nodes, bit for bit, so rows equal ``grid_nodes(grid)[nodes]``.
    return np.linspace(-1.0, 1.0, grid)[ijk]
