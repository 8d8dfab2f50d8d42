"""Dense oriented points: ``voro3d.reconstruct`` against Open3D's screened Poisson at depths 9 and 10.

For each dev mesh, ``--points`` area-uniform samples with their true (face) normals
(:func:`voro3d.sampling.sample_surface`, seeded) are written once; every method then runs in a
process of its own on the same file, so that its peak memory is its own: the highest of the
child's ``VmHWM`` (reset at its start: Linux carries the parent's peak across exec) and the
resident memory of the child and all its descendants (a tiled fit's pool workers, Ray's
processes), summed every 0.5 s (:func:`run_child`):

* ``voro3d``: ``voro3d.reconstruct(cloud)`` with ``grid="auto"``, as a user with a dense oriented scan calls it;
* ``poisson<d>`` (``--methods``; default 9 and 10): ``TriangleMesh.create_from_point_cloud_poisson(cloud, depth=d)``.

Each output is scored against the mesh (:func:`voro3d.evaluate`: CD x1e5, F1, NC) in the parent.
Methods of one mesh run in turn (``--repeats`` times, seconds the median), so they share the
machine's load; the load average is recorded before each. Where Poisson ran at the depth of
voro3d's own target (read from its ``target`` phase line), the table ends with voro3d's time over
Poisson's. Writes ``benchmarks/results/<name>.md`` and ``.json`` (``--name``, default ``large``).

``--scaling 100000 300000 ...``: instead, ``voro3d`` alone on one mesh at each point count, its
seconds and peak memory against the count as a table and a log-log plot
(``benchmarks/results/large_scaling.md``, ``.json``, ``.png``).

    python benchmarks/bench_large.py [--meshes organic_bunny.off ...] [--points 1000000] [--eval-seeds 5]
    python benchmarks/bench_large.py --points 100000 --methods voro3d poisson8 poisson9 --repeats 3 --name large_100k
    python benchmarks/bench_large.py --scaling 100000 300000 1000000 3000000 [--meshes organic_bunny.off]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"
MESHES = ("organic_bunny.off", "organic_armadillo.obj", "cad_fandisk.obj", "abc_00000005.stl")

CHILD = r"""
import json, sys, time
# The peak resident memory starts as the parent's (Linux keeps it across exec): reset it (Linux >= 4.0).
with open("/proc/self/clear_refs", "w") as handle:
    handle.write("5")
import numpy as np, open3d as o3d
method, cloud_path, out_path = sys.argv[1:4]
data = np.load(cloud_path)
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(data[:, :3]))
cloud.normals = o3d.utility.Vector3dVector(data[:, 3:])
start = time.perf_counter()
if method == "voro3d":
    import voro3d
    mesh = voro3d.reconstruct(cloud, progress=True)  # its phase lines name the target's depth
else:
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=int(method[len("poisson"):]))
seconds = time.perf_counter() - start
o3d.io.write_triangle_mesh(out_path, mesh)
peak_kb = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
print(json.dumps(dict(seconds=seconds, peak_gb=peak_kb / 2**20, faces=len(mesh.triangles))))
"""


def run_child(arguments: list, interval: float = 0.5) -> tuple[dict, str, float]:
    """Run ``python -c`` with ``arguments`` (the code first) and return its last stdout line (JSON),
    its stderr, and the highest resident memory of it and all its descendants, in GB, summed every
    ``interval`` seconds."""
    import psutil

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    child = subprocess.Popen([sys.executable, "-c", *arguments], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env=env)
    watched, peak = psutil.Process(child.pid), 0
    while child.poll() is None:
        total = 0
        for member in [watched, *watched.children(recursive=True)]:
            try:
                total += member.memory_info().rss
            except psutil.Error:  # ended meanwhile
                pass
        peak = max(peak, total)
        time.sleep(interval)
    stdout, stderr = child.communicate()
    if child.returncode:
        raise RuntimeError(f"{arguments[1:]} failed:\n{stderr[-3000:]}")
    return json.loads(stdout.strip().splitlines()[-1]), stderr, peak / 1024**3


def _run(method: str, cloud: Path, out: Path) -> dict:
    load = os.getloadavg()[0]
    result, stderr, tree_gb = run_child([CHILD, method, str(cloud), str(out)])
    depth = re.search(r"target +poisson depth (\d+)", stderr)
    return dict(result, peak_gb=max(result["peak_gb"], tree_gb), load_before=load,
                **({"target_depth": int(depth.group(1))} if depth else {}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=list(MESHES))
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--methods", nargs="+", default=["voro3d", "poisson9", "poisson10"])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--repeats", type=int, default=1, help="runs of each method; seconds are their median")
    parser.add_argument("--name", default="large", help="file stem of the table and JSON")
    parser.add_argument("--scaling", type=int, nargs="+", help="point counts: voro3d alone on the first mesh")
    parser.add_argument("--eval-seeds", type=int, default=1,
                        help="evaluation seeds each mesh is scored with, CD, F1 and NC their means: one seed's CD "
                             "moves by up to 0.005 from seed to seed at 10^6 points, as much as the methods differ")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    if args.scaling:
        _scaling(args)
        return
    import voro3d
    from voro3d.io import load_mesh

    rows = []
    with tempfile.TemporaryDirectory(prefix="voro3d-large-") as scratch:
        for name in args.meshes:
            source = load_mesh(DEV / name)
            points, normals = voro3d.sample_surface(source, args.points, seed=0)
            cloud = Path(scratch) / "cloud.npy"
            np.save(cloud, np.hstack([points, normals]))
            # Repeats run the methods in turn, so that each one meets the machine's changing load alike;
            # the first run's mesh is scored (the mesh does not change between runs).
            for repeat in range(args.repeats):
                for method in args.methods:
                    out = Path(scratch) / f"{method}.ply"
                    row = dict(mesh=name, points=args.points, method=method, repeat=repeat, **_run(method, cloud, out))
                    if repeat == 0:
                        mesh = load_mesh(out, weld=False)
                        scores = [voro3d.evaluate(mesh, source, seed=seed) for seed in range(args.eval_seeds)]
                        row.update({key: float(np.mean([score[metric] for score in scores])) for key, metric in
                                    (("cd", "chamfer_x1e5"), ("f1", "f1"), ("nc", "nc"))},
                                   cd_seeds=[score["chamfer_x1e5"] for score in scores])
                    rows.append(row)
                    print(row, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.name}.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), cpus=os.cpu_count(),
                                                         rows=rows), indent=1))
    lines = [f"# {args.points:,} oriented points: voro3d against Poisson ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs)",
             "", f"{args.points:,} area-uniform samples of each dev mesh with their true normals; each method in a "
             "process of its own on the same points (peak = the highest of its resident maximum and its process tree's "
             f"resident sum), methods of one mesh in turn, {args.repeats} run(s) each (seconds: the median; "
             "peak: the highest); CD x1e5, F1 at 0.003 and NC against the mesh (`voro3d.evaluate`"
             f"{f', the means over evaluation seeds 0-{args.eval_seeds - 1}; CD range: their lowest and highest' if args.eval_seeds > 1 else ''}). "
             f"`python benchmarks/bench_large.py --points {args.points} --methods {' '.join(args.methods)} "
             f"--repeats {args.repeats} --name {args.name}{f' --eval-seeds {args.eval_seeds}' if args.eval_seeds > 1 else ''}`.", "",
             "| mesh | method | seconds (runs) | peak GB | faces | CD | CD range | F1 | NC | load before |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    summary = _medians(rows)
    for r in summary:
        runs = ", ".join(f"{s:.1f}" for s in r["runs"])
        spread = r.get("cd_seeds", [r["cd"]])
        lines.append(f"| {r['mesh']} | {r['method']} | {r['seconds']:.1f} ({runs}) | {r['peak_gb']:.2f} | {r['faces']:,} | "
                     f"{r['cd']:.4f} | {min(spread):.4f}-{max(spread):.4f} | {r['f1']:.4f} | {r['nc']:.4f} | {r['load_before']:.1f} |")
    ratios = _depth_ratios(summary)
    if ratios:
        lines += ["", "voro3d's seconds over Poisson's at the octree depth of voro3d's own target (its `target` "
                  "phase line): " + ", ".join(f"{mesh} {ratio:.2f}x (depth {depth})" for mesh, depth, ratio, _, _ in ratios)
                  + f"; summed {sum(r[3] for r in ratios) / sum(r[4] for r in ratios):.2f}x."]
    (args.out / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _medians(rows: list) -> list:
    """One row per mesh and method: the first run's row with the median seconds over its runs,
    the highest peak and the list of runs."""
    out = []
    for row in rows:
        if row["repeat"] == 0:
            runs = [r for r in rows if r["mesh"] == row["mesh"] and r["method"] == row["method"]]
            out.append(dict(row, seconds=float(np.median([r["seconds"] for r in runs])),
                            peak_gb=max(r["peak_gb"] for r in runs), runs=[r["seconds"] for r in runs]))
    return out


def _depth_ratios(summary: list) -> list:
    """``(mesh, depth, ratio, voro3d seconds, Poisson seconds)`` for each mesh whose Poisson run
    at voro3d's target depth was measured."""
    seconds = {(r["mesh"], r["method"]): r["seconds"] for r in summary}
    out = []
    for r in summary:
        poisson = seconds.get((r["mesh"], f"poisson{r.get('target_depth')}"))
        if r["method"] == "voro3d" and poisson:
            out.append((r["mesh"], r["target_depth"], r["seconds"] / poisson, r["seconds"], poisson))
    return out


def _scaling(args) -> None:
    """``voro3d`` alone on the first mesh at each of ``args.scaling`` points: table, JSON and plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import voro3d
    from voro3d.io import load_mesh

    name = args.meshes[0]
    source = load_mesh(DEV / name)
    rows = []
    with tempfile.TemporaryDirectory(prefix="voro3d-large-") as scratch:
        for count in args.scaling:
            points, normals = voro3d.sample_surface(source, count, seed=0)
            cloud = Path(scratch) / "cloud.npy"
            np.save(cloud, np.hstack([points, normals]))
            del points, normals
            out = Path(scratch) / "voro3d.ply"
            row = dict(mesh=name, points=count, method="voro3d", **_run("voro3d", cloud, out))
            scores = voro3d.evaluate(load_mesh(out, weld=False), source)
            row.update(cd=scores["chamfer_x1e5"], f1=scores["f1"], nc=scores["nc"])
            rows.append(row)
            print(row, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "large_scaling.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"),
                                                                 cpus=os.cpu_count(), rows=rows), indent=1))
    counts = np.array([r["points"] for r in rows], float)
    slope = {key: float(np.polyfit(np.log(counts), np.log([r[key] for r in rows]), 1)[0]) for key in ("seconds", "peak_gb")}
    lines = [f"# voro3d's time and memory against the point count ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs)",
             "", f"`reconstruct` (grid auto, true normals) on area-uniform samples of {name}, each count in a process of "
             "its own (peak = the highest of its resident maximum and its process tree's resident sum, pool workers "
             "included; above 2M points the cloud is reconstructed from a 1M subset, its fit in tiles). Log-log slopes over the counts: seconds "
             f"{slope['seconds']:.2f}, peak memory {slope['peak_gb']:.2f} (1 = linear). "
             "`python benchmarks/bench_large.py --scaling ...`.", "",
             "| points | seconds | peak GB | faces | CD | NC | load before |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['points']:,} | {r['seconds']:.1f} | {r['peak_gb']:.2f} | {r['faces']:,} | {r['cd']:.3f} | "
                     f"{r['nc']:.4f} | {r['load_before']:.1f} |")
    (args.out / "large_scaling.md").write_text("\n".join(lines) + "\n")
    figure, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, key, label in ((axes[0], "seconds", "seconds"), (axes[1], "peak_gb", "peak resident memory (GB)")):
        ax.loglog(counts, [r[key] for r in rows], "o-")
        ax.set_xlabel("points")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    figure.suptitle(f"voro3d.reconstruct on {name}, 2-core machine")
    figure.tight_layout()
    figure.savefig(args.out / "large_scaling.png", dpi=100)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
