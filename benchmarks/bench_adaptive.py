"""Adaptive against uniform generators: what the octree band buys at a given cost or accuracy.

For each dev mesh, 10^6 area-uniform samples with their true normals (seeded) go through the
point-cloud path as ``reconstruct`` runs it for a clean oriented cloud from the target on: the
screened Poisson target at the depth ``reconstruct`` picks (``poisson_depth`` from the grid and the
point spacing: 9 for these clouds), the VoroLoss samples of
it, the fit (``CLOUD_STEPS`` steps), the cleaned mesh snapped to the target. The target is built
once per mesh; only the generators differ:

* ``uniform g``: the uniform band of a ``g^3`` grid (``150 g^2`` samples), g in ``--uniform``;
* ``adaptive t``: the band of :class:`voro3d.generators.AdaptiveBand` over ``--finest`` up to
  32^3 voxels, split at plane-fit residual ``t`` finest voxels, samples per leaf as its level's.

Scores against the mesh (:func:`voro3d.evaluate`: CD x1e5, F1, NC), generators, samples, faces
and fit seconds (one process, methods back to back on a quiet machine). The summary compares each
adaptive band with the uniform bands interpolated (log-linearly in generators) at the same number
of generators, and at the same CD. Writes ``benchmarks/results/adaptive.md``, ``.json``, ``.png``.

    python benchmarks/bench_adaptive.py [--meshes organic_bunny.off ...] [--points 1000000]
    python benchmarks/bench_adaptive.py --pictures   # adaptive_fandisk.png, adaptive_armadillo.png

``--pictures``: instead, ``voro3d.reconstruct`` of the same 10^6 oriented points at ``grid=64`` and
``grid="auto"`` (the adaptive band), side by side, for fandisk and the armadillo.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"
MESHES = ("organic_bunny.off", "organic_armadillo.obj", "cad_fandisk.obj", "abc_00000005.stl")


def run_mesh(name: str, n_points: int, uniform, finest: int, tolerances) -> list[dict]:
    import open3d as o3d

    import voro3d
    from voro3d.fitting import fit_samples
    from voro3d.frames import fit_frame
    from voro3d.generators import AdaptiveBand
    from voro3d.pointcloud.poisson import poisson_depth, poisson_surface
    from voro3d.pointcloud.preprocess import cloud_stats
    from voro3d.pointcloud.debris import drop_stray_cells
    from voro3d.pointcloud.reconstruct import SnapTarget, cloud_mesh
    from voro3d.pointcloud.resolution import band_levels, target_samples
    from voro3d.pointcloud.tuning import CLOUD_STEPS, MAX_TARGET_GRID
    from voro3d.sampling import sample_surface

    mesh = o3d.io.read_triangle_mesh(str(DEV / name))
    points, normals = sample_surface(mesh, n_points, seed=1)
    frame = fit_frame(points)
    framed = frame.apply(points)
    depth = poisson_depth(MAX_TARGET_GRID, cloud_stats(framed).median_spacing)
    target = poisson_surface(framed, normals, depth)
    vertices = target.project(target.vertices)
    snap = SnapTarget(frame.invert(vertices), target.triangles, snap=True, smoothing=0.0)
    variants = [("uniform", g, None) for g in uniform] + [("adaptive", finest, t) for t in tolerances]
    rows = []
    for kind, grid, tolerance in variants:
        start = time.perf_counter()
        band = AdaptiveBand(vertices, grid, levels=band_levels(grid), tolerance=tolerance) if tolerance else None
        samples = target_samples(target, vertices, framed, grid, band=band, seed=0)
        shape, info = fit_samples(samples, target.inside, grid, frame=frame, steps=CLOUD_STEPS,
                                  generators=None if band is None else band.generators())
        shape = drop_stray_cells(shape)
        seconds = time.perf_counter() - start
        out = cloud_mesh(shape, snap)
        score = voro3d.evaluate(out, mesh)
        rows.append(dict(mesh=name, kind=kind, grid=grid, tolerance=tolerance, depth=depth, generators=len(shape.generators),
                         samples=int(samples.shape[0]), searches=info.candidate_searches, fit_seconds=round(seconds, 2),
                         faces=len(out.triangles), cd=round(float(score["chamfer_x1e5"]), 4),
                         f1=round(float(score["f1"]), 4), nc=round(float(score["nc"]), 4),
                         leaves=None if band is None else [int(leaves.size) for leaves in band.leaves]))
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _interpolate(x, xs, ys):
    """ys at x, linear in log(xs) between the nearest uniform bands; None outside their range."""
    order = np.argsort(xs)
    xs, ys = np.log(np.asarray(xs, float)[order]), np.asarray(ys, float)[order]
    x = np.log(x)
    return float(np.interp(x, xs, ys)) if xs[0] <= x <= xs[-1] else None


def _generators_for_cd(cd, uniform_rows):
    """Generators a uniform band needs for ``cd`` (log-linear between bands; CD falling with generators)."""
    gens = np.log([row["generators"] for row in uniform_rows])
    cds = np.array([row["cd"] for row in uniform_rows])
    for i in range(len(cds) - 1):
        a, b = cds[i], cds[i + 1]
        if (a - cd) * (b - cd) <= 0 and a != b:
            return float(np.exp(gens[i] + (cd - a) / (b - a) * (gens[i + 1] - gens[i])))
    return None


def summary(rows) -> list[dict]:
    out = []
    for name in dict.fromkeys(row["mesh"] for row in rows):
        uniform = sorted((r for r in rows if r["mesh"] == name and r["kind"] == "uniform"), key=lambda r: r["generators"])
        gens = [r["generators"] for r in uniform]
        for row in (r for r in rows if r["mesh"] == name and r["kind"] == "adaptive"):
            same_gens = {key: _interpolate(row["generators"], gens, [r[key] for r in uniform])
                         for key in ("cd", "nc", "faces", "fit_seconds")}
            needed = _generators_for_cd(row["cd"], uniform)
            at_cd = None if needed is None else {key: _interpolate(needed, gens, [r[key] for r in uniform])
                                                 for key in ("faces", "fit_seconds")}
            out.append(dict(mesh=name, tolerance=row["tolerance"], generators=row["generators"], cd=row["cd"],
                            nc=row["nc"], faces=row["faces"], fit_seconds=row["fit_seconds"],
                            uniform_at_same_generators=same_gens, uniform_generators_for_same_cd=needed,
                            uniform_at_same_cd=at_cd))
    return out


def _fmt(value, digits=4):
    return "-" if value is None else f"{value:,.{digits}f}" if isinstance(value, float) and digits else f"{value:,.0f}"


def write(rows, compared, out: Path, args) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "adaptive.json").write_text(json.dumps(dict(points=args.points, rows=rows, summary=compared), indent=1))
    depths = ", ".join(map(str, sorted({r.get("depth", 8) for r in rows})))
    lines = ["# Adaptive against uniform generators", "",
             f"`python benchmarks/bench_adaptive.py` ({args.points:,} true-normal samples per mesh, the point-cloud "
             f"path from its Poisson target on, depth {depths}; one process, back to back, quiet machine). CD x1e5, "
             "NC and F1 against the mesh; fit seconds are band, samples, fit and labels.", "",
             "| mesh | band | grid | tolerance | generators | samples | searches | faces | fit s | CD | F1 | NC |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mesh']} | {r['kind']} | {r['grid']} | {r['tolerance'] or '-'} | {r['generators']:,} | "
                     f"{r['samples']:,} | {r['searches']} | {r['faces']:,} | {r['fit_seconds']:.1f} | {r['cd']:.4f} | "
                     f"{r['f1']:.3f} | {r['nc']:.4f} |")
    lines += ["", "## Adaptive against uniform at the same generators, and at the same CD", "",
              "Uniform figures interpolated between the uniform bands, log-linearly in generators ('-': outside "
              "their range).", "",
              "| mesh | tolerance | adaptive gens | adaptive CD | uniform CD, same gens | adaptive NC | uniform NC, "
              "same gens | adaptive faces | uniform faces, same gens | uniform gens, same CD | uniform faces, same CD "
              "| adaptive fit s | uniform fit s, same CD |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in compared:
        same, at_cd = c["uniform_at_same_generators"], c["uniform_at_same_cd"] or {}
        lines.append(f"| {c['mesh']} | {c['tolerance']} | {c['generators']:,} | {c['cd']:.4f} | {_fmt(same['cd'])} | "
                     f"{c['nc']:.4f} | {_fmt(same['nc'])} | {c['faces']:,} | {_fmt(same['faces'], 0)} | "
                     f"{_fmt(c['uniform_generators_for_same_cd'], 0)} | {_fmt(at_cd.get('faces'), 0)} | "
                     f"{c['fit_seconds']:.1f} | {_fmt(at_cd.get('fit_seconds'), 1)} |")
    lines += ["", "`adaptive_fandisk.png`, `adaptive_armadillo.png` (`--pictures`): `reconstruct` of the same 10^6 points at "
              "grid 64 and grid auto, side by side."]
    (out / "adaptive.md").write_text("\n".join(lines) + "\n")
    _plot(rows, out / "adaptive.png")


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(row["mesh"] for row in rows))
    figure, axes = plt.subplots(2, len(names), figsize=(4 * len(names), 6.5), squeeze=False)
    for column, name in enumerate(names):
        for kind, style in (("uniform", "o-"), ("adaptive", "s--")):
            mine = sorted((r for r in rows if r["mesh"] == name and r["kind"] == kind), key=lambda r: r["generators"])
            for row_axis, key in ((0, "cd"), (1, "nc")):
                axes[row_axis, column].plot([r["generators"] for r in mine], [r[key] for r in mine], style, label=kind)
        axes[0, column].set_title(name, fontsize=9)
        axes[1, column].set_xlabel("generators")
        for axis in axes[:, column]:
            axis.set_xscale("log")
    axes[0, 0].set_ylabel("CD x1e5")
    axes[1, 0].set_ylabel("NC")
    axes[0, 0].legend()
    figure.tight_layout()
    figure.savefig(path, dpi=90)


def pictures(n_points: int, out: Path) -> None:
    import voro3d
    from voro3d.render.pictures import render_meshes
    from voro3d.sampling import sample_surface

    for name, view, up in (("cad_fandisk.obj", None, "z"), ("organic_armadillo.obj", "front", "y")):
        mesh = voro3d.load_mesh(DEV / name)
        points, normals = sample_surface(mesh, n_points, seed=1)
        meshes, titles = [], []
        for grid, label in ((64, "uniform 64"), ("auto", "auto (adaptive 128-32)")):
            meshes.append(voro3d.reconstruct(np.hstack([points, normals]), grid=grid))
            titles.append(f"{Path(name).stem} {label}: {len(meshes[-1].triangles):,} faces")
        render_meshes(meshes, out / f"adaptive_{Path(name).stem.split('_')[-1]}.png", titles=titles, size=(560, 440),
                      view=view, up=up)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=list(MESHES))
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--uniform", type=int, nargs="+", default=[48, 64, 96, 128])
    parser.add_argument("--finest", type=int, default=128)
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.1, 0.05, 0.03])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--pictures", action="store_true", help="only the side-by-side pictures")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    if args.pictures:
        pictures(args.points, args.out)
        return
    rows = [row for name in args.meshes for row in run_mesh(name, args.points, args.uniform, args.finest, args.tolerances)]
    write(rows, summary(rows), args.out, args)


if __name__ == "__main__":
    main()
