"""Throughput of ``voro3d batch``: 1 vs 2 local workers, and the Ray engine's overhead and outputs.

The watertight dev meshes (``shared/data/dev``; ``thingi32_96481`` is open and left out; ``--shapes``
takes the smallest few) are linked into a temporary input folder and fitted at grid 32 (``--steps``,
default the full 400) four ways, each into a fresh output folder:

* ``local, 1 worker`` and ``local, 2 workers`` (one thread and one CPU each, the default):
  :func:`voro3d.batch.run_batch` end to end, worker start-up (spawn, imports, warm-up) included;
  throughput is shapes per wall-clock second.
* ``local, 1 worker x 2 threads``: the other way to use two cores, for comparison.
* ``ray, 2 workers``: a local Ray instance with 2 CPUs, started here first so that ``ray.init``
  is timed on its own; the overhead per shape is (Ray wall time - local wall time at 2 workers)
  / shapes. Outputs are compared byte for byte with the local engine's.
* parallel capacity, before each 1-worker / 2-worker pair: the work two busy-loop processes get
  done together over what one gets done alone, i.e. the best speed-up the machine offers then.
* engine cost per shape, for both engines: batches of 10 and 60 corrupt files (each fails at
  once) at 2 workers; the slope of wall time between them is what the engine itself spends on a
  shape, start-up cancelled out.

The load average is recorded before and after every run: on a shared machine the speed-up
depends on what else is running. Writes ``benchmarks/results/batch.{md,json}``.

    python benchmarks/bench_batch.py [--shapes N] [--steps 400] [--repeats 1] [--no-ray]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import platform
import statistics
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OPEN_MESHES = {"thingi32_96481.obj"}


def _subset(count: int | None) -> list[Path]:
    """The ``count`` smallest watertight dev meshes, or all of them."""
    from voro3d.io import MESH_SUFFIXES

    meshes = [path for path in DEV.iterdir() if path.suffix.lower() in MESH_SUFFIXES and path.name not in OPEN_MESHES]
    return sorted(meshes, key=lambda path: (path.stat().st_size, path.name))[:count]


def _autogroup() -> bool:
    """Whether Linux shares CPU between sessions first (``sched_autogroup``), then between their processes."""
    try:
        return Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip() == "1"
    except OSError:
        return False


def _digests(folder: Path, rows) -> dict:
    return {row["output"]: hashlib.sha256((folder / row["output"]).read_bytes()).hexdigest()
            for row in rows if row["status"] == "ok"}


def _wait_until_quiet(load: float | None, limit: float) -> None:
    """Wait (at most ``limit`` seconds) for the 1-minute load average to drop below ``load``."""
    deadline = time.monotonic() + limit
    while load is not None and os.getloadavg()[0] >= load and time.monotonic() < deadline:
        time.sleep(5)


def _spin(seconds: float, queue) -> None:
    count, end = 0, time.perf_counter() + seconds
    while time.perf_counter() < end:
        count += 1
    queue.put(count)


def _parallel_capacity(seconds: float = 3.0) -> float:
    """Work two busy-loop processes get done together over what one gets done alone.

    The best speed-up any two processes of this session could get at that moment: 2.0 on two
    idle cores, less while other jobs take CPU time.
    """
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    totals = []
    for count in (1, 2):
        queue = context.Queue()
        spinners = [context.Process(target=_spin, args=(seconds, queue)) for _ in range(count)]
        for spinner in spinners:
            spinner.start()
        totals.append(sum(queue.get() for _ in spinners))
        for spinner in spinners:
            spinner.join()
    return totals[1] / totals[0]


def _run(label: str, inputs: Path, output: Path, **options) -> dict:
    from voro3d.batch import run_batch

    load_before = os.getloadavg()
    summary = run_batch(inputs, output, **options)
    load_after = os.getloadavg()
    rows = summary.rows
    ok = [row for row in rows if row["status"] == "ok"]
    record = {
        "label": label, "engine": summary.engine, "workers": summary.workers, "threads": options.get("threads", 1),
        "shapes": len(rows), "ok": len(ok),
        "wall_seconds": summary.seconds, "throughput_shapes_per_s": len(rows) / summary.seconds,
        "mean_shape_seconds": statistics.fmean(row["seconds"] for row in ok) if ok else None,
        "mean_shape_cpu_seconds": statistics.fmean(row["cpu_seconds"] for row in ok) if ok else None,
        # CPU the shapes got per wall-clock second: how many cores the batch actually had.
        "cores_obtained": sum(row["cpu_seconds"] for row in ok) / summary.seconds,
        "mean_peak_memory_mb": statistics.fmean(row["peak_memory_mb"] for row in ok) if ok else None,
        "load_before": load_before, "load_after": load_after,
        "failures": {row["input"]: row["error"] for row in rows if row["status"] != "ok"},
        "digests": _digests(output, rows),
    }
    print(f"{label:<28} {summary.seconds:7.1f} s  {record['throughput_shapes_per_s']:.3f} shapes/s  "
          f"load {load_before[0]:.2f} -> {load_after[0]:.2f}", flush=True)
    return record


def _dispatch_seconds(scratch: Path, engine: str, sizes=(10, 60)) -> float:
    """Marginal wall time of one shape that fails at once (a corrupt file), at 2 workers.

    The slope between two batch sizes, so that start-up cancels out: what is left is the engine's
    own cost per shape (hand-over, result transfer, the fsynced row).
    """
    from voro3d.batch import run_batch

    walls = []
    for size in sizes:
        folder = scratch / f"dispatch-{engine}-{size}"
        folder.mkdir()
        for index in range(size):
            (folder / f"broken{index:03}.ply").write_bytes(b"ply\nformat ascii 1.0\nnot a mesh\n")
        walls.append(run_batch(folder, scratch / f"dispatch-{engine}-{size}-out", workers=2, engine=engine).seconds)
    return (walls[1] - walls[0]) / (sizes[1] - sizes[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=int, help="use only the N smallest watertight dev meshes (default all)")
    parser.add_argument("--grid", type=int, default=32)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=1, help="runs of the 1-worker / 2-worker pair")
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray engine")
    parser.add_argument("--quiet-load", type=float,
                        help="before each run, wait until the 1-minute load average is below this")
    parser.add_argument("--max-wait", type=float, default=600, help="seconds to wait for quiet, per run")
    args = parser.parse_args()

    meshes = _subset(args.shapes)
    options = dict(method="fit", grid=args.grid, steps=args.steps, seed=0)
    runs = []
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        inputs = scratch / "in"
        inputs.mkdir()
        for mesh in meshes:
            (inputs / mesh.name).symlink_to(mesh)
        capacity = []
        for repeat in range(args.repeats):
            capacity.append(_parallel_capacity())
            print(f"two busy loops do {capacity[-1]:.2f}x the work of one", flush=True)
            for workers in (1, 2):
                _wait_until_quiet(args.quiet_load, args.max_wait)
                runs.append(_run(f"local, {workers} worker{'s' * (workers > 1)}", inputs,
                                 scratch / f"local{workers}-{repeat}", workers=workers, **options))
        _wait_until_quiet(args.quiet_load, args.max_wait)
        runs.append(_run("local, 1 worker x 2 threads", inputs, scratch / "threads2", workers=1, threads=2, **options))
        dispatch = {"local": _dispatch_seconds(scratch, "local")}
        ray_init = None
        if not args.no_ray:
            import ray

            _wait_until_quiet(args.quiet_load, args.max_wait)
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            start = time.perf_counter()
            ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING)
            ray_init = time.perf_counter() - start
            try:
                runs.append(_run("ray, 2 workers", inputs, scratch / "ray2", workers=2, engine="ray", **options))
                dispatch["ray"] = _dispatch_seconds(scratch, "ray")
            finally:
                ray.shutdown()

    one = [run for run in runs if run["engine"] == "local" and run["workers"] == 1 and run["threads"] == 1]
    two = [run for run in runs if run["engine"] == "local" and run["workers"] == 2]
    threaded = next(run for run in runs if run["threads"] == 2)
    speedups = [b["throughput_shapes_per_s"] / a["throughput_shapes_per_s"] for a, b in zip(one, two)]
    reference = two[0]["digests"]
    identical = {run["label"] + f" #{index}": run["digests"] == reference for index, run in enumerate(runs)}
    ray_run = next((run for run in runs if run["engine"] == "ray"), None)
    local_two_wall = statistics.fmean(run["wall_seconds"] for run in two)
    result = {
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cpus": len(os.sched_getaffinity(0)), "autogroup": _autogroup()},
        "meshes": [mesh.name for mesh in meshes], "grid": args.grid, "steps": args.steps,
        "runs": runs, "speedup_2_vs_1": speedups, "parallel_capacity": capacity,
        "speedup_2_threads_vs_1": threaded["throughput_shapes_per_s"] / one[0]["throughput_shapes_per_s"],
        "speedup_2_workers_vs_2_threads": two[0]["throughput_shapes_per_s"] / threaded["throughput_shapes_per_s"],
        "outputs_identical_to_local_2": identical,
        "ray_init_seconds": ray_init,
        "dispatch_seconds_per_shape": dispatch,
        "ray_overhead_seconds_per_shape": (ray_run["wall_seconds"] - local_two_wall) / len(meshes) if ray_run else None,
    }
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "batch.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "batch.md").write_text(_markdown(result))
    print(_markdown(result))


def _markdown(result: dict) -> str:
    lines = [
        "# voro3d batch throughput",
        "",
        f"{len(result['meshes'])} watertight dev meshes ({', '.join(result['meshes'])}), "
        f"`--method fit --grid {result['grid']} --steps {result['steps']}`, seed 0. "
        f"Taken {result['date']} on a {result['machine']['cpus']}-CPU machine "
        f"({result['machine']['platform']}, Python {result['machine']['python']}); "
        "the load averages show whether anything else ran (a quiet machine stays under about 1 "
        "during a 1-worker run, 2 during a 2-worker run). Wall time is end to end: "
        "worker start-up (spawn, imports, a warm-up shape) included; the Ray run excludes `ray.init`, "
        "timed on its own. Workers have one thread and one CPU each unless the run says otherwise.",
        "",
        "| run | wall (s) | shapes/s | mean s per shape in its worker | mean CPU s per shape | cores obtained "
        "| mean peak RSS (MB) | load avg 1 min before -> after |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for run in result["runs"]:
        lines.append(f"| {run['label']} | {run['wall_seconds']:.1f} | {run['throughput_shapes_per_s']:.3f} | "
                     f"{run['mean_shape_seconds']:.2f} | {run['mean_shape_cpu_seconds']:.2f} | "
                     f"{run['cores_obtained']:.2f} | {run['mean_peak_memory_mb']:.0f} | "
                     f"{run['load_before'][0]:.2f} -> {run['load_after'][0]:.2f} |")
    lines += ["", "*cores obtained*: CPU seconds of all shapes / wall seconds. When it does not grow with the "
              "workers, the machine had no more CPU to give (other jobs held it); CPU seconds per shape staying "
              "flat shows that the workers themselves do not slow each other down."]
    lines += ["", "Speed-up of 2 local workers over 1 (throughput ratio): "
              + ", ".join(f"{s:.2f}x" for s in result["speedup_2_vs_1"]) + ". Just before each pair, two "
              "busy-loop processes got " + ", ".join(f"{c:.2f}x" for c in result["parallel_capacity"])
              + " the work of one done: the most any two processes could gain at that moment (2.0 on two idle "
              "cores)."]
    if result["machine"]["autogroup"]:
        lines += ["", "This kernel has `sched_autogroup` on: CPU is shared fairly between sessions first, and a "
                  "batch and its local workers are one session (Ray's processes run in sessions of their own). "
                  "While other sessions keep the CPUs busy, the batch gets one session's share however many "
                  "workers it runs, so the speed-up only shows on an otherwise idle machine."]
    lines += ["", f"Two threads in one worker instead of two workers: {result['speedup_2_threads_vs_1']:.2f}x the "
              f"throughput of one single-threaded worker; two single-threaded workers get "
              f"{result['speedup_2_workers_vs_2_threads']:.2f}x its throughput. A shape gains little from a second "
              "thread (the fit is 400 small steps; only the kNN searches and the inside tests are multi-threaded), "
              "which is why `--threads` defaults to 1."]
    if result["ray_init_seconds"] is not None:
        lines += ["", f"Ray: `ray.init` took {result['ray_init_seconds']:.1f} s; the overhead per shape over the "
                  f"local engine at 2 workers is {result['ray_overhead_seconds_per_shape']:+.2f} s (wall-time difference / "
                  "shapes; on a shared machine differences of a second or so are noise)."]
    dispatch = result["dispatch_seconds_per_shape"]
    lines += ["", "Engine cost per shape, measured on shapes that fail at once (corrupt files) as the slope of wall "
              "time between batches of 10 and 60, so that start-up cancels: "
              + ", ".join(f"{engine} {seconds * 1000:.0f} ms" for engine, seconds in dispatch.items()) + "."]
    identical = result["outputs_identical_to_local_2"]
    lines += ["", "Output meshes identical byte for byte (SHA-256) to the local 2-worker run: "
              + ("all runs." if all(identical.values()) else ", ".join(f"{k}: {v}" for k, v in identical.items()))]
    failures = {run["label"]: run["failures"] for run in result["runs"] if run["failures"]}
    if failures:
        lines += ["", f"Failures: {failures}"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
