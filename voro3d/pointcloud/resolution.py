"""How finely a cloud is fitted: its grid, its adaptive band of generators, the fit's samples.

``grid="auto"`` takes the finest voxel from the point spacing (:func:`auto_grid`) and, for the
VoroLoss fit, an adaptive band (:class:`voro3d.generators.AdaptiveBand`) from that level up to
voxels of a ``COARSEST_GRID`` grid: the finest voxels only where the target surface bends or
breaks, so a dense scan keeps the detail its points hold without a uniform fine grid's cost. An
explicit grid is a uniform grid.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..generators import AdaptiveBand
from ..geometry import face_area_vectors, grid_voxel
from .tuning import (AUTO_GRID_RANGE, AUTO_SPACINGS_PER_VOXEL, BAND_TOLERANCE, CLOUD_SAMPLES_PER_FACE, COARSEST_GRID,
                     DETAIL_SPACINGS, HOLE_VOXELS, MAX_REFINE, MAX_TARGET_GRID, MIN_SPACINGS_PER_VOXEL)

__all__ = ["auto_grid", "band_levels", "choose_grid", "fit_band", "max_supported_grid", "refine_levels", "target_samples"]


def max_supported_grid(spacing: float) -> int:
    """Finest grid whose voxels (fit frame, diagonal 2) are still ``MIN_SPACINGS_PER_VOXEL``
    median spacings wide; ``spacing`` in fit-frame units."""
    return int(2.0 / (MIN_SPACINGS_PER_VOXEL * spacing)) + 1


def auto_grid(spacing: float) -> int:
    """Finest grid for a cloud of median spacing ``spacing`` (fit frame): voxels about
    ``AUTO_SPACINGS_PER_VOXEL`` spacings wide, clipped to ``AUTO_GRID_RANGE``."""
    return int(np.clip(round(2.0 / (AUTO_SPACINGS_PER_VOXEL * spacing)) + 1, *AUTO_GRID_RANGE))


def band_levels(grid: int) -> int:
    """Levels of an adaptive band over ``grid``: its coarsest voxels at most those of ``COARSEST_GRID``."""
    return max(int(np.floor(np.log2((grid - 1) / (COARSEST_GRID - 1)))), 0)


def choose_grid(grid, spacing: float, *, adaptive: bool, exact: bool = True) -> tuple[int, int]:
    """``(grid, levels)`` for a cloud: ``"auto"`` is :func:`auto_grid`, with :func:`band_levels`
    when ``adaptive``; an int is that uniform grid (0 levels), with a warning past
    :func:`max_supported_grid`.

    ``"auto"`` stays at ``MAX_TARGET_GRID`` (the target's own) for the learned model, whose uniform
    grid costs ``grid^3`` nodes, and for points that are not ``exact`` (noisy): their smoothed
    target's bumps are noise, and a finer band fits them (bunny at 100k points, 0.5% noise:
    CD 2.10 at 64^3, 2.14 at 101^3 over 2 levels; NC 0.913 and 0.905).
    """
    from .._validate import grid_option

    if grid_option(grid) == "auto":
        grid = auto_grid(spacing) if adaptive and exact else min(auto_grid(spacing), MAX_TARGET_GRID)
        return grid, band_levels(grid) if adaptive else 0
    supported = max_supported_grid(spacing)
    if grid > supported:
        warnings.warn(f"grid {grid} is finer than the points support (voxels narrower than their spacing; up to "
                      f"{supported} is supported): the surface between points comes from the smooth target alone",
                      stacklevel=5)
    return grid, 0


def refine_levels(kind: str, depth: int, grid: int, spacing: float, *, exact: bool) -> int:
    """Times the cleaned triangles are split in four before their fit to a Poisson target
    (:meth:`voro3d.VoroMesh.to_open3d`'s ``refine``): until they are about as fine as the finest
    detail the target holds, rounded in powers of two, at most ``MAX_REFINE`` times. That detail is
    the coarser of the target's octree cell and ``DETAIL_SPACINGS`` times the median point
    ``spacing`` (fit frame): points a spacing apart show nothing finer than two spacings, so sparse
    clouds are never split however fine the octree. Noisy points (not ``exact``) never: their
    target's bumps are noise (bunny and cow, 20k points, 0.5% noise, split once: CD +1% / +3%). IMLS
    and shell targets never: their field follows the grid.

    The grid's flat faces then no longer cut the chords of the detail the target holds. The
    measurements: beside ``DETAIL_SPACINGS`` and ``MAX_REFINE`` in :mod:`~voro3d.pointcloud.tuning`.
    """
    if kind != "poisson" or not exact:
        return 0
    detail = max(2.0 / 2**depth, DETAIL_SPACINGS * spacing)
    return int(np.clip(round(np.log2(grid_voxel(grid) / detail)), 0, MAX_REFINE))


def fit_band(surface_vertices: np.ndarray, grid: int, levels: int) -> AdaptiveBand | None:
    """The adaptive band over the target's vertices (fit frame), None for a uniform grid."""
    return AdaptiveBand(surface_vertices, grid, levels=levels, tolerance=BAND_TOLERANCE) if levels else None


def target_samples(target, surface_vertices, points, grid: int, *, band: AdaptiveBand | None = None,
                   seed: int) -> np.ndarray:
    """The VoroLoss samples: ``CLOUD_SAMPLES_PER_FACE grid^2`` of them (half a mesh fit's: the mesh is
    fitted to the target afterwards), fewer where ``band`` is coarse.

    Dense clean points (``target.dense``: spacing under ``DENSE_SPACINGS`` of a voxel) are exact
    samples already, and the proxy mesh is only as good as its grid (a wall thinner than a grid step is
    lost there): they are used, and proxy samples only fill the holes, where no point is within
    ``HOLE_VOXELS`` voxels. Otherwise the samples all come from the target mesh: a Poisson
    mesh as it is (four times finer than the grid), or the IMLS proxy with its vertices moved
    onto the IMLS surface (its samples then lie within the chord error of a mesh twice finer
    than the grid). On closed clouds, dense ones too, Poisson's samples beat the points:
    bunny and armadillo at 100k points, CD 0.607 / 0.511 from the points, 0.597 / 0.478.
    With a band, each leaf gets the samples per area of a uniform fit at its own level
    (:meth:`~voro3d.generators.AdaptiveBand.density`).
    """
    from scipy.spatial import cKDTree

    from ..sampling import sample_surface

    budget = CLOUD_SAMPLES_PER_FACE * grid**2
    rng = np.random.default_rng(seed)
    if band is None:
        proxy, _ = sample_surface((surface_vertices, target.triangles), budget, seed=seed)
    else:
        centroids = surface_vertices[target.triangles].mean(axis=1)
        density = band.density(centroids)
        area = np.linalg.norm(face_area_vectors(surface_vertices, target.triangles), axis=1)
        share = float(np.dot(area, density) / max(area.sum(), 1e-300))
        proxy, _ = sample_surface((surface_vertices, target.triangles), max(int(round(budget * share)), 4),
                                  seed=seed, density=density)
    if not target.dense:
        return proxy
    if band is not None:
        points = points[rng.random(points.shape[0]) < min(1.0, budget / points.shape[0]) * band.density(points)]
    elif points.shape[0] > budget:
        points = points[rng.choice(points.shape[0], budget, replace=False)]
    hole = HOLE_VOXELS * grid_voxel(grid)
    # Bounded: only whether a point is that near counts, and an unbounded search from proxy samples
    # far from the points (an open scan's closed side) crawls (5e5 of them at 10^6 points: 90 s).
    distance, _ = cKDTree(points).query(proxy, distance_upper_bound=hole, workers=-1)
    return np.vstack([points, proxy[distance > hole]])
