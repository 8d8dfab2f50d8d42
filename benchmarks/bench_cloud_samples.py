"""How many VoroLoss samples a cloud's fit needs: samples per grid face against quality and time.

A mesh fit takes ``150 grid^2`` samples (the official code's). A cloud's mesh is fitted to its
smooth target afterwards (``snapping.snap_to_surface``), so its fit may need fewer (``tuning.py``'s
``CLOUD_SAMPLES_PER_FACE``). Each dev mesh is sampled into clouds without normals under some of
``bench_pointcloud``'s conditions and reconstructed at ``--grid`` with that number set to each of
``--per-face`` in turn (the same cloud, one process, back to back). CD x1e5, NC, F1 against the
mesh, the fit's seconds and the whole call's. Writes ``benchmarks/results/cloud_samples.{md,json}``.

    python benchmarks/bench_cloud_samples.py [--per-face 150 75 40] [--shapes ...] [--conditions ...]
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import dev_parser, dev_shapes

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"
SHAPES = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "abc_00000005.stl", "organic_cow.obj",
          "thingi32_252119.obj")
CONDITIONS = ("clean 20k", "noise 0.5%", "clean 100k", "range scan 3 views")


def run_cloud(name: str, condition: str, grid: int, per_face: list) -> list:
    import voro3d.pointcloud.resolution as resolution
    from bench_pointcloud import make_cloud
    from voro3d.io import load_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, reconstruct_points

    source = load_mesh(DEV / name)
    points = make_cloud(source, condition)
    saved, rows = resolution.CLOUD_SAMPLES_PER_FACE, []
    for count in per_face:
        resolution.CLOUD_SAMPLES_PER_FACE = count
        try:
            start = time.perf_counter()
            shape, target, info = reconstruct_points(points, grid=grid)
            mesh = cloud_mesh(shape, target)
            seconds = time.perf_counter() - start
        finally:
            resolution.CLOUD_SAMPLES_PER_FACE = saved
        scores = evaluate(mesh, source)
        rows.append(dict(shape=name, condition=condition, per_face=count, cd=scores["chamfer_x1e5"], nc=scores["nc"],
                         f1=scores["f1"], fit=info.seconds["samples"] + info.seconds["fit"], seconds=seconds,
                         faces=len(mesh.triangles), target=info.target))
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _table(rows: list, grid: int) -> str:
    per_face = list(dict.fromkeys(r["per_face"] for r in rows))
    lines = [f"# Samples per grid face of a cloud's fit ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs)", "",
             f"{len({r['shape'] for r in rows})} dev meshes, clouds without normals, grid {grid}, the counts back to "
             "back on each cloud (`python benchmarks/bench_cloud_samples.py`). Means per condition; ratios against "
             f"{per_face[0]} per face, per cloud, then averaged.", "",
             "| condition | per face | CD x1e5 | CD ratio (worst) | NC | F1 | fit + samples s | call s |",
             "|---|---|---|---|---|---|---|---|"]
    for condition in dict.fromkeys(r["condition"] for r in rows):
        base = {r["shape"]: r for r in rows if r["condition"] == condition and r["per_face"] == per_face[0]}
        for count in per_face:
            chosen = [r for r in rows if r["condition"] == condition and r["per_face"] == count]
            ratio = [r["cd"] / base[r["shape"]]["cd"] for r in chosen]
            mean = {key: float(np.mean([r[key] for r in chosen])) for key in ("cd", "nc", "f1", "fit", "seconds")}
            lines.append(f"| {condition} | {count} | {mean['cd']:.3f} | {np.mean(ratio):.3f} ({max(ratio):.3f}) | "
                         f"{mean['nc']:.4f} | {mean['f1']:.4f} | {mean['fit']:.1f} | {mean['seconds']:.1f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = dev_parser(__doc__, SHAPES, OUT)
    parser.add_argument("--per-face", nargs="+", type=int, default=[150, 75, 40])
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS))
    parser.add_argument("--grid", type=int, default=64)
    args = parser.parse_args()
    shapes = dev_shapes(args.shapes, DEV)
    sys.path.insert(0, str(ROOT))
    rows = [row for name in shapes for condition in args.conditions
            for row in run_cloud(name, condition, args.grid, args.per_face)]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cloud_samples.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), grid=args.grid,
                                                                 cpus=os.cpu_count(), rows=rows), indent=1))
    (args.out / "cloud_samples.md").write_text(_table(rows, args.grid))
    print(_table(rows, args.grid))


if __name__ == "__main__":
    main()
