"""Point cloud -> VoroMesh: clean, orient, build a smooth target surface, fit the generators to it.

Raw points are neither dense nor exact: a 5,000-point scan leaves most voxels of a 64^3 grid empty, and noise pulls
generators off the surface. So the VoroLoss fit sees dense samples (as many as a mesh fit gets) of a target surface
that the points define: screened Poisson for points that enclose a volume (:mod:`voro3d.pointcloud.poisson`), carved
where it buries points that were seen (:mod:`voro3d.pointcloud.sightlines`); a robust IMLS field with the winding
number of the points behind it for open, one-sided scans, held within a shell's depth of the points where they do not
enclose it (:mod:`voro3d.pointcloud.surface`); or, for walls sampled on both sides closer than the point spacing, a
shell around the points (:func:`~voro3d.pointcloud.shell.sheet_surface`); the same target labels the cells.
:func:`cloud_mesh` extracts the watertight mesh, cleans it and fits its vertices to the target
(:func:`voro3d.snapping.snap_to_surface`), its triangles split first where the target is finer than the grid.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..queries import point_areas
from ..snapping import NOISY_SMOOTHING
from ..geometry import grid_voxel
from .normals import REPAIRABLE_SHARE, estimate_normals, orient_normals, repair_normals, sign_disagreement, unusable_normals
from .preprocess import MAX_SURFACE_DIMENSION, MAX_SURFACE_FILL, cloud_stats, fill_ratio, local_dimension, merge_duplicates, outlier_mask, outlier_neighbours
from .scanlines import thin_lines
from .poisson import poisson_depth, poisson_helper
from .resolution import choose_grid, fit_band, refine_levels, target_samples
from .plan import as_plan, CloudPlan, settle_denoise, settle_filter, settle_hull, settle_normals
from .sides import outward_normals
from .surface import imls
from .debris import drop_stray_cells
from .hull import cropped_rim, reach_past_hull
from .targets import build_target, check_coverage
from .tiles import ENGINES, analysis_subset, fit_in_tiles
from .tuning import (CLOUD_STEPS, CLOUD_BOUNDARY_STEPS, CLOUD_REFRESH_VOXELS, WIDTH_PER_SPACING,
                     TRUSTED_WIDTH_PER_SPACING, WIDTH_PER_NOISE, MAX_TRUSTED_OUTLIERS, MIN_NORMAL_AGREEMENT,
                     MAX_SIGN_DISAGREEMENT, NOISY, DENSE_SPACINGS, MAX_TARGET_GRID, CLOSED_LEVEL, FIELD_REFINEMENT,
                     MAX_FIELD_RESOLUTION)

__all__ = ["PointCloudInfo", "SnapTarget", "reconstruct_points", "cloud_mesh"]

MIN_POINTS = 100
# The VoroLoss fit of the target samples, or the learned model on the target's SDF grid.
METHODS = ("fit", "learned")


@dataclass(frozen=True)
class PointCloudInfo:
    """What :func:`reconstruct_points` found and where the time went.

    Attributes
    ----------
    n_points, n_outliers : int
        Points given, and points removed as outliers.
    spacing, noise : float
        Median point spacing and estimated noise (standard deviation), in the input's units.
    noisy : bool
        Whether the fine-scale noise is over ``NOISY`` spacings.
    normals : str
        Where the normals came from: ``"estimated"`` or ``"given"``, then ``", re-oriented"`` when
        the given signs disagreed between neighbours (``MAX_SIGN_DISAGREEMENT``), ``", N repaired"``
        when N were zero, NaN or inf (taken from their neighbours) and ``", flipped"`` when they
        pointed inward; ``"estimated (...)"`` when over ``REPAIRABLE_SHARE`` of the given ones were
        unusable (``plan.normals`` ``"check"``; ``"trust"`` refuses them).
    level : float
        Winding level of the oriented points (:func:`~voro3d.pointcloud.sides.winding_level`,
        clipped to 0-0.5): over ``CLOSED_LEVEL`` they enclose a volume.
    plan : CloudPlan
        The plan as it ran, every choice settled (:mod:`~voro3d.pointcloud.plan`); read from it:
        ``smoothed`` (bool: the noise-smoothing pass ran), ``filtered`` (bool: the Poisson target
        was bilateral-filtered) and ``target`` (``"poisson"``, ``"imls"`` or ``"sheet"``).
    grid, levels : int
        VoroMesh grid used (its finest level), and the coarser levels of the adaptive band
        (:class:`voro3d.generators.AdaptiveBand`); 0 for a uniform grid.
    voxel : float
        The grid's voxel, in the input's units.
    offset : float
        How far the target keeps from the points by design, in the input's units: the shell's
        offset for target ``"sheet"``, else 0.
    tiles : int
        Tiles the fit was cut into (:mod:`voro3d.pointcloud.tiles`): 0 for one loop (``TILE_POINTS`` points or fewer).
    seconds : dict
        ``clean`` (outliers, statistics), ``normals``, ``surface`` (field and proxy mesh),
        ``samples`` (sampling and projection), ``fit`` (VoroLoss fit and cell labels).
    """

    n_points: int
    n_outliers: int
    spacing: float
    noise: float
    noisy: bool
    normals: str
    level: float
    plan: CloudPlan
    grid: int
    levels: int
    voxel: float
    offset: float
    tiles: int
    seconds: dict

    @property
    def smoothed(self) -> bool:
        return self.plan.denoise == "on"

    @property
    def filtered(self) -> bool:
        return self.plan.filter == "on"

    @property
    def target(self) -> str:
        return self.plan.target


@dataclass(frozen=True)
class SnapTarget:
    """The smooth surface a cloud's VoroMesh was fitted to, handed to the stages after extraction.

    Attributes
    ----------
    vertices : (v, 3) float64
        In the input's units.
    triangles : (t, 3) int64
    snap : bool
        Whether the cleaned mesh is fitted to it (:func:`cloud_mesh`): where the VoroMesh was
        fitted to samples of it (not a dense clean cloud, fitted to its own points).
    smoothing : float
        The snap's pull of each vertex towards its neighbours (``NOISY_SMOOTHING`` for a noisy cloud).
    refine : int
        Times the triangles are split in four before the snap (:func:`~voro3d.pointcloud.resolution.refine_levels`).
    """

    vertices: np.ndarray = field(repr=False)
    triangles: np.ndarray = field(repr=False)
    snap: bool
    smoothing: float
    refine: int = 0


def report_phase(progress: bool, phase: str, text: str, seconds: float | None = None) -> None:
    """One line on stderr for a phase, with its time when finished, when ``progress`` (beside any tqdm bar)."""
    if progress:
        from tqdm import tqdm

        tqdm.write(f"voro3d {phase:<8} {text}" + ("" if seconds is None else f" ({seconds:.1f} s)"), file=sys.stderr)


def reconstruct_points(points, normals=None, *, grid="auto", method: str = "fit", steps: int | None = None,
                       seed: int | None = None, device: str | None = None, model=None, threads: int | None = None,
                       plan=None, engine: str = "local", workers: int | None = None, progress: bool = False):
    """VoroMesh of a point cloud, through a smooth target surface.

    1. Repeated points merged (:func:`~voro3d.pointcloud.preprocess.merge_duplicates`), points on
       scan lines far apart thinned along them (``plan.thin``), outliers out
       (:func:`~voro3d.pointcloud.preprocess.outlier_mask`), spacing and noise measured; a cloud
       that fills a volume instead of sampling a surface is refused.
    2. The plan (:class:`~voro3d.pointcloud.plan.CloudPlan`): its fields left ``"auto"`` are
       settled from what steps 1-3 find, and the chosen plan is printed with ``progress``.
       Normals: the given ones, checked (zero, NaN or inf ones taken from their neighbours,
       :func:`~voro3d.pointcloud.normals.repair_normals`; signs inconsistent between neighbours: re-oriented,
       :func:`~voro3d.pointcloud.normals.orient_normals`; all inward: flipped), else estimated
       and oriented (:func:`estimate_normals`); a cavity's wall facing into the cavity is turned
       back (:func:`~voro3d.pointcloud.sides.outward_normals`).
    3. On a noisy cloud (``plan.denoise``), IMLS (its kernel spans several noise deviations)
       smooths the normals (a second pass where they mostly agree, ``MIN_NORMAL_AGREEMENT``), then
       moves the points onto the smooth surface and replaces their normals with the field's.
    4. The target, without the pieces the points do not support: screened Poisson when the
       points enclose a volume (their winding level is over ``CLOSED_LEVEL``; bilateral-filtered
       where the noise is over ``HEAVY_NOISE`` octree cells, :mod:`~voro3d.pointcloud.denoise`; from
       ``SPLIT_POINTS`` points on, solved in two halves at once, one in a second process started
       with the call, :func:`~voro3d.pointcloud.poisson.poisson_surface`); for an open,
       one-sided scan the IMLS field near the points and their winding number away from them,
       held by the points' convex hull where ``plan.hull`` cuts to it (auto: open clouds), else
       within each point's shell depth (its curvature's radius, at most ``SHELL_DEPTH``) of the points
       where they do not enclose it (a shell under the seen side, not a block out to the box), on a
       grid twice as fine as the VoroMesh grid, meshed by Marching Cubes. Either cut back to the
       points' convex hull where ``plan.hull`` asks (:mod:`~voro3d.pointcloud.hull`).
    5. The VoroLoss samples: ``CLOUD_SAMPLES_PER_FACE grid^2`` (75) of them from the target mesh,
       or, for a dense scan, the points themselves (:func:`~voro3d.pointcloud.resolution.target_samples`); the target
       labels the cells.

    A cloud of more than ``TILE_POINTS`` points is reconstructed from a uniform subset of
    ``ANALYSIS_POINTS`` (:func:`~voro3d.pointcloud.tiles.analysis_subset`: at the target's resolution
    the rest adds nothing), and its fit runs in tiles of at most ``TILE_SAMPLES`` samples
    (:mod:`voro3d.pointcloud.tiles`), as tasks of a local process pool or of Ray.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 or None
        Outward normals, or None (or an empty array, as ``np.asarray(cloud.normals)`` gives for an
        Open3D cloud without normals) to estimate them.
    grid : int or "auto"
        VoroMesh grid, at least 4 (uniform); ``"auto"`` picks the finest from the spacing
        (:func:`auto_grid`: 32-128) and, for the fit, an adaptive band over it
        (:mod:`voro3d.pointcloud.resolution`). A grid finer than :func:`max_supported_grid` works
        but warns.
    method : {"fit", "learned"}
        VoroLoss fit, or the ONNX network on the target's signed distance grid.
    steps, seed, device : int, int, str, optional
        As in :func:`voro3d.fit` (defaults ``CLOUD_STEPS`` = 120, 0, ``"cpu"``: a cloud's mesh is fitted to its
        target afterwards; its candidates are searched again after ``CLOUD_REFRESH_VOXELS`` = 2.5 voxels of a
        move); refused with ``method="learned"``, which uses none of them.
    model, threads
        As in :func:`voro3d.reconstruct`.
    progress : bool
        As in :func:`voro3d.fit`, and one line on stderr per phase (clean, normals, target, fit)
        with what it chose and its time.
    plan : CloudPlan, dict or None
        The choices of steps 1-4 (:class:`~voro3d.pointcloud.plan.CloudPlan`), or a dict of some of
        them; None or ``"auto"`` fields are decided from the cloud. ``info.plan`` is the plan as it ran.
    engine : {"local", "ray"}
        Where a tiled fit's tiles run: a local process pool, or Ray tasks
        (:func:`~voro3d.pointcloud.tiles.fit_tiles`); the same mesh either way.
    workers : int, optional
        Tiles fitted at once; default one per CPU.

    Returns
    -------
    voromesh : voro3d.VoroMesh
        In the input's units, with its grid, frame and triangulation.
    target : SnapTarget
        The target surface, for :func:`cloud_mesh`.
    info : PointCloudInfo

    Raises
    ------
    ValueError
        Too few points left after outlier removal, a cloud that fills a volume, normals that
        cannot be estimated, an unknown method, an option the method does not use, or a plan
        with an unknown field or choice (``plan={"normals": "check"}`` without normals too).
    """
    from .._validate import as_points, trusted

    points = as_points(points, "points", min_count=MIN_POINTS)
    if normals is not None:
        normals = np.asarray(normals, np.float64)
        if normals.size == 0:
            normals = None
        elif normals.shape != points.shape:
            raise ValueError(f"normals must have the points' shape {points.shape}, got {normals.shape}")
    plan = as_plan(plan)
    with trusted(), poisson_helper(points.shape[0], threads, wanted=plan.target in ("auto", "poisson")) as helper:
        return _reconstruct_points(points, normals, grid=grid, method=method, steps=steps, seed=seed, device=device,
                                   model=model, threads=threads, plan=plan, engine=engine, workers=workers,
                                   progress=progress, helper=helper)


def _reconstruct_points(points, normals, *, grid, method, steps, seed, device, model, threads, plan, engine, workers,
                        progress, helper):
    """:func:`reconstruct_points` on checked inputs."""
    from scipy.spatial import cKDTree

    from .._validate import method_options, positive_int
    from ..frames import fit_frame

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if workers is not None:
        workers = positive_int(workers, "workers")
    fit_options = method_options(method, "fit", steps=steps, seed=seed, device=device)
    model = method_options(method, "learned", model=model).get("model")
    if method == "fit":
        fit_options.setdefault("steps", CLOUD_STEPS)
        fit_options["refresh_voxels"] = CLOUD_REFRESH_VOXELS

    normal_plan = settle_normals(plan, normals is not None)
    if normal_plan == "estimate":
        normals = None
    seconds = {}
    start = time.perf_counter()
    n_points = points.shape[0]
    points, normals = merge_duplicates(points, normals)
    repaired, dropped = 0, ""
    if normals is not None:  # zero, NaN or inf ones (scanners write them) from their neighbours
        unusable = int(unusable_normals(normals).sum())
        if normal_plan == "check" and unusable > REPAIRABLE_SHARE * len(normals):
            # Past that share our own estimate does as well (the measurement beside it).
            dropped = f" ({unusable:,} of the {len(normals):,} given normals were zero, NaN or inf)"
            normals, normal_plan = None, "estimate"
        else:
            repaired, normals = unusable, repair_normals(points, normals)
    # A dense cloud is reconstructed from a subset (see the docstring).
    distinct, subset = points.shape[0], analysis_subset(points.shape[0], fit_options.get("seed", 0))
    if subset is not None:
        points, normals = points[subset], None if normals is None else normals[subset]
    frame = fit_frame(points)
    framed = frame.apply(points)
    tree = cKDTree(framed)
    before, rounds = len(framed), 0
    if plan.thin != "off":
        framed, normals, rounds = thin_lines(framed, normals, tree=tree, force=plan.thin == "on", min_points=MIN_POINTS)
    if rounds:
        points, tree, normals = frame.invert(framed), cKDTree(framed), normals if normals is None else repair_normals(framed, normals)
    # One kNN table for the outlier tests, the spacing and the point areas (1M points: 4.7 s less).
    neighbours = outlier_neighbours(framed, tree=tree)
    outliers = outlier_mask(framed, tree=tree, neighbours=neighbours)
    if n_points - outliers.sum() < MIN_POINTS:
        raise ValueError(f"{int(outliers.sum())} of {n_points} points look like outliers; fewer than {MIN_POINTS} "
                         "surface points are left")
    if outliers.any():
        points = points[~outliers]
        normals = None if normals is None else normals[~outliers]
        frame = fit_frame(points)  # without the outliers, which may have stretched the box
        framed = frame.apply(points)
        tree, neighbours = cKDTree(framed), None
    seconds["clean"] = time.perf_counter() - start
    start = time.perf_counter()
    normal_source = None if normals is None else "given"
    if normals is not None and normal_plan == "check" and sign_disagreement(framed, normals, tree=tree) > MAX_SIGN_DISAGREEMENT:
        # Normals whose signs were never made consistent (a bare estimate_normals(), say):
        # their axes are kept, their signs set as for our own.
        normals, normal_source = orient_normals(framed, normals), "given, re-oriented"
    seconds["normals"] = time.perf_counter() - start
    start = time.perf_counter()
    # Given normals tell the two sides of a thin wall apart: the far side stays out of the noise and the point areas
    # (bench_thin_walls; 12 dev meshes with their true normals, clean 5k / clean 20k / 0.5% noise, mean CD 12.6 ->
    # 1.65, 2.06 -> 0.80, 4.35 -> 3.83, none worse by 0.3%). Ours do not: their signs are 38-47% wrong across such
    # walls, and used so on 14 dev meshes x 6 conditions without normals, the lid abc_00000007 went from CD 47.8 to
    # 445 (clean 5k) and 14.7 to 117 (clean 20k); the other 82 clouds moved by -8% to +9% (the noisy ones -1%).
    sides = normals if normal_source == "given" else None
    stats = cloud_stats(framed, tree=tree, neighbours=neighbours, normals=sides)
    if not stats.median_spacing > 1e-9:
        raise ValueError("most points are duplicated (their neighbours sit at the same position): no surface can be "
                         "fitted to them")
    noisy = stats.fine_noise > NOISY * stats.median_spacing
    fill = fill_ratio(framed, stats.median_spacing)
    # Points spread through a volume have no plane at the spacing's scale (they read as noisy: 0.31-0.32
    # spacings from 300 to 50k points in a box, a slab or a rod); a clean sparse surface does, and its
    # few points can read like a volume on the other two tests (abc_00000005 at 1,000 points: fill
    # 0.74, dimension 2.47, fine noise 0). The dimension needs 128 neighbours per point (1.6 s at 10^5
    # points): only when the cheap tests already read like a volume.
    if noisy and fill > MAX_SURFACE_FILL and (dimension := local_dimension(framed, tree=tree)) > MAX_SURFACE_DIMENSION:
        raise ValueError(f"the points fill a volume instead of sampling a surface (local dimension {dimension:.2f}, "
                         f"fill ratio {fill:.2f}; a sampled surface reads about 2 and under 0.25): no surface to "
                         "reconstruct")
    grid, levels = choose_grid(grid, stats.median_spacing, adaptive=method == "fit", exact=not noisy)
    seconds["clean"] += time.perf_counter() - start
    report_phase(progress, "clean", f"{len(points):,} points kept of "
                 f"{n_points:,}{f' (a subset of {distinct:,} distinct)' if subset is not None else ''}"
                 f"{f' (thinned along its scan lines, {before:,} -> {len(framed):,})' if rounds else ''} "
                 f"({int(outliers.sum()):,} outliers), "
                 f"spacing {stats.median_spacing / frame.scale:.3g}, noise {stats.noise / frame.scale:.3g}, grid {grid}"
                 f"{f' adaptive over {levels + 1} levels' if levels else ''}",
                 seconds["clean"])

    start = time.perf_counter()
    if normals is None:
        normals, normal_source = estimate_normals(framed, walls=stats.walls, neighbours=neighbours), "estimated"
        normal_source += dropped
    seconds["normals"] += time.perf_counter() - start
    walls = "" if stats.walls is None or not stats.walls.any() else \
        f" ({stats.walls.sum():,} points, {stats.walls.mean():.1%}, span both sides of a thin wall: fitted on their nearer side)"
    if repaired and normal_source.startswith("given"):
        normal_source += f", {repaired:,} repaired"
    report_phase(progress, "normals", normal_source + walls, seconds["normals"])

    start = time.perf_counter()
    # Clean points are followed closely; noisy ones, or a cloud that held strays, are averaged.
    trusted = not noisy and outliers.mean() < MAX_TRUSTED_OUTLIERS
    # The target's resolution follows the grid only up to MAX_TARGET_GRID; an adaptive band's finer
    # levels take their detail from the samples (dense points, or the target's own finer mesh).
    target_grid = min(grid, MAX_TARGET_GRID)
    dense = trusted and stats.median_spacing < DENSE_SPACINGS * grid_voxel(target_grid)
    # Dense clouds are fitted on their own points; their field only fills holes and must not
    # reach past its band with the planes of single points, so they keep the wider kernel.
    per_spacing = TRUSTED_WIDTH_PER_SPACING if trusted and not dense else WIDTH_PER_SPACING
    widths = np.maximum(per_spacing * stats.spacing, WIDTH_PER_NOISE * stats.noise)
    areas = point_areas(framed, tree=tree, distances=None if neighbours is None else neighbours[0],
                        indices=None if neighbours is None else neighbours[1], normals=sides)
    normals, level, flipped, turned = outward_normals(framed, normals, areas, float(np.median(widths)),
                                                      turn=normal_plan != "trust")
    neighbours = None  # 21 neighbours a point: not kept through the fit
    normal_source += ", flipped" if flipped else ""
    level = min(max(level, 0.0), 0.5)
    closed = level > CLOSED_LEVEL
    cropped = not closed and plan.hull != "on" and cropped_rim(framed, normals, tree=tree)
    denoise = settle_denoise(plan, noisy=noisy, closed=closed, dense=dense)
    given = framed
    if denoise == "on":
        value, gradient, agreement = imls(framed, normals, widths, framed, tree=tree)
        if noisy and np.median(agreement) > MIN_NORMAL_AGREEMENT:
            value, gradient, _ = imls(framed, gradient, widths, framed, tree=tree)
        framed = framed - value[:, None] * gradient
        normals = gradient
    depth = poisson_depth(target_grid, stats.median_spacing)
    resolution = min(FIELD_REFINEMENT * target_grid, MAX_FIELD_RESOLUTION)
    filtered = settle_filter(plan, smoothed=denoise == "on", noisy=noisy, noise=stats.noise, depth=depth)
    kind, target, distance, why = build_target(plan.target, framed, given, normals, widths, stats, level=level, closed=closed,
                                               depth=depth, resolution=resolution, filtered=filtered == "on",
                                               dense=dense and denoise == "off", cropped=cropped, helper=helper,
                                               hull=settle_hull(plan, closed=closed) == "on")
    if kind == "sheet":
        framed = given
    filtered = filtered if kind == "poisson" else "off"
    check_coverage(target, framed, widths, distance=distance if framed is given else None)
    surface_vertices = target.project(target.vertices)
    plan = CloudPlan(normals=normal_plan, denoise=denoise, filter=filtered, target=kind,
                     hull=settle_hull(plan, closed=closed, kind=kind), thin="on" if rounds else "off")
    seconds["surface"] = time.perf_counter() - start
    # What the plan's hull would cut, read for the report only.
    past = reach_past_hull(target, framed, resolution) if progress and plan.hull == "off" and kind != "sheet" else 0.0
    flat = ", and target imls with it closes it flat" if kind == "poisson" else ""
    reach = (f"; its closure reaches {past / 2:.0%} of the diagonal past the points' convex hull (plan hull on cuts "
             f"it back{flat}: scans from a few viewpoints)" if past else "")
    notes = ([why] if why else []) + getattr(target, "carves", [])
    notes += [f"{turned:,} normals on a cavity's wall turned inward"] if turned else []
    report_phase(progress, "target", f"{kind}{f' depth {depth}' if kind == 'poisson' else ''}{''.join(', ' + note for note in notes)}"
                 f"{' (flipped normals)' if normal_source.endswith('flipped') else ''}, "
                 f"{'closed' if closed else 'open'} (winding level {level:.2f}); plan: {plan}{reach}", seconds["surface"])

    start = time.perf_counter()
    n_tiles = 0
    if method == "learned":
        shape = _predict(target, grid, frame, model=model, threads=threads)
        seconds["samples"], seconds["fit"] = 0.0, time.perf_counter() - start
    else:
        from ..fitting import fit_samples

        band = fit_band(surface_vertices, grid, levels)
        samples = target_samples(target, surface_vertices, framed, grid, band=band, seed=fit_options.get("seed", 0))
        seconds["samples"] = time.perf_counter() - start
        start = time.perf_counter()
        # The grid's nodes about the target, not pairs across it (one pair a voxel, 0.3 voxels either side
        # of the target's sample nearest the voxel's centre): 6 dev meshes x clean 20k / 3 / 6 views, grid 64
        # (2026-12-06), 120 steps CD +1.1% / -0.0% / +2.1%, NC -0.0006 / -0.0021 / -0.0009, 13-15% more
        # faces, the fit 1.1-1.5x; 40 steps the fit 0.67-1.03x, CD +2.4% / +0.2% / +5.4%, NC -0.003 to
        # -0.006, 39-43% more faces. Thin walls gain nothing either (abc_00000006 from 6 views CD 21.8 -> 28.0).
        generators = None if band is None else band.generators()
        if subset is None:
            shape, _ = fit_samples(samples, target.inside, grid, frame=frame, threads=threads, progress=progress,
                                   generators=generators, boundary_steps=CLOUD_BOUNDARY_STEPS, **fit_options)
        else:
            shape, n_tiles = fit_in_tiles(samples, generators, target.inside, grid, levels=levels, frame=frame,
                                          engine=engine, workers=workers, threads=threads, progress=progress,
                                          options=fit_options)
        n_samples = len(samples)
        shape = drop_stray_cells(shape)
        seconds["fit"] = time.perf_counter() - start
    report_phase(progress, "fit", f"{method}, {len(shape.generators):,} generators, "
                 f"{n_samples if method == 'fit' else 0:,} samples{f', {n_tiles} tiles' if n_tiles else ''}", seconds["fit"])
    info = PointCloudInfo(n_points=n_points, n_outliers=int(outliers.sum()),
                          spacing=stats.median_spacing / frame.scale, noise=stats.noise / frame.scale,
                          noisy=bool(noisy), normals=normal_source, level=level, plan=plan, grid=grid, levels=levels,
                          voxel=grid_voxel(grid) / frame.scale, offset=target.offset / frame.scale if kind == "sheet" else 0.0,
                          tiles=n_tiles, seconds=seconds)
    surface = SnapTarget(frame.invert(surface_vertices), target.triangles, snap=not target.dense,
                         smoothing=NOISY_SMOOTHING if noisy else 0.0,
                         refine=refine_levels(kind, depth, grid, stats.median_spacing, exact=not noisy))
    return shape, surface, info


def cloud_mesh(shape, target: SnapTarget, *, clean: bool = True, progress: bool = False):
    """The watertight mesh of :func:`reconstruct_points`' VoroMesh.

    Parameters
    ----------
    shape : voro3d.VoroMesh
    target : SnapTarget
        From the same call.
    clean : bool
        Clean the surface (:func:`voro3d.cleaning.clean`) and, where ``target.snap``, fit its
        vertices to the target surface (:func:`voro3d.snapping.snap_to_surface`: at most a
        quarter voxel, no triangle flipped, thinned or crossing; with ``target.smoothing``, the
        triangles split ``target.refine`` times first).
    progress : bool
        One line on stderr when done, as in :func:`reconstruct_points`.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, manifold, outward-oriented, no crossing triangles, with vertex normals.
    """
    start = time.perf_counter()
    snap = clean and target.snap
    mesh = shape.to_open3d(clean=clean, surface=(target.vertices, target.triangles) if snap else None,
                           smoothing=target.smoothing, refine=target.refine if snap else 0)
    # A split that would make triangles cross is not made (geometry.split_triangles): "up to".
    done = ", cleaned" + ("" if not snap else " and fitted to the target" if not target.refine else
                          f", each triangle split in up to {4**target.refine} and fitted to the target") if clean else ""
    report_phase(progress, "mesh", f"{len(mesh.triangles):,} triangles, watertight{done}", time.perf_counter() - start)
    return mesh


def _predict(target, grid: int, frame, *, model, threads):
    """The learned model on the target's signed distance at the ``grid^3`` nodes."""
    from ..infer import predict
    from ..sampling import grid_nodes
    from ..voromesh import VoroMesh

    nodes = grid_nodes(grid)
    distance = target.distance(nodes)
    sdf = np.where(target.inside(nodes), -distance, distance).reshape(grid, grid, grid).astype(np.float32)
    shape = predict(sdf, model=model, threads=threads)
    return VoroMesh(frame.invert(shape.generators), shape.occupancy, grid=grid, frame=frame)
