"""One VoroLoss fit cut into overlapping tiles, each a task; the generators merged into one diagram.

A cloud of tens of millions of points is reconstructed from a uniform subset of a million
(:func:`analysis_subset`), and its fit is cut into boxes (:func:`split_tiles`) of at most
``TILE_SAMPLES`` samples each (``pointcloud.tuning``): each box's generators are fitted to the
samples within a margin of the box, and only the generators that started inside the box are kept.
Every generator starts in exactly one box, so the merged set is one band of generators, refitted
where two boxes meet (:func:`fit_tiles`), then labelled and extracted once: one Voronoi diagram,
closed, with no seams to stitch. Tasks run in a local pool of spawned processes
(``engine="local"``) or as Ray tasks (``engine="ray"``), with the same result: each tile's fit is
deterministic and does not depend on its threads. (A spawned pool imports the calling script
again: a script that reconstructs a large cloud keeps its work under ``if __name__ == "__main__":``.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._system import available_cpus
from .tuning import ANALYSIS_POINTS, SEAM_STEPS, SEAM_WIDTH, TILE_MARGIN, TILE_POINTS, TILE_SAMPLES

__all__ = ["ENGINES", "Tile", "analysis_subset", "fit_in_tiles", "fit_tiles", "seam_tile", "split_tiles"]

ENGINES = ("local", "ray")


@dataclass(frozen=True)
class Tile:
    """One box of the fit: its samples and generators (indices into the whole fit's).

    Attributes
    ----------
    samples : (s,) int64
        Samples within the margin of the box.
    generators : (g,) int64
        Generators within the margin of the box, those inside it (``core``) first.
    n_core : int
        Generators that start inside the box: the ones this tile's fit decides.
    low, high : (3,) float64
        The box, ``[low, high)``; infinite on the outer sides.
    """

    samples: np.ndarray
    generators: np.ndarray
    n_core: int
    low: np.ndarray
    high: np.ndarray


def analysis_subset(count: int, seed: int) -> np.ndarray | None:
    """Sorted indices of ``ANALYSIS_POINTS`` of ``count`` points drawn without replacement, or None
    when ``count <= TILE_POINTS``.

    The statistics a cloud's plan rests on (spacing, noise, normals' signs, the target surface at
    ``MAX_TARGET_GRID``) read the same from a uniform subset of a dense cloud: only its spacing
    scales, as ``sqrt(count / ANALYSIS_POINTS)``.
    """
    if count <= TILE_POINTS:
        return None
    return np.sort(np.random.default_rng(seed).choice(count, ANALYSIS_POINTS, replace=False))


def fit_in_tiles(samples: np.ndarray, generators: np.ndarray | None, inside, grid: int, *, levels: int, frame,
                 engine: str = "local", workers: int | None = None, threads: int | None = None, options: dict,
                 progress: bool = False):
    """:func:`voro3d.fitting.fit_samples` with its loop in tiles of at most ``TILE_SAMPLES`` samples.

    Parameters
    ----------
    samples : (m, 3) float64
        Fit frame.
    generators : (n, 3) float64 or None
        Initial generators (an adaptive band's), or None for the uniform band of ``grid``.
    inside : callable
        Fit-frame inside test that labels the cells.
    grid, levels : int
        The finest grid and the band's levels above it: margins and seams are ``TILE_MARGIN`` and
        ``SEAM_WIDTH`` of the coarsest voxels.
    frame : voro3d.frames.NormalizationFrame
    engine, workers, threads, progress
        As in :func:`fit_tiles`.
    options : dict
        The fit's ``steps, seed, device`` (others default, :func:`voro3d.fitting.fit_schedule`).

    Returns
    -------
    voromesh : voro3d.VoroMesh
    tiles : int
    """
    from ..fitting import fit_schedule, labelled_voromesh, refresh_reach
    from ..generators import initial_generators
    from ..geometry import grid_voxel

    generators = initial_generators(samples, grid) if generators is None else generators
    coarsest = grid_voxel(grid) * 2**levels
    tiles = split_tiles(samples, generators, max_samples=TILE_SAMPLES, margin=TILE_MARGIN * coarsest)
    fitted = fit_tiles(samples, generators, grid, reach=refresh_reach(generators, grid) if levels else None,
                       tiles=tiles, seam=SEAM_WIDTH * coarsest, engine=engine, workers=workers, threads=threads,
                       options=fit_schedule(**options), progress=progress)
    return labelled_voromesh(fitted, inside, grid, frame=frame), len(tiles)


def split_tiles(samples: np.ndarray, generators: np.ndarray, *, max_samples: int, margin: float) -> list[Tile]:
    """Boxes of the fit frame with at most ``max_samples`` samples each, cut at medians.

    A box is halved along its longest side at the samples' median until it holds at most
    ``max_samples`` (a kd-tree of boxes: balanced tasks whatever the shape). The boxes are
    half-open and the outer ones unbounded, so every generator lies in exactly one.

    Parameters
    ----------
    samples : (m, 3) float64
        Fit frame.
    generators : (n, 3) float64
        Initial generators, fit frame.
    max_samples : int
    margin : float
        Fit-frame distance around a box from which its tile also takes samples and generators:
        enough for its boundary generators' cells to see every sample they would see untiled.

    Returns
    -------
    list of Tile
        In a fixed order (depth first, lower half first).
    """
    tiles = []
    pending = [(np.full(3, -np.inf), np.full(3, np.inf), np.arange(samples.shape[0]))]
    while pending:
        low, high, inside = pending.pop()
        if inside.size > max_samples:
            extent = np.ptp(samples[inside], axis=0)
            axis = int(np.argmax(extent))
            cut = float(np.median(samples[inside, axis]))
            upper = samples[inside, axis] >= cut
            if 0 < upper.sum() < inside.size:
                lower_high, upper_low = high.copy(), low.copy()
                lower_high[axis] = upper_low[axis] = cut
                pending += [(upper_low, high, inside[upper]), (low, lower_high, inside[~upper])]
                continue
        tiles.append(_tile(samples, generators, low, high, margin))
    return tiles


def _tile(samples, generators, low, high, margin) -> Tile:
    """The tile of the box ``[low, high)``."""
    core = np.flatnonzero(np.all((generators >= low) & (generators < high), axis=1))
    near = np.flatnonzero(np.all((generators >= low - margin) & (generators < high + margin), axis=1))
    ring = np.setdiff1d(near, core, assume_unique=True)
    taken = np.flatnonzero(np.all((samples >= low - margin) & (samples < high + margin), axis=1))
    return Tile(samples=taken, generators=np.concatenate([core, ring]), n_core=core.size, low=low, high=high)


def fit_tiles(samples: np.ndarray, generators: np.ndarray, grid: int, *, reach: np.ndarray | None, tiles: list,
              seam: float, engine: str = "local", workers: int | None = None, threads: int | None = None,
              options: dict, progress: bool = False) -> np.ndarray:
    """The generators of one VoroLoss fit, tile by tile (:func:`split_tiles`), as tasks, then their seams.

    A tile's generators next to a cut were fitted against its ring as the tile left it, not as
    the next tile did; the Voronoi faces between the two sides then fit neither (600k bunny points
    in 8 tiles: faces at the cuts 2.8x further from the surface). So the generators within
    ``seam`` of a cut are fitted once more (:func:`seam_tile`) from the merged ones, with their
    neighbours held where they are, for ``SEAM_STEPS`` steps at the schedule's last rate.

    Parameters
    ----------
    samples, generators : (m, 3), (n, 3) float64
        Fit frame.
    grid : int
        The finest voxel's grid.
    reach : (n,) float32 or None
        As in :func:`voro3d.fitting.optimise_generators`, for all generators (a tile takes its rows).
    tiles : list of Tile
    engine : {"local", "ray"}
        A pool of spawned worker processes (one tile at a time each; in this process when there
        is one worker), or Ray tasks (a local Ray started here unless one is running).
    workers : int, optional
        Tasks at once; default one per CPU, at most one per tile.
    threads : int, optional
        Threads of each tile's fit; default the CPUs over the workers.
    seam : float
        Fit-frame distance from a cut within which generators are fitted again.
    options : dict
        ``steps, lr, milestones, gamma, batch_fraction, k, seed, device`` of the fit
        (:func:`voro3d.fitting.fit_schedule`).
    progress : bool
        A bar over the tiles.

    Returns
    -------
    (n, 3) float64
        Every generator as its own tile's fit left it.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    cpus = available_cpus()
    workers = max(1, min(cpus if workers is None else workers, len(tiles)))
    threads = max(1, cpus // workers) if threads is None else threads
    tasks = [(samples[tile.samples], generators[tile.generators], None if reach is None else reach[tile.generators],
              tile.n_core) for tile in tiles]
    run = _run_ray if engine == "ray" else _run_local
    fitted = generators.copy()
    for tile, core in zip(tiles, run(tasks, grid, dict(options, threads=threads), workers, progress)):
        fitted[tile.generators[:tile.n_core]] = core
    joint = seam_tile(samples, fitted, tiles, width=seam, margin=seam)
    if joint.n_core:
        settle = dict(options, threads=threads * workers, steps=SEAM_STEPS, milestones=[],
                      lr=options["lr"] * options["gamma"] ** len(options["milestones"]))
        fitted[joint.generators[:joint.n_core]] = _fit_tile(
            samples[joint.samples], fitted[joint.generators], None if reach is None else reach[joint.generators],
            joint.n_core, grid, settle, hold=True)
    return fitted


def seam_tile(samples: np.ndarray, generators: np.ndarray, tiles: list, *, width: float, margin: float) -> Tile:
    """The generators within ``width`` of a cut between ``tiles`` (its core), then their neighbours
    within ``margin`` more (held fixed), with the samples within ``width + margin`` of a cut."""
    to_cut = _cut_distance(generators, tiles)
    free = np.flatnonzero(to_cut < width)
    held = np.flatnonzero((to_cut >= width) & (to_cut < width + margin))
    taken = np.flatnonzero(_cut_distance(samples, tiles) < width + margin)
    return Tile(samples=taken, generators=np.concatenate([free, held]), n_core=free.size,
                low=np.full(3, -np.inf), high=np.full(3, np.inf))


def _cut_distance(points: np.ndarray, tiles: list) -> np.ndarray:
    """(m,) distance from each point to the nearest inner side of the tile box holding it (inf for one tile)."""
    distance = np.full(points.shape[0], np.inf)
    for tile in tiles:
        inside = np.flatnonzero(np.all((points >= tile.low) & (points < tile.high), axis=1))
        local = points[inside]
        distance[inside] = np.minimum(local - tile.low, tile.high - local).min(axis=1)
    return distance


def _fit_tile(samples, generators, reach, n_core, grid, options, *, hold: bool = False) -> np.ndarray:
    """(n_core, 3): one tile's fit, its core generators (the first ``n_core``); with ``hold``, the others stay put."""
    from ..fitting import optimise_generators

    fixed = np.arange(generators.shape[0]) >= n_core if hold else None
    return optimise_generators(samples, generators, grid, reach=reach, fixed=fixed, **options).generators[:n_core]


def _bar(total: int, progress: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="voro3d tiles", unit="tile", disable=not progress, leave=False)


def _run_local(tasks, grid, options, workers, progress) -> list:
    """Each task's core generators, in order: in this process, or in a pool of spawned processes."""
    with _bar(len(tasks), progress) as bar:
        if workers == 1:
            results = []
            for task in tasks:
                results.append(_fit_tile(*task, grid, options))
                bar.update()
            return results
        import concurrent.futures
        import multiprocessing

        # spawn, not fork: a fork would copy this process's threads and locks (tqdm, OpenMP) mid-state.
        try:
            with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                futures = [pool.submit(_fit_tile, *task, grid, options) for task in tasks]
                for _ in concurrent.futures.as_completed(futures):
                    bar.update()
                return [future.result() for future in futures]
        except concurrent.futures.process.BrokenProcessPool as error:
            raise RuntimeError("a tile's worker process died: out of memory, or the calling script runs its work at "
                               "import (a spawned worker imports it again: keep it under "
                               "`if __name__ == \"__main__\":`), or pass workers=1") from error


def _run_ray(tasks, grid, options, workers, progress) -> list:
    """Each task's core generators, in order, as Ray tasks (``pip install 'voro3d[ray]'``)."""
    from .._extras import ray_session

    with ray_session(workers * options["threads"]) as ray:
        fit = ray.remote(num_cpus=options["threads"], max_retries=0)(_fit_tile)
        refs = [fit.remote(*task, grid, options) for task in tasks]
        with _bar(len(refs), progress) as bar:
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                bar.update(len(done))
        return ray.get(refs)
