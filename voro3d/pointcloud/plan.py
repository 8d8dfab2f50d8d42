"""The plan of a cloud's reconstruction: which normals, smoothing, filter and target surface, and its cut.

:func:`~voro3d.pointcloud.reconstruct.reconstruct_points` analyses the cloud (outliers, spacing,
noise, the winding level of its oriented points), then settles each choice of a
:class:`CloudPlan` left ``"auto"`` by the rules below, then runs. ``PointCloudInfo.plan`` is the
plan as it ran, every field settled: passed back in, it gives the same mesh; any field can be set
by hand (``reconstruct(cloud, plan={"target": "imls"})``). The numbers the rules read are in
:mod:`~voro3d.pointcloud.tuning`, each with its measurement.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..geometry import grid_voxel
from .tuning import HEAVY_NOISE, SHEET_OFFSET, SHEET_POINTS_GATE, SHEET_SUPPORT, SHEET_WALLS, SHEET_WIN

__all__ = ["CloudPlan", "as_plan", "NORMALS", "SWITCHES", "TARGETS"]

NORMALS = ("auto", "check", "trust", "estimate")
SWITCHES = ("auto", "on", "off")
TARGETS = ("auto", "poisson", "imls", "sheet")


@dataclass(frozen=True)
class CloudPlan:
    """What :func:`~voro3d.pointcloud.reconstruct_points` does with a cloud; ``"auto"`` lets the analysis decide.

    Attributes
    ----------
    normals : {"auto", "check", "trust", "estimate"}
        ``"check"``: the given normals, re-oriented where their signs disagree between neighbours
        (``MAX_SIGN_DISAGREEMENT``) and flipped where they all point inward; ``"trust"``: the
        given normals as they are; ``"estimate"``: estimated and oriented by us, any given ones
        ignored. ``"auto"``: ``"check"`` when normals are given, else ``"estimate"``.
    denoise : {"auto", "on", "off"}
        The smoothing pass that moves the points onto their IMLS surface. ``"auto"``: on when the
        fine-scale noise is over ``NOISY`` spacings, and for one-sided scans that are not dense
        (sparse points whose normals need to agree across sharp edges).
    filter : {"auto", "on", "off"}
        The bilateral filter of a Poisson target (:mod:`~voro3d.pointcloud.denoise`). ``"auto"``:
        on for smoothed noisy points whose noise is over ``HEAVY_NOISE`` octree cells.
    target : {"auto", "poisson", "imls", "sheet"}
        The smooth surface the VoroMesh is fitted to and labelled by: screened Poisson, the IMLS
        field with the points' winding number behind it (a closed cloud's holes closed at
        ``HOLE_LEVEL``; an open cloud's held by the points' hull where ``hull`` cuts to it, else within
        its shell depth of the points where they do not enclose it), or a shell at a small offset
        around the points (walls thinner than the spacing). ``"auto"``: Poisson when the oriented points
        enclose a volume (winding level over ``CLOSED_LEVEL``) and it does not flap out past them
        (``MAX_POISSON_ESCAPE``), else IMLS; then the shell where it fits the points much better
        (``SHEET_*``).
    hull : {"auto", "on", "off"}
        Cut the target's solid back to the points' convex hull, a voxel out
        (:mod:`~voro3d.pointcloud.hull`; Poisson and IMLS targets): for range scans from a few
        viewpoints, whose closure otherwise swells past everything the points bound. ``"auto"``:
        on for a cloud that does not enclose a volume (its solid behind the seen side is a guess:
        a table seen from above comes back as thin as its seen edges, not a shell's depth), off for
        one that does: with a part cut away it would take the closure's continuation off with the
        swelling, and no measure of the cloud yet tells the two apart (beside ``HULL_MARGIN_NODES``).
        An open cloud whose rim is a crop, not a silhouette (a terrain, a flat map:
        :func:`~voro3d.pointcloud.hull.cropped_rim`), is held a thin shell deep behind its points as
        well, unless ``"on"``: its hull alone fills a valley up to its rim.
    thin : {"auto", "on", "off"}
        Thin the points along the lines they were sampled on, far apart for their spacing along
        them (a LiDAR's scan lines), whose nearest neighbours all lie on their own line
        (:func:`~voro3d.pointcloud.scanlines.thin_lines`). ``"auto"``: while they do
        (``LINE_RATIO``); ``"on"``: one round at least.
    """

    normals: str = "auto"
    denoise: str = "auto"
    filter: str = "auto"
    target: str = "auto"
    hull: str = "auto"
    thin: str = "auto"

    def __post_init__(self):
        for name, choices in (("normals", NORMALS), ("denoise", SWITCHES), ("filter", SWITCHES),
                              ("target", TARGETS), ("hull", SWITCHES), ("thin", SWITCHES)):
            if getattr(self, name) not in choices:
                raise ValueError(f"plan {name} must be one of {choices}, got {getattr(self, name)!r}")

    def __str__(self) -> str:
        return ", ".join(f"{item.name} {getattr(self, item.name)}" for item in fields(self))


def as_plan(plan) -> CloudPlan:
    """``plan`` as a :class:`CloudPlan`: None (all ``"auto"``), a plan, or a mapping of its fields."""
    if plan is None:
        return CloudPlan()
    if isinstance(plan, CloudPlan):
        return plan
    if isinstance(plan, dict):
        unknown = sorted(set(plan) - {item.name for item in fields(CloudPlan)})
        if unknown:
            raise ValueError(f"plan has no field {unknown[0]!r}; its fields are "
                             f"{tuple(item.name for item in fields(CloudPlan))}")
        return CloudPlan(**plan)
    raise TypeError(f"plan must be a CloudPlan, a dict of its fields or None, got {type(plan).__name__}")


def settle_normals(plan: CloudPlan, given: bool) -> str:
    """The normals choice for a cloud with (``given``) or without normals."""
    if plan.normals == "auto":
        return "check" if given else "estimate"
    if plan.normals in ("check", "trust") and not given:
        raise ValueError(f"plan normals {plan.normals!r} needs normals with the points; none were given")
    return plan.normals


def settle_denoise(plan: CloudPlan, *, noisy: bool, closed: bool, dense: bool) -> str:
    """Noisy points onto their smooth surface; sparse one-sided scans too (normals that agree across
    a sharp edge). Dense clean clouds keep their points exact (and thin walls their two sides), and
    Poisson follows clean sparse ones closer unsmoothed (bunny at 5k points: CD 1.13 against 1.77)."""
    if plan.denoise != "auto":
        return plan.denoise
    return "on" if noisy or not (closed or dense) else "off"


def settle_filter(plan: CloudPlan, *, smoothed: bool, noisy: bool, noise: float, depth: int) -> str:
    """The Poisson target's bilateral filter: for smoothed points whose noise the octree still resolves."""
    if plan.filter != "auto":
        return plan.filter
    return "on" if smoothed and noisy and noise > HEAVY_NOISE * 2.0 / 2**depth else "off"


def settle_hull(plan: CloudPlan, *, closed: bool, kind: str = "imls") -> str:
    """The cut to the hull of a Poisson or IMLS target (a shell hugs the points): where asked for and,
    ``"auto"``, for an open cloud (not ``closed``), whose solid behind the seen side is a guess."""
    wanted = plan.hull == "on" or (plan.hull == "auto" and not closed)
    return "on" if wanted and kind != "sheet" else "off"


def sheet_if_closer(target, points, spacing: float, resolution: int, *, distance=None, walls: float = 0.0):
    """The offset shell of the points when it fits them much better than ``target``, else None.

    Tried when the points lie off ``target`` (``SHEET_POINTS_GATE``: the noise of a wall's two
    sides read as one surface) or when a share ``walls`` of at least ``SHEET_WALLS`` of the points
    span both sides of a thin wall (passed for clouds that read closed, whose target can run
    through both sides and still fill what the walls enclose: a bowl comes back as a dome). Kept
    when the points hold it on both faces (its surface lies within ``SHEET_SUPPORT`` spacings of
    them on average: a wall sampled on both sides, not one side of a solid or an open sheet,
    whose shell has an empty face) and its misfit (mean distance points -> surface plus surface
    -> points) is under ``SHEET_WIN`` times the target's. The shell is read, and kept, as laid onto
    the points (:meth:`~voro3d.pointcloud.shell.SheetSurface.hugging`). ``distance``: the distance of
    every :func:`~voro3d.pointcloud.preprocess.check_stride`-th point to ``target``, when already measured.
    """
    from .preprocess import check_stride

    sample = points[::check_stride(len(points))]
    to_target = float(np.mean(target.distance(sample) if distance is None else distance))
    if to_target <= SHEET_POINTS_GATE * spacing and walls < SHEET_WALLS:
        return None
    sheet = sheet_target(points, spacing, resolution)
    held = _surface_to_points(sheet, points)
    if held > SHEET_SUPPORT * spacing:
        return None
    misfit = float(np.mean(sheet.distance(sample))) + held
    return sheet if misfit < SHEET_WIN * (to_target + _surface_to_points(target, points)) else None


def sheet_target(points, spacing: float, resolution: int):
    """The shell ``SHEET_OFFSET`` spacings (at least a field voxel) around the points, laid onto them
    (:meth:`~voro3d.pointcloud.shell.SheetSurface.hugging`)."""
    from .shell import sheet_surface

    sheet = sheet_surface(points, max(grid_voxel(resolution), SHEET_OFFSET * spacing), resolution)
    return sheet.hugging(points, spacing)


def _surface_to_points(target, points, n_samples: int = 20_000) -> float:
    """Mean distance from the target surface (area-uniform samples) to the nearest of ``points``."""
    from ..queries import nearest_distance
    from ..sampling import sample_surface

    samples, _ = sample_surface((target.vertices, target.triangles), n_samples, seed=0)
    return float(np.mean(nearest_distance(points, samples)))
