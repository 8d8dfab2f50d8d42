"""Direct optimisation of a VoroMesh to one input mesh (the paper's Section 4 fitting).

Pipeline: fit frame -> surface samples -> initial generators (grid band) -> Adam on VoroLoss ->
occupancy of every cell from an inside test -> generators mapped back to the input's units.

What the fit does
-----------------
``voro3d.fit(mesh, grid=32)`` puts the mesh in the fit frame (bounding box centred, diagonal
2, as the official code), samples 150·g² surface points, starts from the corners of every
voxel holding a sample, and runs 400 Adam steps on VoroLoss (lr 0.005 halved at 80/120/200/250,
20% of the samples per step, k = 8 nearest generators where the official code takes 11). Each
cell is then labelled at the mean of its Voronoi vertices by a robust inside test (three spread
rays, winding number where they disagree), and the generators go back to the input's units. kNN
candidates are searched again only when a generator has moved 1.5 voxels, at most 0.08 in the
fit frame (1.24 voxels at 32³): ``benchmarks/profile_fit.py --refresh-study`` shows a threshold of
a voxel matches a search at every step, and ``--schedule-study``
(``benchmarks/results/profile_fit_schedule.md``) that k = 8 with this threshold keeps the mean CD,
F1 and NC of k = 11 with a voxel over all dev meshes at 32³ and 64³, with 40% fewer searches and
a quarter less work per step. Point clouds take the same fit on samples of a smooth target
surface (:mod:`voro3d.pointcloud`).
"""
from __future__ import annotations

import bisect
import time
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ._cpufit import KernelLoop, cpu_threads
from ._extras import require
from ._validate import as_points, grid_option, mesh_grid, positive_int, trusted
from .delaunay import triangulate
from .frames import fit_frame
from .generators import initial_generators
from .geometry import grid_voxel
from .io import mesh_arrays
from .occupancy import label_cells
from .queries import InsideOutside
from .sampling import sample_surface
from .voromesh import VoroMesh

__all__ = ["FitInfo", "MAX_REFRESH_DISTANCE", "REFRESH_VOXELS", "SAMPLES_PER_FACE", "fit", "fit_samples",
           "fit_schedule", "labelled_voromesh", "optimise_generators", "refresh_reach"]

# Surface samples per grid face, n_samples = SAMPLES_PER_FACE * grid**2 (official code).
SAMPLES_PER_FACE = 150

# The kNN candidates of every sample are searched once and searched again only after some
# generator has moved this many voxels since the last search (2-3 searches at grid 32, 3-5 at 64).
# Between searches the nearest generator and the nearest bisector are re-ranked among the
# candidates at every step, so the loss stays exact while the candidates still hold them.
# Against a search at every step (benchmarks/profile_fit.py --refresh-study, bunny, fandisk and
# thingi32 44234 at 32, bunny at 64) a threshold of 1 voxel left the final loss within 3% and CD and
# F1 within 1%; with no second search the final loss is 1.4-6.4 times higher and CD 3-8% worse.
# 1.5 voxels with FIT_K candidates, but at most MAX_REFRESH_DISTANCE in the fit frame (1.24
# voxels at 32^3), searches half as often at the same mean CD, F1 and NC over the dev meshes at 32
# and 64 (profile_fit.py --schedule-study). A coarse grid needs the cap: 1.5 voxels at 32^3 left 2
# searches in all, and thin parts (the cow's horns) fitted worse, mean CD +8.5%.
REFRESH_VOXELS = 1.5
MAX_REFRESH_DISTANCE = 0.08

# On CPU the fit runs voro3d._cpufit.KernelLoop (the compiled kernel, no torch); False runs the
# torch loop there too, the reference that CUDA runs, so that benchmarks/profile_fit.py and the
# tests can compare the two.
_CPU_KERNEL = True

# kNN candidates per sample in the fit: the nearest generator and 7 more. The official code (and
# voro3d.loss.DEFAULT_K, a standalone VoroLoss with no re-ranking between searches) takes 10 more;
# at the fit's refresh threshold the nearest bisector is among the first 8 as often
# (profile_fit.py --schedule-study: the same mean CD, F1 and NC over the dev meshes at 32 and 64),
# and the step and each search cost a quarter less.
FIT_K = 8


class Optimised(NamedTuple):
    """What :func:`optimise_generators` returns."""

    generators: np.ndarray
    losses: list
    final_loss: float
    searches: int
    init_seconds: float
    loop: object = None  # the backend's loop (voro3d.fitloop.FitLoop), to go on from


@dataclass(frozen=True)
class FitInfo:
    """What :func:`fit` did and where the time went.

    Attributes
    ----------
    n_samples : int
        Surface samples.
    n_generators : int
        Generators optimised (the grid band around the samples).
    final_loss : float
        VoroLoss of all samples at the final generators, in fit-frame units squared (the fit
        frame has bounding-box diagonal 2), searched among the candidates of the last kNN search.
    losses : (steps,) float64
        Loss of each step's batch, before the step.
    candidate_searches : int
        kNN candidate searches over all samples, the first one included.
    sampling_seconds, init_seconds, optimisation_seconds, occupancy_seconds, total_seconds : float
        Wall-clock time of: surface sampling (and setting up the inside test); initial
        generators and the first candidate search;
        the optimisation loop (later searches included); cell occupancy; all of :func:`fit`.
    """

    n_samples: int
    n_generators: int
    final_loss: float
    losses: np.ndarray
    candidate_searches: int
    sampling_seconds: float
    init_seconds: float
    optimisation_seconds: float
    occupancy_seconds: float
    total_seconds: float


def fit(mesh, grid: int = 32, *, steps: int = 400, lr: float = 0.005, milestones=(80, 120, 200, 250),
        gamma: float = 0.5, batch_fraction: float = 0.2, k: int = FIT_K, n_samples: int | None = None,
        seed: int = 0, device: str = "cpu", threads: int | None = None, allow_open: bool = False,
        boundary_steps: int = 0, progress: bool = False) -> tuple[VoroMesh, FitInfo]:
    """Fit a VoroMesh to a triangle mesh, and report how the fit went.

    The mesh is mapped to the fit frame (:func:`voro3d.frames.fit_frame`: bounding box centred,
    diagonal 2), sampled (``n_samples`` area-uniform points), and the generators start at the
    corners of the grid voxels holding samples (:func:`voro3d.generators.initial_generators`).
    Adam then minimises VoroLoss (:func:`voro3d.loss.voroloss`) on a random ``batch_fraction``
    of the samples per step, with the learning rate times ``gamma`` at each milestone; generators
    are clamped to ``[-1, 1]^3`` after each step, as in the official code. Finally each cell is
    labelled inside or outside at a point inside it (:func:`voro3d.occupancy.label_cells`).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or (vertices, triangles)
        Closed (unless ``allow_open``), in any units.
    grid : int or "auto"
        Nodes per axis of the initial grid over ``[-1, 1]^3``, ``>= 4`` (the paper uses 32-128);
        ``"auto"`` is 32 (a mesh has no point spacing to choose it from).
    steps : int
        Adam steps (official: 400).
    lr : float
        Initial learning rate, in fit-frame units (official: 0.005).
    milestones : sequence of int
        Steps at which the learning rate is multiplied by ``gamma``. The paper's are the default;
        the official code uses ``(80, 150, 200, 250)``.
    gamma : float
        Learning-rate factor at each milestone, in ``(0, 1]``.
    batch_fraction : float
        Share of the samples used per step, in ``(0, 1]`` (official: 0.2).
    k : int
        kNN candidates per sample, ``>= 2`` (default :data:`FIT_K`).
    n_samples : int, optional
        Surface samples; default ``150 * grid**2`` (official).
    seed : int
        Seeds the samples and the batches: the same seed gives bitwise-identical generators on CPU.
    device : str
        ``"cpu"`` or ``"cuda"`` (or ``"cuda:N"``) for the optimisation loop.
    threads : int, optional
        Threads of the CPU kernel; default ``torch.get_num_threads()`` when torch is loaded, else
        ``OMP_NUM_THREADS``, else every CPU the process may use. A seed gives the same bits on any count.
    allow_open : bool
        Accept a mesh with boundary edges; inside is then decided by winding number
        (see :class:`voro3d.queries.InsideOutside`).
    boundary_steps : int
        Steps on the faces between inside and outside cells alone after the labels
        (:func:`fit_samples`). Off by default: on the 38 dev meshes at grid 32 (``benchmarks/bench_fit.py
        --boundary-steps 40``, 2026-12-07) 40 of them lowered the mean CD 0.841 -> 0.790 (lower on 14),
        but raised it on organic_homer (+11.7%) and organic_armadillo (+8.5%), where a cell flips when
        labelled again, and NC 0.9708 -> 0.9700: sub-voxel grooves (abc_00000001, NC 0.912 -> 0.872)
        come out as jagged ridges instead of being smoothed over.
    progress : bool
        Show a tqdm progress bar over the steps (off by default, like every voro3d function).

    Returns
    -------
    voromesh : VoroMesh
        Generators ``(n, 3) float64`` in the input mesh's units, with their occupancy.
    info : FitInfo
        The loss of every step and where the time went; always returned, so the two values
        unpack the same way on every call (``shape, _ = fit(mesh)`` when only the shape matters).

    Raises
    ------
    ValueError
        A bad argument (named in the message), a mesh that is open without ``allow_open``,
        or ``device`` asking for CUDA when none is available.
    MissingExtra
        ``device`` other than ``"cpu"`` without torch installed (an ``ImportError``: ``pip install 'voro3d[torch]'``).

    Notes
    -----
    The loop works in float32 and, for speed, differs from the official code in three ways that
    leave the result unchanged (``benchmarks/profile_fit.py`` measures it): each step's batch is
    a window of consecutive samples at a random offset (the samples are i.i.d., so a window is a
    random batch, and a slice instead of a gather); the kNN candidates are searched again only
    after a generator has moved ``REFRESH_VOXELS`` voxels, the nearest generator and bisector
    being re-ranked among them at every step; the loss gradient is written by hand.

    On CPU the loop does without torch: each step's loss and gradient and the kNN searches come
    from the compiled kernel ``voro3d._fitkernel``, on ``torch.get_num_threads()`` threads when
    torch is loaded, else ``OMP_NUM_THREADS``, else every CPU the process may use; the gradient
    is summed in fixed point, so a seed gives the same bits on any thread count. On CUDA the
    loop runs in torch, the reference the kernel is tested against.
    """
    start = time.perf_counter()
    grid = mesh_grid(grid)
    n_samples = SAMPLES_PER_FACE * grid**2 if n_samples is None else positive_int(n_samples, "n_samples")
    _device(device)  # fail before the sampling, not after

    vertices, triangles = mesh_arrays(mesh)
    with trusted():
        frame = fit_frame((vertices, triangles))
        shape = (frame.apply(vertices), triangles)
        inside = InsideOutside(shape, allow_open=allow_open)  # fails early on an open mesh
        samples, _ = sample_surface(shape, n_samples, seed=seed)
        sampled = time.perf_counter() - start
        result, info = fit_samples(samples, inside.occupancy, grid, frame=frame, steps=steps, lr=lr,
                                   milestones=milestones, gamma=gamma, batch_fraction=batch_fraction, k=k, seed=seed,
                                   device=device, threads=threads, boundary_steps=boundary_steps, progress=progress)
        return result, replace(info, sampling_seconds=sampled, total_seconds=info.total_seconds + sampled)


def fit_samples(samples, inside, grid: int, *, frame=None, steps: int = 400, lr: float = 0.005,
                milestones=(80, 120, 200, 250), gamma: float = 0.5, batch_fraction: float = 0.2,
                k: int = FIT_K, seed: int = 0, device: str = "cpu", threads: int | None = None,
                generators=None, refresh_voxels: float | None = None, boundary_steps: int = 0,
                progress: bool = False) -> tuple[VoroMesh, FitInfo]:
    """Fit a VoroMesh to surface samples, with any inside test: the core of :func:`fit`.

    Parameters
    ----------
    samples : (m, 3) float
        Surface samples in the fit frame (inside ``[-1, 1]^3``).
    inside : callable
        Maps (q, 3) float64 fit-frame points to (q,) bool, True inside the shape (a mesh's
        :class:`voro3d.queries.InsideOutside`, a point cloud's winding number, ...).
    grid, steps, lr, milestones, gamma, batch_fraction, k, seed, device, threads, progress
        As in :func:`fit`.
    frame : voro3d.frames.NormalizationFrame, optional
        The generators are mapped back through ``frame.invert``; None keeps the fit frame.
    generators : (n, 3) float, optional
        Initial generators in the fit frame, e.g. an adaptive band's
        (:meth:`voro3d.generators.AdaptiveBand.generators`, whose level 0 is ``grid``); default
        :func:`~voro3d.generators.initial_generators` of ``grid``. ``grid`` is then their finest
        spacing: the result's voxel; the kNN refresh distance of each generator is scaled by its
        nearest-neighbour distance in those voxels.
    refresh_voxels : float, optional
        The kNN candidates are searched again once a generator has moved this many voxels (at
        most ``MAX_REFRESH_DISTANCE``); default ``REFRESH_VOXELS``.
    boundary_steps : int
        Steps, after the cells are labelled, on the loss of the faces between inside and outside
        cells only (the kernel's ``sides``), at the schedule's last learning rate decayed once
        more; the cells are then labelled again. The loss above pulls any face onto the samples:
        in a wall a cell or two thick a face between two inside cells can hold them while an
        inside cell pokes out.

    Returns
    -------
    voromesh : VoroMesh
        With its grid, frame and Delaunay triangulation (the one its cells were labelled with).
    info : FitInfo
        ``sampling_seconds`` is 0: the samples came in.
    """
    start = time.perf_counter()
    grid = grid_option(grid, allow_auto=False)
    schedule = fit_schedule(steps=steps, lr=lr, milestones=milestones, gamma=gamma, batch_fraction=batch_fraction,
                            k=k, seed=seed, device=device, refresh_voxels=refresh_voxels)
    k = schedule["k"]
    boundary_steps = positive_int(boundary_steps, "boundary_steps", minimum=0)
    samples = as_points(samples, "samples", min_count=4)
    threads = cpu_threads() if threads is None else positive_int(threads, "threads")

    reach = None
    if generators is not None:
        generators = as_points(generators, "generators", min_count=k)
        reach = refresh_reach(generators, grid)
    with trusted():
        generators = initial_generators(samples, grid) if generators is None else generators
        run = optimise_generators(samples, generators, grid, reach=reach, threads=threads, progress=progress,
                                  **schedule)
        generators = run.generators
        optimised = time.perf_counter()

        result = labelled_voromesh(generators, inside, grid, frame=frame)
        if boundary_steps:
            labelled = time.perf_counter()
            # The schedule's learning rate decayed once more: at its last one the restarted Adam shook
            # a converged fit (a sphere at grid 24: the labelled faces' loss 1.20e-6 -> 1.40e-6, at
            # the next one 1.15e-6).
            decays = bisect.bisect_right(schedule["milestones"], schedule["steps"] - 1) + 1
            on_faces = dict(schedule, steps=boundary_steps, lr=schedule["lr"] * schedule["gamma"] ** decays,
                            milestones=[])
            faces = optimise_generators(samples, run.generators, grid, reach=reach, threads=threads,
                                        sides=result.occupancy, loop=run.loop, **on_faces)
            optimised += time.perf_counter() - labelled
            # Labelled again: keeping the labels the faces were fitted between (2026-12-07) left the cells
            # that moved across the target inside, a spike on organic_camel_b's leg (clean 100k CD 0.394 ->
            # 0.890, dense 38 meshes 0.6456 -> 0.6606); it won elsewhere (12 benchmark meshes x 6
            # conditions: CD 0.15-0.8% lower; meshes at grid 32: organic_homer 0.600 -> 0.525).
            result = labelled_voromesh(faces.generators, inside, grid, frame=frame)
        generators = result.generators
        done = time.perf_counter()
        info = FitInfo(
            n_samples=samples.shape[0], n_generators=generators.shape[0], final_loss=run.final_loss, losses=run.losses,
            candidate_searches=run.searches, sampling_seconds=0.0,
            init_seconds=run.init_seconds, optimisation_seconds=optimised - start - run.init_seconds,
            occupancy_seconds=done - optimised, total_seconds=done - start,
        )
        return result, info


def fit_schedule(*, steps: int = 400, lr: float = 0.005, milestones=(80, 120, 200, 250), gamma: float = 0.5,
                 batch_fraction: float = 0.2, k: int = FIT_K, seed: int = 0, device: str = "cpu",
                 refresh_voxels: float | None = None) -> dict:
    """The options of :func:`fit_samples`' loop, checked, defaults filled in: the keywords of
    :func:`optimise_generators` but ``threads`` and ``progress``.

    Raises
    ------
    ValueError
        A step count, k or milestone that is not a positive int, lr not finite and positive,
        refresh_voxels not positive, gamma or batch_fraction outside (0, 1], or an unknown or
        unavailable device.
    """
    refresh_voxels = REFRESH_VOXELS if refresh_voxels is None else refresh_voxels
    if not refresh_voxels > 0:  # inf is allowed: MAX_REFRESH_DISTANCE then sets the distance
        raise ValueError(f"refresh_voxels must be a number > 0, got {refresh_voxels}")
    if not (np.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be a finite number > 0, got {lr}")
    if not 0 < gamma <= 1:
        raise ValueError(f"gamma must be in (0, 1], got {gamma}")
    if not 0 < batch_fraction <= 1:
        raise ValueError(f"batch_fraction must be in (0, 1], got {batch_fraction}")
    return dict(steps=positive_int(steps, "steps"), lr=float(lr),
                milestones=sorted(positive_int(step, "milestones") for step in milestones), gamma=float(gamma),
                batch_fraction=float(batch_fraction), k=positive_int(k, "k", minimum=2), seed=seed,
                device=_device(device), refresh_voxels=float(refresh_voxels))


def labelled_voromesh(generators: np.ndarray, inside, grid: int, *, frame=None) -> VoroMesh:
    """The VoroMesh of fitted ``generators`` (fit frame), each cell labelled by ``inside`` (a fit-frame test).

    Triangulated once, in the result's units (through ``frame.invert``; None keeps the fit frame):
    the labels, any later pass and the extraction share it.
    """
    if frame is not None:
        generators = frame.invert(generators)
        inside = _in_frame(inside, frame)
    triangulation = triangulate(generators)
    occupancy = label_cells(generators, inside, triangulation=triangulation)
    return VoroMesh(generators, occupancy, grid=grid, frame=frame, triangulation=triangulation)


def optimise_generators(samples: np.ndarray, generators: np.ndarray, grid: int, *, reach: np.ndarray | None,
                        steps: int, lr: float, milestones, gamma: float, batch_fraction: float, k: int, seed: int,
                        device: str, threads: int, refresh_voxels: float,
                        fixed: np.ndarray | None = None, sides: np.ndarray | None = None, loop=None,
                        progress: bool = False):
    """Adam on the VoroLoss of ``samples`` over ``generators``: the loop of :func:`fit_samples`, on checked inputs.

    Parameters
    ----------
    samples : (m, 3) float64
        Surface samples, fit frame.
    generators : (n, 3) float64
        Initial generators, fit frame.
    grid : int
        The finest voxel's grid (the kNN refresh distance is in its voxels).
    reach : (n,) float32 or None
        Each generator's nearest-neighbour distance in voxels (:func:`refresh_reach`), None for a
        uniform band.
    steps, lr, milestones, gamma, batch_fraction, k, seed, device, threads, progress
        As in :func:`fit`; ``device`` checked, ``threads`` an int.
    refresh_voxels : float
        As in :func:`fit_samples`, checked.
    fixed : (n,) bool, optional
        Generators that stay where they are (their neighbours' cells still see them).
    sides : (n,) bool, optional
        The generators' labels: the loss is then that of the faces between inside and outside cells.
    loop : voro3d.fitloop.FitLoop, optional
        The ``loop`` of an earlier :class:`Optimised` to go on from, with its samples and generators
        (``generators`` are then its own), their candidates searched again, and a fresh Adam. (Its
        last candidates missed the cells across thin walls: poste_france's bumps stayed.)

    Returns
    -------
    Optimised
        ``generators`` (n, 3) float64, optimised, fit frame, in the given order; ``losses``,
        ``final_loss``, ``searches`` (kNN candidate searches) and ``init_seconds`` (the loop's setup).
    """
    start = time.perf_counter()
    schedule = dict(lr=lr, milestones=milestones, gamma=gamma, seed=seed,
                    refresh_distance=min(refresh_voxels * grid_voxel(grid), MAX_REFRESH_DISTANCE), progress=progress)
    if device == "cpu" and _CPU_KERNEL:
        if loop is None:
            loop = KernelLoop(samples, generators, grid=grid, k=k, batch_fraction=batch_fraction, threads=threads,
                              reach=reach)
        else:
            loop.search()
        loop.fixed = fixed
        loop.sides = sides
        initialised = time.perf_counter()
        losses = loop.run(steps, **schedule)
        final_loss = loop.loss()
    else:
        import torch

        from ._torchfit import TorchLoop

        if loop is None:
            loop = TorchLoop(samples, generators, grid=grid, k=k, batch_fraction=batch_fraction,
                             device=torch.device(device), reach=reach)
        else:
            loop.search()
        loop.fixed = None if fixed is None else torch.as_tensor(fixed, device=loop.generators_t.device)
        loop.sides = None if sides is None else torch.as_tensor(sides, device=loop.generators_t.device)
        initialised = time.perf_counter()
        previous = torch.get_num_threads()
        if device == "cpu":
            torch.set_num_threads(1)
        try:
            losses = loop.run(steps, **schedule)
            final_loss = loop.loss()
        finally:
            torch.set_num_threads(previous)
    return Optimised(loop.generators(), losses, final_loss, loop.searches, initialised - start, loop)


def refresh_reach(generators: np.ndarray, grid: int) -> np.ndarray:
    """(n,) float32, ``>= 1``: each generator's nearest-neighbour distance in ``grid`` voxels.

    Given generators (an adaptive band's) are spaced by their own leaves' voxels: one moves as far
    before its candidates go stale, and the candidate search's cells follow their median. Against
    the finest voxel for all, a 1M-point fandisk over 3 levels (128^3 to 32^3) searched 12 times
    where the uniform 64^3 band searched 3, and the fit took 1.7x as long per sample.
    """
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(generators).query(generators, k=2)
    return np.maximum(distance[:, 1] / grid_voxel(grid), 1.0).astype(np.float32)


def _in_frame(inside, frame):
    """``inside`` (a fit-frame test) for points in the frame's original units."""
    return lambda points: inside(frame.apply(points))


def _device(device) -> str:
    """``device`` checked: ``"cpu"``, which needs no torch, or the name of an available CUDA device."""
    if device == "cpu":
        return "cpu"
    torch = require("torch", f"device={device!r}")
    try:
        torch_device = torch.device(device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"device must be 'cpu' or 'cuda', got {device!r}") from error
    if torch_device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} was asked for but CUDA is not available")
    if torch_device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda', got {device!r}")
    return str(torch_device)

