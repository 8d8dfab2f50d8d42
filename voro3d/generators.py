"""Initial Voronoi generators: the grid nodes around the surface samples."""
from __future__ import annotations

import numpy as np

from ._validate import as_points, positive_int
from .geometry import grid_voxel
from .sampling import grid_nodes, node_coordinates

__all__ = ["AdaptiveBand", "grid_nodes", "initial_generators"]

# Fewest points in a voxel whose plane fit decides it is flat.
_MIN_PLANE_POINTS = 8
# Points a block of AdaptiveBand.level_of: its voxel indices and keys of 10^7 points at once take over 1 GB.
_BLOCK = 1 << 20
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
    voxel = _voxel_ijk(points, grid)
    voxel = np.unique((voxel[:, 0] * grid + voxel[:, 1]) * grid + voxel[:, 2])
    # A voxel's lowest corner has the voxel's own index; the others add C-order node strides.
    strides = _CORNERS @ np.array([grid * grid, grid, 1], dtype=np.int64)
    return node_coordinates(np.unique((voxel[:, None] + strides).reshape(-1)), grid)


def _voxel_ijk(points: np.ndarray, grid: int) -> np.ndarray:
    """(m, 3) int64: the voxel (i, j, k) of each point, points outside clipped into the boundary voxels."""
    return np.clip(np.floor((points + 1.0) / grid_voxel(grid)).astype(np.int64), 0, grid - 2)


class AdaptiveBand:
    """An octree band of voxels around a surface: coarse where the surface is flat, fine where not.

    Level 0 is the uniform grid of ``grid`` nodes per axis (voxel ``h = 2 / (grid - 1)``); a
    level-``l`` voxel is a block of ``2^l`` level-0 voxels per axis, its corners level-0 nodes, so
    voxels of all levels share one node lattice. Built top-down from surface points: a voxel of
    level ``l >= 1`` holding points is split into its 8 children while its points lie further than
    ``tolerance * h`` (root mean square) from their least-squares plane, or holds too few to
    tell (under 8); otherwise it is a leaf.
    A flat patch is as exact in one coarse Voronoi face as in many fine ones, and a curved or
    sharp patch gets the finest voxels, so the generators (the leaves' corners) and the fit's
    samples go where the surface has detail. With ``levels=0`` it is the uniform band of
    :func:`initial_generators`.

    Parameters
    ----------
    points : (m, 3) float
        Surface points in the fit frame (``[-1, 1]^3``), dense enough that every voxel of level 1
        crossed by the surface holds a few (a target mesh's vertices at its resolution).
    grid : int
        Level-0 nodes per axis, ``>= 2``.
    levels : int
        Levels above level 0, ``>= 0``; the coarsest voxels are ``2^levels`` fine voxels wide.
    tolerance : float
        Plane-fit residual, in level-0 voxels, above which a voxel is split.

    Attributes
    ----------
    grid, levels, tolerance
        As given.
    leaves : list of (n_l,) int64
        Sorted keys (C-order index in the level's own voxel grid) of each level's leaves.
    """

    def __init__(self, points, grid: int, *, levels: int, tolerance: float):
        points = as_points(points, "points")
        self.grid = positive_int(grid, "grid", minimum=2)
        self.levels = positive_int(levels, "levels", minimum=0)
        if not (np.isfinite(tolerance) and tolerance >= 0):
            raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance}")
        self.tolerance = float(tolerance)
        ijk = _voxel_ijk(points, self.grid)
        limit = (self.tolerance * grid_voxel(self.grid)) ** 2
        self.leaves = [np.empty(0, np.int64)] * (self.levels + 1)
        active = np.ones(points.shape[0], bool)
        for level in range(self.levels, -1, -1):
            keys = self._keys(ijk[active] >> level, level)
            unique, group = np.unique(keys, return_inverse=True)
            if level == 0:
                self.leaves[0] = unique
                break
            residual, count = _plane_residual(points[active], group, unique.shape[0])
            # A few points say nothing of the surface's shape (3 always lie on a plane): split.
            flat = (residual <= limit) & (count >= _MIN_PLANE_POINTS)
            self.leaves[level] = unique[flat]
            # Points of split voxels go on to the next level down.
            active[np.flatnonzero(active)[flat[group]]] = False

    def _size(self, level: int) -> int:
        """Voxels per axis at ``level`` (the last one cut off by the box)."""
        return ((self.grid - 2) >> level) + 1

    def _keys(self, ijk: np.ndarray, level: int) -> np.ndarray:
        size = self._size(level)
        return (ijk[:, 0] * size + ijk[:, 1]) * size + ijk[:, 2]

    def level_of(self, points) -> np.ndarray:
        """(m,) int64: the level of the leaf holding each point; 0 where none does (off the band)."""
        points = np.asarray(points, dtype=np.float64)
        return np.concatenate([self._level_block(points[start:start + _BLOCK])
                               for start in range(0, points.shape[0], _BLOCK)] or [np.zeros(0, np.int64)])

    def _level_block(self, points: np.ndarray) -> np.ndarray:
        ijk = _voxel_ijk(points, self.grid)
        level = np.zeros(ijk.shape[0], np.int64)
        found = np.zeros(ijk.shape[0], bool)
        for current in range(self.levels, 0, -1):
            leaves = self.leaves[current]
            if leaves.size == 0:
                continue
            keys = self._keys(ijk >> current, current)
            at = np.minimum(np.searchsorted(leaves, keys), leaves.size - 1)
            hit = ~found & (leaves[at] == keys)
            level[hit], found = current, found | hit
        return level

    def generators(self) -> np.ndarray:
        """(n, 3) float64: the distinct corners of all leaves, in increasing C-order level-0 node index."""
        strides = np.array([self.grid * self.grid, self.grid, 1], dtype=np.int64)
        nodes = []
        for level, leaves in enumerate(self.leaves):
            size = self._size(level)
            ijk = np.stack([leaves // (size * size), (leaves // size) % size, leaves % size], axis=1)
            corners = np.minimum((ijk[:, None, :] + _CORNERS) << level, self.grid - 1)
            nodes.append((corners @ strides).reshape(-1))
        return node_coordinates(np.unique(np.concatenate(nodes)), self.grid)

    def density(self, points) -> np.ndarray:
        """(m,) float64: samples per area at each point as a share of level 0's, ``4^-level``: the
        uniform fit of a leaf's own grid gives each voxel face the same number of samples."""
        return 0.25 ** self.level_of(points)


def _plane_residual(points: np.ndarray, group: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """(n_groups,) float64 each: mean squared distance of each group's points to their least-squares
    plane (the smallest eigenvalue of the group's covariance), and the group's point count."""
    count = np.bincount(group, minlength=n_groups).astype(np.float64)
    mean = np.stack([np.bincount(group, points[:, a], n_groups) for a in range(3)], axis=1) / count[:, None]
    centred = points - mean[group]
    cov = np.empty((n_groups, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(group, centred[:, a] * centred[:, b], n_groups) / count
    return np.linalg.eigvalsh(cov)[:, 0], count
