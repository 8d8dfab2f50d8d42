"""Inside/outside labels of Voronoi cells."""
from __future__ import annotations

from typing import Callable

import numpy as np

from ._validate import as_points
from .delaunay import Triangulation, circumcenters, triangulate

__all__ = ["cell_interior_points", "label_cells"]


def cell_interior_points(generators, *, triangulation: Triangulation | None = None) -> np.ndarray:
    """A point inside each generator's Voronoi cell: the mean of the cell's Voronoi vertices.

    The mean of a convex polytope's vertices lies inside it, so unlike the generator itself
    (which may sit outside the surface while its cell reaches inside) it labels the cell
    by where the cell is. Cells are bounded by eight far box corners added as generators.

    Parameters
    ----------
    generators : (n, 3) float
        Generator positions, at least 4 distinct ones.
    triangulation : voro3d.delaunay.Triangulation, optional
        Their triangulation (:func:`voro3d.delaunay.triangulate`), when the caller has it.
        Generators it merged (closer than its tolerance) share one cell and one point.

    Returns
    -------
    (n, 3) float64
    """
    points = as_points(generators, "generators", min_count=4)
    if triangulation is None:
        triangulation = triangulate(points)
    elif triangulation.site.shape[0] != points.shape[0]:
        raise ValueError(f"triangulation is of {triangulation.site.shape[0]} generators, not {points.shape[0]}")
    all_points, tets = triangulation.points, triangulation.tets
    centres = circumcenters(all_points, tets)
    n = all_points.shape[0]
    owners = tets.reshape(-1)
    counts = np.bincount(owners, minlength=n).astype(float)
    sums = np.stack([np.bincount(owners, weights=np.repeat(centres[:, d], 4), minlength=n) for d in range(3)], axis=1)
    return sums[triangulation.site] / counts[triangulation.site, None]


def label_cells(generators, inside: Callable[[np.ndarray], np.ndarray], *,
                triangulation: Triangulation | None = None) -> np.ndarray:
    """Occupancy of every cell from an inside test evaluated at :func:`cell_interior_points`.

    Parameters
    ----------
    generators : (n, 3) float
    inside : callable
        Maps (m, 3) float64 points to (m,) bool, True inside the shape.
    triangulation : voro3d.delaunay.Triangulation, optional
        As in :func:`cell_interior_points`.

    Returns
    -------
    (n,) bool
    """
    points = cell_interior_points(generators, triangulation=triangulation)
    labels = np.asarray(inside(points))
    if labels.shape != (points.shape[0],):
        raise ValueError(f"inside must return shape ({points.shape[0]},), got {labels.shape}")
    return labels.astype(bool)
