"""The whole fit against another checkout of voro3d (today's code), interleaved in one run.

Each (mesh, grid) is fitted by ``--candidate`` (default: this tree) and by ``--baseline``, each a
folder holding a ``voro3d`` package with its extensions built (e.g. ``git archive <commit> | tar
-x -C /tmp/base`` plus the ``.so`` files), one fresh process each, alternating, so that both see the same load. Recorded per fit: wall and
CPU seconds of ``fit`` in-process, peak RSS, kNN searches, final loss, CD / F1 / NC (paper
conventions) and watertightness of the extracted mesh, and the load average before it. Writes
``<out>/fit_speed.{md,json}``.

    python benchmarks/bench_fit_speed.py --baseline /tmp/base [--candidate /tmp/new] [--meshes organic_bunny.off ...]
        [--grids 32 64] [--repeats 1] [--out benchmarks/results]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"

_ONE_FIT = """
import json, resource, sys, time
import voro3d
from voro3d.fitting import fit
from voro3d.io import load_mesh
from voro3d.metrics import evaluate
from voro3d.watertight import check_watertight

mesh = load_mesh(sys.argv[1])
wall, cpu = time.perf_counter(), time.process_time()
shape, info = fit(mesh, int(sys.argv[2]))
wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
surface = shape.to_open3d()
metrics = evaluate(surface, mesh)
print(json.dumps({"package": voro3d.__file__, "fit_s": wall, "fit_cpu_s": cpu, "peak_rss_mib": peak,
                  "searches": info.candidate_searches, "final_loss": info.final_loss,
                  "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"], "nc": metrics["nc"],
                  "watertight": check_watertight(surface, self_intersection=False).watertight}))
"""


def one_fit(package_root: Path, mesh: Path, grid: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(package_root))
    # Run outside the repository so that the current directory does not shadow PYTHONPATH.
    result = subprocess.run([sys.executable, "-c", _ONE_FIT, str(mesh), str(grid)], capture_output=True, text=True,
                            env=env, cwd="/", check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def markdown(rows) -> str:
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for row in rows:
        lines.append("| " + " | ".join(f"{row[key]:.4g}" if isinstance(row[key], float) else str(row[key])
                                        for key in keys) + " |")
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="folder holding the baseline voro3d package")
    parser.add_argument("--candidate", type=Path, default=ROOT, help="folder holding the voro3d package to time")
    parser.add_argument("--meshes", nargs="+", default=["organic_bunny.off", "cad_fandisk.obj", "thingi32_44234.obj"])
    parser.add_argument("--grids", nargs="+", type=int, default=[32, 64])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()

    rows = []
    for grid in args.grids:
        for name in args.meshes:
            path = Path(name) if Path(name).is_file() else DEV / name
            for repeat in range(args.repeats):
                for version, root in (("baseline", args.baseline.resolve()), ("candidate", args.candidate.resolve())):
                    load = os.getloadavg()[0]
                    row = {"mesh": path.name, "grid": grid, "repeat": repeat, "version": version, "load_before": load}
                    row.update(one_fit(root, path, grid))
                    del row["package"]
                    rows.append(row)
                    print(row, flush=True)
    machine = {"platform": platform.platform(), "cpus": os.cpu_count(), "baseline": _shown(args.baseline),
               "candidate": _shown(args.candidate)}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fit_speed.json").write_text(json.dumps({"machine": machine, "rows": rows}, indent=1))
    text = ("# Whole fit: a candidate vs a baseline checkout, interleaved\n\n"
            f"Machine: {json.dumps(machine)}. Seconds are `fit` in-process (sampling to occupancy); "
            "`load_before` is the 1-minute load average before each fit.\n\n" + markdown(rows))
    (args.out / "fit_speed.md").write_text(text)
    print(text)


def _shown(path: Path) -> str:
    """A checkout as the results name it: relative to this repository (``.`` for itself), else by its folder name,
    never a path of the machine that ran it."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else f"checkout {path.name}"


if __name__ == "__main__":
    main()
