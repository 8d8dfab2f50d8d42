"""A coloured cloud's colours carried onto its reconstruction."""
from __future__ import annotations

import numpy as np

__all__ = ["transfer_colors"]


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
