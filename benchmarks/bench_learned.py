"""Learned VoroMesh (the shipped ONNX model) against Marching Cubes from the same SDF grid.

For every dev mesh (never trained on) whose inside is defined, in its fit frame, at 32^3 and
64^3: the SDF grid (:func:`voro3d.queries.sdf_grid`, cached in ``benchmarks/cache/``), then

* learned VoroMesh with fallbacks (the default), timed as network (SDF checks, node selection,
  onnxruntime, fallbacks) and extraction (``VoroMesh.to_open3d``);
* learned VoroMesh without fallbacks (the network alone decides every cell);
* Marching Cubes (scikit-image) of the same grid;

each scored by :func:`voro3d.metrics.evaluate` (CD x1e5, F1, NC in the ground truth's NDC
frame, 100k points) and :func:`voro3d.watertight.check_watertight`. The VoroMeshes are cleaned
(``to_open3d()``'s default, as ``voro3d predict`` writes them). Writes
``benchmarks/results/learned.{md,json}`` (``--out``: another path stem, e.g. for a candidate model).

    python benchmarks/bench_learned.py [--grids 32 64] [--threads N] [--limit N] [--model M.onnx] [--out STEM]
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
CACHE = ROOT / "benchmarks" / "cache" / "learned"
RESULTS = ROOT / "benchmarks" / "results"
GROUPS = ("thingi32", "abc", "cad", "organic")


def _sdf(path: Path, grid: int):
    """Fit-frame mesh and cached SDF grid of one dev mesh (None when its inside is undefined)."""
    from voro3d.frames import fit_frame
    from voro3d.io import load_mesh, mesh_arrays
    from voro3d.queries import sdf_grid

    vertices, triangles = mesh_arrays(load_mesh(path))
    vertices = fit_frame((vertices, triangles)).apply(vertices)
    cached = CACHE / f"{path.stem}_{grid}.npy"
    if cached.is_file():
        return (vertices, triangles), np.load(cached)
    try:
        sdf = sdf_grid((vertices, triangles), grid)
    except ValueError:  # open mesh: no inside, no SDF sign
        return (vertices, triangles), None
    CACHE.mkdir(parents=True, exist_ok=True)
    np.save(cached, sdf)
    return (vertices, triangles), sdf


def _score(mesh, gt) -> dict:
    from voro3d.metrics import evaluate
    from voro3d.watertight import check_watertight

    metrics = evaluate(mesh, gt, n_samples=100_000, seed=0)
    report = check_watertight(mesh)
    return {"chamfer_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"], "nc": metrics["nc"],
            "watertight": bool(report.watertight), "n_triangles": metrics["n_triangles"]}


def run_case(predictor, path: Path, grid: int) -> dict | None:
    from voro3d.baselines import marching_cubes

    gt, sdf = _sdf(path, grid)
    if sdf is None:
        return None
    predictor.predict(sdf)  # warm the session for this input size
    started = time.perf_counter()
    voro = predictor.predict(sdf)
    network = time.perf_counter() - started
    mesh = voro.to_open3d()
    extraction = time.perf_counter() - started - network
    learned = _score(mesh, gt)
    learned.update(network_s=network, extraction_s=extraction, total_s=network + extraction,
                   n_generators=int(voro.generators.shape[0]))
    plain = _score(predictor.predict(sdf, fallback=False).to_open3d(), gt)
    started = time.perf_counter()
    mc = marching_cubes(sdf)
    mc_seconds = time.perf_counter() - started
    mc = _score(mc, gt)
    mc["total_s"] = mc_seconds
    return {"mesh": path.name, "grid": grid, "learned": learned, "learned_no_fallback": plain, "mc": mc}


def _summary(rows: list[dict]) -> dict:
    def mean(method, key):
        return float(np.mean([r[method][key] for r in rows]))

    out = {"n_shapes": len(rows)}
    for method in ("learned", "learned_no_fallback", "mc"):
        out[method] = {key: mean(method, key) for key in ("chamfer_x1e5", "f1", "nc")}
        out[method]["watertight_percent"] = 100.0 * mean(method, "watertight")
    out["learned"]["median_chamfer_x1e5"] = float(np.median([r["learned"]["chamfer_x1e5"] for r in rows]))
    out["mc"]["median_chamfer_x1e5"] = float(np.median([r["mc"]["chamfer_x1e5"] for r in rows]))
    out["learned_beats_mc"] = int(sum(r["learned"]["chamfer_x1e5"] <= r["mc"]["chamfer_x1e5"] for r in rows))
    for key in ("network_s", "extraction_s", "total_s"):
        values = [r["learned"][key] for r in rows]
        out[f"mean_{key}"] = float(np.mean(values))
        out[f"max_{key}"] = float(np.max(values))
    out["mean_generators"] = float(np.mean([r["learned"]["n_generators"] for r in rows]))
    return out


def _markdown(result: dict) -> str:
    lines = ["# Learned VoroMesh vs Marching Cubes (dev meshes, never trained on)", "",
             f"Model `{result['model']}`; onnxruntime threads: {result['threads']}; {result['machine']}; "
             f"1-minute load average {result['load_average']['before'][0]:.2f} before, "
             f"{result['load_average']['after'][0]:.2f} after (timings are noisy when other work runs).",
             "CD x1e5 / F1 / NC in the ground truth's NDC frame (100k points each way). "
             "`learned` uses the SDF fallbacks (default), `no fallback` the network alone.",
             f"Skipped (open meshes, no SDF sign): {', '.join(result['skipped']) or 'none'}.", ""]
    for grid, summary in result["summary"].items():
        lines += [f"## {grid}^3 ({summary['n_shapes']} shapes)", "",
                  "| method | CD x1e5 (mean) | CD x1e5 (median) | F1 | NC | watertight % |", "|---|---|---|---|---|---|"]
        for method, label in (("learned", "learned VoroMesh"), ("learned_no_fallback", "learned, no fallback"),
                              ("mc", "Marching Cubes")):
            s = summary[method]
            median = f"{s['median_chamfer_x1e5']:.2f}" if "median_chamfer_x1e5" in s else "-"
            lines.append(f"| {label} | {s['chamfer_x1e5']:.2f} | {median} | {s['f1']:.3f} | {s['nc']:.3f} | "
                         f"{s['watertight_percent']:.0f} |")
        lines += ["", f"Learned CD <= MC CD on {summary['learned_beats_mc']} of {summary['n_shapes']} shapes. "
                  f"Time per shape (mean / max): network {summary['mean_network_s']:.3f} / "
                  f"{summary['max_network_s']:.3f} s, extraction {summary['mean_extraction_s']:.3f} / "
                  f"{summary['max_extraction_s']:.3f} s, total {summary['mean_total_s']:.3f} / "
                  f"{summary['max_total_s']:.3f} s; {summary['mean_generators']:.0f} generators on average.", ""]
        groups = result["groups"][grid]
        lines += ["| group | n | learned CD | MC CD | learned F1 | MC F1 | learned NC | MC NC |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, g in groups.items():
            lines.append(f"| {name} | {g['n_shapes']} | {g['learned']['chamfer_x1e5']:.2f} | "
                         f"{g['mc']['chamfer_x1e5']:.2f} | {g['learned']['f1']:.3f} | {g['mc']['f1']:.3f} | "
                         f"{g['learned']['nc']:.3f} | {g['mc']['nc']:.3f} |")
        lines += ["", "| mesh | learned CD | MC CD | learned F1 | MC F1 | network s | extraction s |",
                  "|---|---|---|---|---|---|---|"]
        for row in result["rows"]:
            if row["grid"] == int(grid):
                a, b = row["learned"], row["mc"]
                lines.append(f"| {row['mesh']} | {a['chamfer_x1e5']:.2f} | {b['chamfer_x1e5']:.2f} | {a['f1']:.3f} | "
                             f"{b['f1']:.3f} | {a['network_s']:.3f} | {a['extraction_s']:.3f} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: all cores)")
    parser.add_argument("--limit", type=int, default=None, help="only the first N dev meshes")
    parser.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    parser.add_argument("--out", type=Path, default=RESULTS / "learned",
                        help="path stem of the .md and .json results (default: benchmarks/results/learned)")
    args = parser.parse_args()

    from voro3d.infer import DEFAULT_MODEL, Predictor
    from voro3d.learn import machine_description

    if not DEV.is_dir():
        raise SystemExit(f"dev meshes not found at {DEV}")
    predictor = Predictor(args.model, threads=args.threads)
    paths = sorted(p for p in DEV.iterdir() if p.suffix.lower() in (".obj", ".off", ".stl", ".ply"))[: args.limit]
    rows, skipped = [], set()
    load_before = os.getloadavg()
    for grid in args.grids:
        for path in paths:
            row = run_case(predictor, path, grid)
            if row is None:
                skipped.add(path.name)
                continue
            rows.append(row)
            print(f"{grid} {path.name}: learned {row['learned']['chamfer_x1e5']:.2f} mc {row['mc']['chamfer_x1e5']:.2f} "
                  f"net {row['learned']['network_s']:.3f}s extract {row['learned']['extraction_s']:.3f}s", flush=True)
    result = {"model": args.model or str(DEFAULT_MODEL.relative_to(ROOT)),
              "threads": args.threads or "default (all cores)", "machine": machine_description(),
              "load_average": {"before": load_before, "after": os.getloadavg()},
              "skipped": sorted(skipped), "rows": rows, "summary": {}, "groups": {}}
    for grid in args.grids:
        grid_rows = [r for r in rows if r["grid"] == grid]
        result["summary"][str(grid)] = _summary(grid_rows)
        result["groups"][str(grid)] = {group: _summary(members) for group in GROUPS
                                       if (members := [r for r in grid_rows if r["mesh"].startswith(group)])}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    args.out.with_suffix(".md").write_text(_markdown(result))
    print(_markdown(result))


if __name__ == "__main__":
    main()
