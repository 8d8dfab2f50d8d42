"""Inside/outside labels of Voronoi cells."""
from __future__ import annotations

from typing import Callable

import numpy as np

from ._validate import as_points
from .delaunay import circumcenters, delaunay_with_box

__all__ = ["cell_interior_points", "label_cells"]


def cell_interior_points(generators) -> np.ndarray:
    """A point inside each generator's Voronoi cell: the mean of the cell's Voronoi vertices.

    The mean of a convex polytope's vertices lies inside it, so unlike the generator itself
    (which may sit outside the surface while its cell reaches inside) it labels the cell
    by where the cell is. Cells are bounded by eight far box corners added as generators.

    Parameters
    ----------
    generators : (n, 3) float
        Distinct generator positions (n >= 4).

    Returns
    -------
    (n, 3) float64
    """
    points = as_points(generators, "generators", min_count=4)
    all_points, tets, _ = delaunay_with_box(points)
    centres = circumcenters(all_points, tets)
    n = all_points.shape[0]
    owners = tets.reshape(-1)
    counts = np.bincount(owners, minlength=n).astype(float)
    sums = np.stack([np.bincount(owners, weights=np.repeat(centres[:, d], 4), minlength=n) for d in range(3)], axis=1)
    result = points.copy()
    # A duplicate generator is never a Delaunay vertex; it keeps its own position.
    has_cell = counts[: points.shape[0]] > 0
    result[has_cell] = sums[: points.shape[0]][has_cell] / counts[: points.shape[0], None][has_cell]
    return result


def label_cells(generators, inside: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Occupancy of every cell from an inside test evaluated at :func:`cell_interior_points`.

    Parameters
    ----------
    generators : (n, 3) float
    inside : callable
        Maps (m, 3) float64 points to (m,) bool, True inside the shape.

    Returns
    -------
    (n,) bool
    """
    points = cell_interior_points(generators)
    labels = np.asarray(inside(points))
    if labels.shape != (points.shape[0],):
        raise ValueError(f"inside must return shape ({points.shape[0]},), got {labels.shape}")
    return labels.astype(bool)
