"""Seconds and peak memory, stage by stage, of ``voro3d.reconstruct`` on a large oriented cloud.

A dev mesh is sampled area-uniformly into ``--points`` points with its true (face) normals
(:func:`voro3d.sampling.sample_surface`; ``--normals none``: without, ``--noise``: Gaussian
noise added), handed over as an Open3D ``PointCloud`` with normals,
and reconstructed with ``grid="auto"``, as a user with a dense scan would. A child process
samples this process's resident memory (``/proc/<pid>/statm``) every ``--interval`` seconds; each
stage's peak is the highest sample inside its time window, and the whole call's is also read
from ``getrusage`` (exact). Stages:

* ``read``: input checks, duplicate merge, normal repair (``reconstruction._read``);
* ``separate``: objects far apart (``separate_objects``);
* ``clean``, ``normals``, ``surface``, ``samples``, ``fit``: the windows that
  ``PointCloudInfo.seconds`` times inside ``reconstruct_points``;
* ``mesh``: extraction, cleaning and snapping (``cloud_mesh``); ``check``: ``_check_fit``.

The functions those stages call are wrapped too (where they exist), each with its calls,
seconds and peak: that is where a big intermediate shows. Memory is absolute (the cloud and
the imports are in it: ``baseline``, read just before the call). The machine may be shared:
timings then are contended, and the load average at start and end is recorded.

Each run is stored under its ``--label`` (``before``, ``after`` ...) in
``benchmarks/results/large_profile.json``, and ``large_profile.md`` is written from all runs.

    python benchmarks/profile_large.py [--mesh organic_bunny.off] [--points 1000000]
        [--normals true|none] [--noise 0.005] [--label after] [--evaluate] [--max-gb 18]
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results" / "large_profile"
PAGE = os.sysconf("SC_PAGE_SIZE")
GB = 1024**3
STAGES = ("read", "separate", "clean", "normals", "surface", "samples", "fit", "mesh", "check")
# Functions wrapped for the per-function table, by the module (or class) they are looked up in;
# names that a version lacks are skipped.
WRAPPED = {
    "voro3d.reconstruction": ["_read", "_check_fit"],
    "voro3d.pointcloud": ["separate_objects", "reconstruct_points", "cloud_mesh"],
    "voro3d.pointcloud.reconstruct": ["merge_duplicates", "outlier_mask", "cloud_stats", "local_dimension",
                                      "fill_ratio", "estimate_normals", "orient_normals", "sign_disagreement",
                                      "point_areas", "outward_normals", "imls", "poisson_surface", "target_surface",
                                      "sheet_if_closer", "sheet_target", "_check_coverage", "check_coverage", "target_samples",
                                      "fit_band", "drop_stray_cells"],
    "voro3d.pointcloud.targets": ["poisson_surface", "target_surface", "sheet_if_closer", "sheet_target"],
    "voro3d.pointcloud.normals": ["orient_normals", "_outside_votes"],
    "voro3d.pointcloud.surface": ["imls", "mesh_field"],
    "voro3d.pointcloud.surface.TargetSurface": ["inside", "project"],
    "voro3d.pointcloud.poisson": ["_supported_pieces"],
    "voro3d.pointcloud.poisson.PoissonSurface": ["escape", "distance"],
    "voro3d.queries": ["point_winding_number"],
    "voro3d.fitting": ["fit_samples"],
    "voro3d.cleaning": ["clean"],
    "voro3d.snapping": ["snap_to_surface"],
}


# The sampler runs in its own process: a thread would wait for the GIL, which Open3D's Poisson,
# libigl and some numpy calls hold through their largest allocations (a thread's samples at 100k
# points peaked at 0.4 GB where getrusage read 1.6 GB).
SAMPLER = """
import os, signal, sys, time
pid, interval, limit, page = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), os.sysconf("SC_PAGE_SIZE")
ticks = os.sysconf("SC_CLK_TCK")
while True:
    try:
        with open(f"/proc/{pid}/statm") as handle:
            value = int(handle.read().split()[1]) * page
        with open(f"/proc/{pid}/stat") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        break
    # utime + stime (fields 14 and 15 of /proc/pid/stat, after the name) in clock ticks.
    print(time.perf_counter(), value, (int(fields[11]) + int(fields[12])) / ticks, flush=True)
    if value > limit:
        print(f"resident memory {value / 2**30:.1f} GB over the limit: killing {pid}", file=sys.stderr, flush=True)
        os.kill(pid, signal.SIGKILL)
        break
    time.sleep(interval)
"""


class Memory:
    """Resident memory of this process, sampled by a child process; it kills this one past ``limit`` bytes."""

    def __init__(self, interval: float, limit: float):
        import subprocess
        import sys
        import tempfile

        self._log = tempfile.TemporaryFile("w+")
        self._process = subprocess.Popen([sys.executable, "-c", SAMPLER, str(os.getpid()), str(interval), str(limit)],
                                         stdout=self._log)
        self.times, self.values, self.cpu = np.zeros(0), np.zeros(0), np.zeros(0)

    @staticmethod
    def now() -> int:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * PAGE

    def stop(self):
        self._process.terminate()
        self._process.wait()
        self._log.seek(0)
        samples = np.loadtxt(self._log, ndmin=2)
        self.times, self.values, self.cpu = samples[:, 0], samples[:, 1], samples[:, 2]

    def cpu_seconds(self, start: float, end: float) -> float:
        """CPU seconds (all threads, user + system) spent between two times, to the sampling interval."""
        return float(np.interp(end, self.times, self.cpu) - np.interp(start, self.times, self.cpu))

    def peak(self, start: float, end: float) -> float:
        """Highest sample in [start, end] (the nearest samples around a window shorter than the interval)."""
        inside = (self.times >= start) & (self.times <= end)
        if not inside.any():
            inside = np.zeros(len(self.times), bool)
            inside[max(np.searchsorted(self.times, start) - 1, 0):np.searchsorted(self.times, end) + 1] = True
        return float(self.values[inside].max())


def wrap(spans: list):
    """Wrap the ``WRAPPED`` functions so that every call appends (name, start, end) to ``spans``."""
    for owner_name, names in WRAPPED.items():
        try:
            owner = importlib.import_module(owner_name)
        except ImportError:
            module, _, cls = owner_name.rpartition(".")
            try:
                owner = getattr(importlib.import_module(module), cls)
            except (ImportError, AttributeError):
                continue
        for name in names:
            _wrap_one(owner, name, spans)


def _wrap_one(owner, attribute: str, spans: list) -> None:
    """Replace ``owner.attribute`` by a wrapper that appends (name, start, end) to ``spans`` per call."""
    import functools

    function = getattr(owner, attribute, None)
    if function is None or getattr(function, "_profiled", False):
        return

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            spans.append((attribute, start, time.perf_counter()))

    wrapper._profiled = True
    setattr(owner, attribute, wrapper)


def make_cloud(mesh_path: Path, n: int, seed: int, *, normals: str = "true", noise: float = 0.0):
    """The mesh and an Open3D cloud of ``n`` samples of it: with their true normals or none, and
    Gaussian noise of ``noise`` bounding-box diagonals per coordinate."""
    import open3d as o3d

    import voro3d
    from voro3d.sampling import sample_surface

    mesh = voro3d.load_mesh(mesh_path)
    points, true_normals = sample_surface(mesh, n, seed=seed)
    if noise:
        diagonal = np.linalg.norm(points.max(axis=0) - points.min(axis=0))
        points = points + np.random.default_rng(seed + 1).normal(scale=noise * diagonal, size=points.shape)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals == "true":
        cloud.normals = o3d.utility.Vector3dVector(true_normals)
    return mesh, cloud


def profile(args) -> dict:
    import voro3d

    mesh, cloud = make_cloud(DEV / args.mesh, args.points, args.seed, normals=args.normals, noise=args.noise)
    spans: list = []
    infos: list = []
    wrap(spans)
    # reconstruct() imports reconstruct_points from voro3d.pointcloud at call time.
    import voro3d.pointcloud

    traced = voro3d.pointcloud.reconstruct_points

    def keep_info(*a, **k):
        result = traced(*a, **k)
        infos.append(result[-1])  # (shape, target, info); (shape, info) before e00553d
        return result

    voro3d.pointcloud.reconstruct_points = keep_info
    memory = Memory(args.interval, args.max_gb * GB)
    load = os.getloadavg()
    baseline = Memory.now()
    start = time.perf_counter()
    result = voro3d.reconstruct(cloud, grid="auto")
    end = time.perf_counter()
    memory.stop()
    total_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    # The reconstruct_points span (the wrapped inner function) holds its start.
    inner = [s for s in spans if s[0] == "reconstruct_points"]
    info = infos[-1]
    windows = {}
    cursor = inner[-1][1]
    for stage in ("clean", "normals", "surface", "samples", "fit"):
        windows[stage] = (cursor, cursor + info.seconds[stage])
        cursor += info.seconds[stage]
    for stage, function in (("read", "_read"), ("separate", "separate_objects"), ("mesh", "cloud_mesh"),
                            ("check", "_check_fit")):
        found = [s for s in spans if s[0] == function]
        if found:
            windows[stage] = (found[0][1], found[-1][2])
    stages = {stage: dict(seconds=round(windows[stage][1] - windows[stage][0], 2),
                          cpu_seconds=round(memory.cpu_seconds(*windows[stage]), 1),
                          peak_gb=round(memory.peak(*windows[stage]) / GB, 2)) for stage in STAGES if stage in windows}
    functions = {}
    for name, begin, finish in spans:
        row = functions.setdefault(name, dict(calls=0, seconds=0.0, cpu_seconds=0.0, peak_gb=0.0))
        row["calls"] += 1
        row["seconds"] = round(row["seconds"] + finish - begin, 2)
        row["cpu_seconds"] = round(row["cpu_seconds"] + memory.cpu_seconds(begin, finish), 1)
        row["peak_gb"] = round(max(row["peak_gb"], memory.peak(begin, finish) / GB), 2)
    run = dict(label=args.label, mesh=args.mesh, points=args.points, given_normals=args.normals, noise=args.noise, date=time.strftime("%Y-%m-%d %H:%M"),
               seconds=round(end - start, 1), cpu_seconds=round(memory.cpu_seconds(start, end), 1), peak_gb=round(total_peak / GB, 2), baseline_gb=round(baseline / GB, 2),
               grid=info.grid, target=info.target, normals=info.normals, faces=len(result.triangles),
               load_average=[round(load[0], 2), round(os.getloadavg()[0], 2)], cpus=os.cpu_count(),
               stages=stages, functions=functions)
    if args.evaluate:
        scores = voro3d.evaluate(result, mesh)
        run.update(chamfer_x1e5=round(scores["chamfer_x1e5"], 4), nc=round(scores["nc"], 4), f1=round(scores["f1"], 4))
    return run


def write(runs: list, out: Path) -> None:
    out.with_suffix(".json").write_text(json.dumps(runs, indent=1) + "\n")
    lines = ["# Large clouds: seconds and peak memory per stage of `reconstruct`", "",
             "Area-uniform samples of a dev mesh with their true normals, `voro3d.reconstruct(cloud, grid=\"auto\")` "
             "(`benchmarks/profile_large.py`). Peak = highest resident memory sampled in the stage's window "
             "(absolute: the cloud and the imports are in it, `baseline`); the whole call's from `getrusage`. "
             "Timings on a shared 2-core machine are contended (load average at start, end); CPU s (user + system, "
             "all threads, from `/proc`) is the work done, which contention inflates far less.", "",
             "Stage cells: seconds / peak GB.", "",
             "| run | mesh | points | normals | noise | grid | target | seconds | CPU s | peak GB | baseline GB | load | "
             + " | ".join(STAGES) + " |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(STAGES)]
    for run in runs:
        cells = [f"{run['stages'][s]['seconds']:.1f} s / {run['stages'][s]['peak_gb']:.1f}" if s in run["stages"] else "-"
                 for s in STAGES]
        cpu = f"{run['cpu_seconds']:.0f}" if "cpu_seconds" in run else "-"
        lines.append(f"| {run['label']} | {run['mesh']} | {run['points']:,} | {run.get('given_normals', 'true')} | "
                     f"{run.get('noise', 0.0):g} | {run['grid']} | {run['target']} | {run['seconds']:.1f} | {cpu} | "
                     f"{run['peak_gb']:.2f} | {run['baseline_gb']:.2f} | {run['load_average'][0]:.1f}, "
                     f"{run['load_average'][1]:.1f} | " + " | ".join(cells) + " |")
    key = lambda run: (run["mesh"], run["points"], run.get("given_normals", "true"), run.get("noise", 0.0))
    pairs = [(before, after) for before in runs if before["label"] == "before"
             for after in runs if after["label"] == "after" and key(after) == key(before)]
    for before, after in pairs:
        lines += ["", f"### Before and after: {before['mesh']}, {before['points']:,} points, normals "
                  f"{before.get('given_normals', 'true')}, noise {before.get('noise', 0.0):g}", "",
                  "| stage | before s | before CPU s | before peak GB | after s | after CPU s | after peak GB |",
                  "|---|---|---|---|---|---|---|"]
        cpu = lambda row: f"{row['cpu_seconds']:.1f}" if "cpu_seconds" in row else "-"
        lines += [f"| {stage} | {before['stages'][stage]['seconds']:.1f} | {cpu(before['stages'][stage])} | "
                  f"{before['stages'][stage]['peak_gb']:.2f} | {after['stages'][stage]['seconds']:.1f} | "
                  f"{cpu(after['stages'][stage])} | {after['stages'][stage]['peak_gb']:.2f} |"
                  for stage in STAGES if stage in before["stages"] and stage in after["stages"]]
        lines.append(f"| **whole call** | {before['seconds']:.1f} | {cpu(before)} | {before['peak_gb']:.2f} | "
                     f"{after['seconds']:.1f} | {cpu(after)} | {after['peak_gb']:.2f} |")
    scored = [run for run in runs if "chamfer_x1e5" in run]
    if scored:
        lines += ["", "| run | mesh | points | normals | noise | faces | CD x1e5 | NC | F1 |", "|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['label']} | {r['mesh']} | {r['points']:,} | {r.get('given_normals', 'true')} | "
                  f"{r.get('noise', 0.0):g} | {r['faces']:,} | {r['chamfer_x1e5']:.3f} | {r['nc']:.4f} | {r['f1']:.3f} |"
                  for r in scored]
    for run in runs:
        lines += ["", f"## {run['label']}, {run['mesh']}, {run['points']:,} points, normals {run.get('given_normals', 'true')}, "
                  f"noise {run.get('noise', 0.0):g} ({run['date']}): functions", "",
                  "| function | calls | seconds | CPU s | peak GB |", "|---|---|---|---|---|"]
        lines += [f"| `{name}` | {row['calls']} | {row['seconds']:.2f} | "
                  + (f"{row['cpu_seconds']:.1f}" if "cpu_seconds" in row else "-") + f" | {row['peak_gb']:.2f} |"
                  for name, row in run["functions"].items()]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default="organic_bunny.off")
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--label", default="after")
    parser.add_argument("--normals", choices=("true", "none"), default="true", help="the cloud's normals")
    parser.add_argument("--noise", type=float, default=0.0, help="Gaussian noise, in bounding-box diagonals")
    parser.add_argument("--interval", type=float, default=0.01, help="seconds between memory samples")
    parser.add_argument("--max-gb", type=float, default=18.0, help="abort when resident memory passes this")
    parser.add_argument("--evaluate", action="store_true", help="also CD / NC / F1 against the mesh")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    run = profile(args)
    print(json.dumps(run), flush=True)
    path = args.out.with_suffix(".json")
    runs = json.loads(path.read_text()) if path.exists() else []
    key = ("label", "mesh", "points", "given_normals", "noise")
    runs = [r for r in runs if tuple(r.get(k, d) for k, d in zip(key, (None,) * 3 + ("true", 0.0))) != tuple(run[k] for k in key)]
    write(runs + [run], args.out)
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
