"""Clouds sampled along scan lines far apart for their spacing along them (a LiDAR's): told apart, and thinned.

Such a point's nearest neighbours all lie on its own line, so the plane fits, spacing, noise and
point areas read a line, not the surface: the normals turn about the lines and the surface comes
apart into strips along them. Thinned along the lines until a point's nearest neighbours reach the
lines beside its own, the cloud reads as any other.
"""
from __future__ import annotations

import numpy as np

from .preprocess import NOISE_NEIGHBOURS, SPACING_NEIGHBOURS, _centred_covariance, group_means, stride
from .tuning import LINE_RATIO, LINE_SAMPLE, THIN_ROUNDS

__all__ = ["line_ratio", "thin_lines"]


def line_ratio(points: np.ndarray, tree) -> tuple[float, float]:
    """How one-dimensional the neighbourhoods of ``(n, 3)`` points (their cKDTree ``tree``) are, and their spacing.

    Over every k-th point, at most ``LINE_SAMPLE``: the median of the middle over the largest covariance eigenvalue of
    its ``SPACING_NEIGHBOURS + 1`` nearest points (itself first), and of its ``NOISE_NEIGHBOURS + 1``, the lower of the
    two; and the median distance to its nearest point. A surface sampled evenly reads 0.40 or more (the dev clouds,
    range scans included); one sampled along lines far apart for their spacing along them (a LiDAR's scan lines) under
    0.05, its nearest points all on its own line: the 9 nearest where the lines lie 5-10 steps apart, the 25 nearest
    where depth noise as wide as a step spreads the 9 across their line.
    """
    tested = points[::stride(len(points), LINE_SAMPLE)]
    distance, neighbour = tree.query(tested, k=min(NOISE_NEIGHBOURS + 1, len(points)), workers=-1)
    ratios = []
    for count in (SPACING_NEIGHBOURS + 1, NOISE_NEIGHBOURS + 1):
        values = np.linalg.eigvalsh(_centred_covariance(points[neighbour[:, :count]])[1])
        ratios.append(float(np.median(values[:, 1] / np.maximum(values[:, 2], 1e-300))))
    return min(ratios), float(np.median(distance[:, 1]))


def thin_lines(points: np.ndarray, *attributes, tree, force: bool = False, min_points: int = 1):
    """Points sampled along lines far apart for their spacing along them, thinned along the lines.

    Each round puts one point, the mean of the points (and ``attributes``) it stands for, in each
    occupied cube of twice the points' nearest-neighbour distance, until their neighbourhoods read
    two-dimensional (:func:`line_ratio` at least ``LINE_RATIO``), at most ``THIN_ROUNDS`` rounds and
    never under ``min_points`` points. ``force``: one round at least.

    Parameters
    ----------
    points : (n, 3) float64
    *attributes : (n, c) float64 or None
        Averaged alike (normals come back not unit: renormalise them).
    tree : scipy.spatial.cKDTree
        Of ``points``.

    Returns
    -------
    points : (m, 3) float64
    *attributes : (m, c) float64 or None
    rounds : int
        Rounds made; 0 returns the inputs themselves.
    """
    from scipy.spatial import cKDTree

    rounds = 0
    while rounds < THIN_ROUNDS:
        ratio, nearest = line_ratio(points, tree)
        if ratio >= LINE_RATIO and not (force and rounds == 0):
            break
        cube = np.floor((points - points.min(axis=0)) / (2.0 * nearest)).astype(np.int64)
        group = np.unique(cube, axis=0, return_inverse=True)[1].reshape(-1)
        if group.max() + 1 < min_points:
            break
        points, *attributes = group_means(group, points, *attributes)
        tree, rounds = cKDTree(points), rounds + 1
    return (points, *attributes, rounds)
