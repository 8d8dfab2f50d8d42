"""Time of ``check_watertight`` on VoroMeshes of about 10^5 triangles, and of its parts.

Meshes: the learned VoroMesh (shipped ONNX model) of the bundled ``bracket`` and ``knot`` at a grid
chosen for about 100k triangles, and the VoroMesh of random generators labelled by a ball and a
slab (sheets that touch at duplicated vertices). Each timing is the best of ``--repeats`` runs in
this process. Parts: the whole check, the check without the self-intersection test, and
``self_intersections`` alone. Writes ``benchmarks/results/watertight.{md,json}``; ``--label``
names the column (e.g. the commit).

    python benchmarks/bench_watertight.py [--repeats 2] [--label after]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _meshes() -> dict:
    from voro3d.voromesh import VoroMesh
    from voro3d.infer import predict_from_mesh
    from voro3d.shapes import example_mesh

    meshes = {"bracket learned 78^3": predict_from_mesh(example_mesh("bracket"), 78).to_open3d(),
              "knot learned 88^3": predict_from_mesh(example_mesh("knot"), 88).to_open3d()}
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (200_000, 3))
    inside = (np.linalg.norm(points, axis=1) < 0.8) & (np.abs(points[:, 2]) < 0.5)
    meshes["random ball and slab"] = VoroMesh(points, inside).to_open3d()
    return meshes


def _best(function, repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--label", default=None, help="name of this run (default: the git commit)")
    args = parser.parse_args()

    from voro3d.io import mesh_arrays
    from voro3d.watertight import check_watertight, self_intersections

    label = args.label or subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                         text=True).stdout.strip()
    load_before = os.getloadavg()
    rows = []
    for name, mesh in _meshes().items():
        vertices, triangles = mesh_arrays(mesh)
        whole, report = _best(lambda: check_watertight(mesh), args.repeats)
        topology, _ = _best(lambda: check_watertight(mesh, self_intersection=False), args.repeats)
        pairs, _ = _best(lambda: self_intersections(vertices, triangles), args.repeats)
        rows.append({"mesh": name, "triangles": int(triangles.shape[0]), "check_watertight_s": whole,
                     "without_self_intersection_s": topology, "self_intersections_s": pairs,
                     "self_intersecting_pairs": report.self_intersecting_pairs, "touching_pairs": report.touching_pairs,
                     "watertight": report.watertight})
        print(f"{name}: {triangles.shape[0]} triangles, check_watertight {whole:.2f} s "
              f"(self_intersections {pairs:.2f} s), crossing {report.self_intersecting_pairs}, "
              f"touching {report.touching_pairs}", flush=True)
    result = {"label": label, "machine": f"{platform.machine()}, {os.cpu_count()} cores",
              "load_average": {"before": load_before, "after": os.getloadavg()}, "repeats": args.repeats, "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "watertight.json"
    runs = json.loads(path.read_text())["runs"] if path.is_file() else []
    runs = [run for run in runs if run["label"] != label] + [result]
    path.write_text(json.dumps({"runs": runs}, indent=1) + "\n")
    (RESULTS / "watertight.md").write_text(_markdown(runs))


def _markdown(runs: list) -> str:
    lines = ["# check_watertight on ~10^5-triangle VoroMeshes", "",
             "Best of the repeats, seconds; `benchmarks/bench_watertight.py`. Load averages are 1-minute, "
             "before/after (timings are noisy when other work runs).", ""]
    for run in runs:
        lines += [f"## {run['label']}", "",
                  f"{run['machine']}; best of {run['repeats']}; load average {run['load_average']['before'][0]:.2f} "
                  f"before, {run['load_average']['after'][0]:.2f} after.", "",
                  "| mesh | triangles | check_watertight | without self-intersection | self_intersections | crossing | touching |",
                  "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['mesh']} | {r['triangles']} | {r['check_watertight_s']:.2f} | {r['without_self_intersection_s']:.2f} | "
                  f"{r['self_intersections_s']:.2f} | {r['self_intersecting_pairs']} | {r['touching_pairs']} |"
                  for r in run["rows"]]
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
