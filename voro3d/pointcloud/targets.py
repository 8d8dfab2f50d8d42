"""The target surface a cloud's VoroMesh is fitted to: which one, built, and checked against the points.

Screened Poisson for points that enclose a volume (:mod:`voro3d.pointcloud.poisson`), carved where it
buries points that were seen (:mod:`voro3d.pointcloud.sightlines`); the IMLS field for an open scan,
or one whose Poisson surface runs off (:mod:`voro3d.pointcloud.surface`); either cut back to the
points' convex hull where the plan asks (:mod:`voro3d.pointcloud.hull`); a shell around the points where it lies closer
to them (:func:`~voro3d.pointcloud.plan.sheet_if_closer`). A target that misses the points is refused
(:func:`check_coverage`).
"""
from __future__ import annotations

import numpy as np

from .plan import sheet_if_closer, sheet_target
from .poisson import poisson_surface
from .hull import clip_to_hull
from .preprocess import check_stride
from .sightlines import carve_sightlines
from .surface import shell_depths, target_surface
from .tuning import FILTER_WIDTH_PER_NOISE, HOLE_LEVEL, MAX_POISSON_ESCAPE, MIN_COVERAGE, SHELL_DEPTH, THINNEST_SHELL_NODES

__all__ = ["build_target", "check_coverage"]


def build_target(choice: str, points, given, normals, widths, stats, *, level: float, closed: bool, depth: int,
                 resolution: int, filtered: bool, dense: bool, hull: bool, cropped: bool = False, helper):
    """``(kind, target, distance, why)``: the target surface of a plan's ``target`` field.

    Parameters
    ----------
    choice : {"auto", "poisson", "imls", "sheet"}
        ``"auto"`` is the rule of :class:`~voro3d.pointcloud.plan.CloudPlan`.
    points, given : (n, 3) float64
        Fit frame: the points the field is built from (smoothed or not), and the points as they
        came, for the shell.
    normals, widths : (n, 3) float64, (n,) float64
        Unit outward normals and kernel widths of ``points``.
    stats : CloudStats
    level : float
        Winding level of the points; ``closed`` when over ``CLOSED_LEVEL``.
    depth, resolution : int
        Poisson octree depth and the IMLS field's (and carve grid's) nodes per side.
    filtered, dense, hull, cropped : bool
        Bilateral-filter the Poisson input; fit the IMLS target to the points themselves; cut a
        Poisson or IMLS target back to the points' hull; an open cloud's rim is a crop
        (:func:`~voro3d.pointcloud.hull.rim_facing`): held ``THINNEST_SHELL_NODES`` deep behind it.
    helper
        Solves half of a split Poisson surface (:func:`~voro3d.pointcloud.poisson.poisson_surface`).

    Returns
    -------
    kind : str
        ``"poisson"``, ``"imls"`` or ``"sheet"``.
    target
        The surface (fit frame).
    distance : (m,) float64 or None
        Of every :func:`~voro3d.pointcloud.preprocess.check_stride`-th point of ``given`` to the
        target, where the rule measured it.
    why : str
        For the plan's report: why a closed cloud's target is not Poisson, why its Poisson
        target was not carved, or why the target is the shell; empty otherwise.
    """
    if choice == "sheet":
        return "sheet", sheet_target(given, stats.median_spacing, resolution), None, ""
    target, why = None, ""
    if choice == "poisson" or (choice == "auto" and closed):
        target = poisson_surface(points, normals, depth, filter_width=FILTER_WIDTH_PER_NOISE * stats.noise if filtered else None,
                                 helper=helper)
        escape = target.escape(points) if choice == "auto" else 0.0
        if escape > MAX_POISSON_ESCAPE:
            # A flap: normals that disagree across a thin wall. The local IMLS field does not reach out.
            # (Building it beside the solve, in a second process, lost: on this 2-CPU machine a busy
            # second process halves the first's speed, Open3D's solve of 5k points 0.9 -> 1.9 s beside
            # a pure-Python loop. Refused 3-view scans gained 1.5 s, bunny 8.8 -> 7.3 s; kept ones lost
            # 1 s, cow 5k 2.6 -> 3.4 s; 2026-12-05. Nor does foreseeing the refusal with a coarse solve:
            # on 59 Poisson targets of the 12 benchmark meshes (3 and 6 views, a third missing, 5k,
            # 1% noise), depth 6 on 6000 of the points took 0.28-0.65 s a cloud, 24.5 s in all, to
            # spare the 15.2 s of the 6 refused solves, and refused one kept (homer from 3 views). Nor the
            # points' winding number, which Poisson's indicator follows far from the points: its largest value
            # over the box's faces pushed 0.04-0.2 diagonals out, less or not its mean at the points, on 221
            # solves of the 38 dev meshes (38 refused, 104 of the 600 s solving) spares at most 3 refused
            # solves without refusing a kept one: bench_poisson_foresight.py, poisson_foresight.md.)
            target, why = None, f"Poisson refused: its surface ran {escape:.0%} of the diagonal out of the points' box"
        else:
            target, why = carve_sightlines(target, points, normals, stats.median_spacing, resolution)
    kind = "poisson" if target is not None else "imls"
    if target is None and cropped:
        why = "its rim a crop, not a silhouette: a thin shell behind it"
    if target is None:
        # Behind an open scan the solid is held by the points' hull where it is cut to it, else within
        # each point's shell depth (a shell under the seen side; the thinnest behind a crop, which is no
        # side of a body); a closed cloud's holes are closed at HOLE_LEVEL. The measurement: beside SHELL_DEPTH.
        target = target_surface(points, normals, widths, resolution, dense=dense, level=level,
                                hole_level=max(level, HOLE_LEVEL) if closed else None,
                                depth=None if closed or (hull and not cropped)
                                else _shell_depth(points, normals, resolution, cropped))
    if hull:
        target = clip_to_hull(target, points, resolution)
    if choice == "auto" and not target.dense:
        distance = target.distance(given[::check_stride(len(given))])
        # A closed cloud's target closes its holes, and so fills what thin walls enclose (a bowl as a dome).
        walls = float(np.mean(stats.walls)) if closed and stats.walls is not None else 0.0
        sheet = sheet_if_closer(target, given, stats.median_spacing, resolution, distance=distance, walls=walls)
        if sheet is None:
            return kind, target, distance, why
        shell = f"a shell around the points fits them much closer than the {kind} target (walls sampled on both sides)"
        return "sheet", sheet, None, f"{why}; {shell}" if why else shell
    return kind, target, None, why


def _shell_depth(points, normals, resolution: int, cropped: bool) -> np.ndarray:
    """Each point's depth behind an open scan (:func:`~voro3d.pointcloud.surface.shell_depths`): from
    ``THINNEST_SHELL_NODES`` nodes of the field's grid up to ``SHELL_DEPTH``; the least behind a crop."""
    from ..geometry import grid_voxel

    least = THINNEST_SHELL_NODES * grid_voxel(resolution)
    return np.full(len(points), least) if cropped else shell_depths(points, normals, SHELL_DEPTH, least)


def check_coverage(target, points, widths, *, distance=None) -> None:
    """Refuse a target surface that misses the points: one that no volume behind them explains (a
    one-sided scan of a thin or open structure).

    Read from every :func:`~voro3d.pointcloud.preprocess.check_stride`-th point, whose ``distance``
    to the target may be given.

    Raises
    ------
    ValueError
        Fewer than ``MIN_COVERAGE`` of the points within two kernel widths and a field node of it.
    """
    every = slice(None, None, check_stride(len(points)))
    distance = target.distance(points[every]) if distance is None else distance
    covered = float(np.mean(distance <= 2.0 * widths[every] + 2.0 / (target.resolution - 1)))
    if covered < MIN_COVERAGE:
        raise ValueError(f"no closed surface explains these points: only {100 * covered:.0f}% of them lie on the "
                         "reconstructed surface (an open, one-sided scan of a thin or flat object?)")
