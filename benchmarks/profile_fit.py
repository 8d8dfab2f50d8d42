"""Where :func:`voro3d.fitting.fit` spends its time, and what the candidate-search policy costs in quality.

Three tables:

* ``phases``: for each mesh and grid, wall-clock seconds of sampling, initial generators (with
  the first kNN search), the optimisation loop, cell occupancy, and (outside the fit) mesh
  extraction; the fit's CPU seconds (all threads), which a loaded machine inflates less; the
  number of generators and kNN searches; the final VoroLoss; CD and F1 of the extracted mesh
  (:func:`voro3d.metrics.evaluate`, paper conventions).
* ``steps``: one mesh per grid, the loop's steps timed part by part (batch window, nearest-pair
  search, loss forward+backward, Adam+schedule+clamp+displacement check, kNN searches).
* ``kernel`` (``--kernel-study``): each mesh and grid fitted through the torch step
  (``fitting._CPU_KERNEL = False``, with Open3D's kNN search) and through the compiled kernel
  (``voro3d._fitkernel``), interleaved so that both see the same load: wall and CPU seconds of
  the whole fit, final loss, CD / F1 / NC and watertightness of the extracted mesh.
* ``budget`` (``--budget-study``): the fit (compiled kernel) with fewer surface samples per grid
  face and/or a smaller batch fraction than the official 150 and 0.2, which cut the work per step
  and per kNN search in proportion: seconds, final loss, CD / F1 / NC, watertightness.
* ``schedule`` (``--schedule-study``): the fit (compiled kernel) with other numbers of kNN candidates
  per sample and refresh thresholds (``k:voxels`` pairs; the threshold capped at
  ``fitting.MAX_REFRESH_DISTANCE`` as in every fit), for ``--schedule-meshes`` (``dev``: all dev
  meshes): seconds, searches, CD / F1 / NC, and their means per grid and pair.
* ``refresh`` (``--refresh-study``): the fit redone with the candidates searched again every step
  (``REFRESH_VOXELS = 0``, the exact loss) and at other thresholds; the final loss is recomputed
  exactly (fresh kNN search) so the policies are compared on equal terms.

Timings are taken on whatever machine runs this; on a shared machine they vary from run to run,
so the load average at start and end is recorded with them.
Writes ``<out>/profile_fit.{md,json}``.

    python benchmarks/profile_fit.py [--meshes sphere organic_bunny.off] [--grids 32 64]
        [--steps-mesh organic_bunny.off] [--refresh-study] [--kernel-study] [--budget-study]
        [--out out/profile_fit]
"""
from __future__ import annotations

import argparse
import bisect
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from voro3d import fitting as fit_module
from voro3d._torchfit import TorchLoop
from voro3d.generators import initial_generators
from voro3d.frames import fit_frame
from voro3d.io import load_mesh, mesh_arrays
from voro3d.loss import PAIR_BLOCK, bisector_distance, bisector_pairs, voroloss
from voro3d.metrics import evaluate
from voro3d.sampling import sample_surface
from voro3d.watertight import check_watertight

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"


def load(name):
    import open3d as o3d

    if name == "sphere":
        return o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=120)
    if name == "torus":
        return o3d.geometry.TriangleMesh.create_torus(torus_radius=1.0, tube_radius=0.4, radial_resolution=160,
                                                      tubular_resolution=80)
    path = Path(name) if Path(name).is_file() else DEV / name
    return load_mesh(path)


def phase_row(name, mesh, grid, steps):
    cpu = time.process_time()
    voromesh, info = fit_module.fit(mesh, grid, steps=steps)
    cpu = time.process_time() - cpu
    start = time.perf_counter()
    surface = voromesh.to_open3d()
    extract_seconds = time.perf_counter() - start
    metrics = evaluate(surface, mesh)
    return {
        "mesh": name, "grid": grid, "n_samples": info.n_samples, "n_generators": info.n_generators,
        "searches": info.candidate_searches, "sampling_s": info.sampling_seconds, "init_s": info.init_seconds,
        "optimisation_s": info.optimisation_seconds, "occupancy_s": info.occupancy_seconds,
        "fit_total_s": info.total_seconds, "fit_cpu_s": cpu, "extract_s": extract_seconds,
        "final_loss": info.final_loss,
        "watertight": check_watertight(surface, self_intersection=False).watertight,
        "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"],
    }


def step_row(name, mesh, grid, steps):
    """The loop of ``FitLoop.run`` on the torch backend, each part timed (a copy of it, so the fit itself carries no timers)."""
    vertices, triangles = mesh_arrays(mesh)
    frame = fit_frame((vertices, triangles))
    samples, _ = sample_surface((frame.apply(vertices), triangles), fit_module.SAMPLES_PER_FACE * grid**2, seed=0)
    loop = TorchLoop(samples, initial_generators(samples, grid), grid=grid, k=11, batch_fraction=0.2,
                     device=torch.device("cpu"))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    parts = dict.fromkeys(["window", "pairs", "loss_fwd_bwd", "adam_clamp_displacement", "search"], 0.0)
    generators_t = loop.generators_t
    with torch.no_grad():
        optimizer = fit_module.Adam(generators_t)
    offsets = np.random.default_rng(0).integers(loop.n_samples, size=steps).tolist()
    refresh = fit_module.REFRESH_VOXELS * fit_module.grid_voxel(grid)
    searches = 0
    try:
        for step in range(steps):
            generators_t.grad = None
            for start in range(0, loop.batch, PAIR_BLOCK):
                t0 = time.perf_counter()
                window = slice(offsets[step] + start, offsets[step] + min(start + PAIR_BLOCK, loop.batch))
                samples_t = loop.samples_t[:, window].contiguous()
                t1 = time.perf_counter()
                nearest, other = bisector_pairs(samples_t, generators_t.detach(), loop.candidates_t[:, window])
                t2 = time.perf_counter()
                loss = bisector_distance(samples_t, generators_t, nearest, other).square().sum() / loop.batch
                loss.backward()
                t3 = time.perf_counter()
                parts["window"] += t1 - t0
                parts["pairs"] += t2 - t1
                parts["loss_fwd_bwd"] += t3 - t2
            t3 = time.perf_counter()
            with torch.no_grad():
                optimizer.step(generators_t.grad, 0.005 * 0.5 ** bisect.bisect_right([80, 120, 200, 250], step))
                generators_t.clamp_(-1.0, 1.0)
                moved = (generators_t - loop.searched_at).square_().sum(0).amax()
            search = bool(moved > refresh**2) and step + 1 < steps
            t4 = time.perf_counter()
            if search:
                loop._search()
                searches += 1
            t5 = time.perf_counter()
            parts["adam_clamp_displacement"] += t4 - t3
            parts["search"] += t5 - t4
    finally:
        torch.set_num_threads(threads)
    total = sum(parts.values())
    row = {"mesh": name, "grid": grid, "batch": loop.batch, "steps": steps, "searches_in_loop": searches,
           "loop_s": total, "ms_per_step_without_search": 1e3 * (total - parts["search"]) / steps}
    row.update({f"{part}_s": seconds for part, seconds in parts.items()})
    return row


def kernel_rows(name, mesh, grid, steps, repeats):
    rows = []
    try:
        for repeat in range(repeats):
            for kernel in (False, True):
                fit_module._CPU_KERNEL = kernel
                load = os.getloadavg()[0]
                cpu = time.process_time()
                voromesh, info = fit_module.fit(mesh, grid, steps=steps)
                cpu = time.process_time() - cpu
                surface = voromesh.to_open3d()
                metrics = evaluate(surface, mesh)
                rows.append({"mesh": name, "grid": grid, "repeat": repeat, "step": "kernel" if kernel else "torch",
                             "fit_total_s": info.total_seconds, "optimisation_s": info.optimisation_seconds,
                             "fit_cpu_s": cpu, "searches": info.candidate_searches, "final_loss": info.final_loss,
                             "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"], "nc": metrics["nc"],
                             "watertight": check_watertight(surface, self_intersection=False).watertight,
                             "load_before": load})
                print(rows[-1], flush=True)
    finally:
        fit_module._CPU_KERNEL = True
    return rows


def budget_rows(name, mesh, grid, steps, budgets):
    rows = []
    for samples_per_face, batch_fraction in budgets:
        load = os.getloadavg()[0]
        cpu = time.process_time()
        voromesh, info = fit_module.fit(mesh, grid, steps=steps, n_samples=int(samples_per_face * grid**2),
                                        batch_fraction=batch_fraction)
        cpu = time.process_time() - cpu
        surface = voromesh.to_open3d()
        metrics = evaluate(surface, mesh)
        rows.append({"mesh": name, "grid": grid, "samples_per_face": samples_per_face, "batch_fraction": batch_fraction,
                     "fit_total_s": info.total_seconds, "fit_cpu_s": cpu, "searches": info.candidate_searches,
                     "final_loss": info.final_loss, "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"],
                     "nc": metrics["nc"], "watertight": check_watertight(surface, self_intersection=False).watertight,
                     "load_before": load})
        print(rows[-1], flush=True)
    return rows


def schedule_rows(name, mesh, grid, steps, schedules):
    rows = []
    default = fit_module.REFRESH_VOXELS
    try:
        for k, refresh in schedules:
            fit_module.REFRESH_VOXELS = refresh
            load = os.getloadavg()[0]
            cpu = time.process_time()
            voromesh, info = fit_module.fit(mesh, grid, steps=steps, k=k, allow_open=True)  # thingi32_96481 is open
            cpu = time.process_time() - cpu
            surface = voromesh.to_open3d()
            metrics = evaluate(surface, mesh)
            rows.append({"mesh": name, "grid": grid, "k": k, "refresh_voxels": refresh,
                         "fit_total_s": info.total_seconds, "fit_cpu_s": cpu, "searches": info.candidate_searches,
                         "final_loss": info.final_loss,
                         "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"], "nc": metrics["nc"],
                         "load_before": load})
            print(rows[-1], flush=True)
    finally:
        fit_module.REFRESH_VOXELS = default
    return rows


def schedule_means(rows):
    """Means per grid and (k, refresh) pair, and their change against the first pair of the grid."""
    means = []
    for grid in dict.fromkeys(row["grid"] for row in rows):
        pairs = dict.fromkeys((row["k"], row["refresh_voxels"]) for row in rows if row["grid"] == grid)
        first = None
        for k, refresh in pairs:
            chosen = [row for row in rows if (row["grid"], row["k"], row["refresh_voxels"]) == (grid, k, refresh)]
            mean = {key: float(np.mean([row[key] for row in chosen]))
                    for key in ("fit_total_s", "fit_cpu_s", "searches", "cd_x1e5", "f1", "nc")}
            first = first or mean
            means.append({"grid": grid, "k": k, "refresh_voxels": refresh, "meshes": len(chosen), **mean,
                          "max_fit_total_s": max(row["fit_total_s"] for row in chosen),
                          "cd_change_%": 100 * (mean["cd_x1e5"] / first["cd_x1e5"] - 1),
                          "f1_change_%": 100 * (mean["f1"] / first["f1"] - 1),
                          "nc_change_%": 100 * (mean["nc"] / first["nc"] - 1)})
    return means


def refresh_rows(name, mesh, grid, steps, thresholds):
    vertices, triangles = mesh_arrays(mesh)
    frame = fit_frame((vertices, triangles))
    samples, _ = sample_surface((frame.apply(vertices), triangles), fit_module.SAMPLES_PER_FACE * grid**2, seed=0)
    rows = []
    default = fit_module.REFRESH_VOXELS
    try:
        for threshold in thresholds:
            fit_module.REFRESH_VOXELS = threshold
            voromesh, info = fit_module.fit(mesh, grid, steps=steps)
            surface = voromesh.to_open3d()
            metrics = evaluate(surface, mesh)
            exact = float(voroloss(samples, torch.tensor(frame.apply(voromesh.generators))))
            rows.append({"mesh": name, "grid": grid, "refresh_voxels": threshold, "searches": info.candidate_searches,
                         "fit_total_s": info.total_seconds, "loss_with_fit_candidates": info.final_loss,
                         "exact_final_loss": exact, "cd_x1e5": metrics["chamfer_x1e5"], "f1": metrics["f1"]})
            print(rows[-1], flush=True)
    finally:
        fit_module.REFRESH_VOXELS = default
    return rows


def markdown(title, rows):
    if not rows:
        return ""
    keys = list(rows[0])
    lines = [f"## {title}", "", "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for row in rows:
        cells = [f"{row[key]:.4g}" if isinstance(row[key], float) else str(row[key]) for key in keys]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=["sphere", "organic_bunny.off", "cad_fandisk.obj",
                                                        "thingi32_44234.obj"])
    parser.add_argument("--grids", nargs="*", type=int, default=[32, 64], help="grids of the phase and step tables")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--steps-mesh", default="organic_bunny.off", help="mesh of the per-step table")
    parser.add_argument("--refresh-study", action="store_true")
    parser.add_argument("--kernel-study", action="store_true", help="torch step vs compiled kernel, interleaved")
    parser.add_argument("--kernel-grids", nargs="+", type=int, default=[32, 64])
    parser.add_argument("--kernel-repeats", type=int, default=1)
    parser.add_argument("--budget-study", action="store_true", help="fewer samples per face / smaller batches")
    parser.add_argument("--budget-grids", nargs="+", type=int, default=[32, 64])
    parser.add_argument("--budgets", nargs="+", default=["150:0.2", "100:0.2", "75:0.2", "150:0.1"],
                        help="samples_per_face:batch_fraction pairs")
    parser.add_argument("--schedule-study", action="store_true", help="kNN candidates and refresh threshold")
    parser.add_argument("--schedule-grids", nargs="+", type=int, default=[32, 64])
    parser.add_argument("--schedules", nargs="+", default=["11:1.0", "8:1.5"], help="k:refresh_voxels pairs")
    parser.add_argument("--schedule-meshes", nargs="+", default=None,
                        help="meshes of the schedule study (default --meshes; 'dev' for all dev meshes)")
    parser.add_argument("--refresh-grids", nargs="+", type=int, default=[32, 64])
    parser.add_argument("--refresh-thresholds", nargs="+", type=float, default=[0.0, 0.5, 1.0, 2.0, float("inf")])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "profile_fit")
    args = parser.parse_args()

    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "torch": torch.__version__,
                          "load_average_at_start": os.getloadavg()},
              "phases": [], "steps": [], "kernel": [], "budget": [], "schedule": [], "schedule_means": [],
              "refresh": []}
    meshes = {name: load(name) for name in dict.fromkeys(args.meshes + [args.steps_mesh])}
    for grid in args.grids:
        for name in args.meshes:
            result["phases"].append(phase_row(name, meshes[name], grid, args.steps))
            print(result["phases"][-1], flush=True)
        result["steps"].append(step_row(args.steps_mesh, meshes[args.steps_mesh], grid, args.steps))
        print(result["steps"][-1], flush=True)
    if args.kernel_study:
        for grid in args.kernel_grids:
            for name in args.meshes:
                result["kernel"] += kernel_rows(name, meshes[name], grid, args.steps, args.kernel_repeats)
    if args.budget_study:
        budgets = [(float(text.split(":")[0]), float(text.split(":")[1])) for text in args.budgets]
        for grid in args.budget_grids:
            for name in args.meshes:
                result["budget"] += budget_rows(name, meshes[name], grid, args.steps, budgets)
    if args.schedule_study:
        names = args.schedule_meshes or args.meshes
        if names == ["dev"]:
            names = sorted(path.name for path in DEV.iterdir() if path.suffix in (".obj", ".off", ".stl", ".ply"))
        schedules = [(int(text.split(":")[0]), float(text.split(":")[1])) for text in args.schedules]
        for grid in args.schedule_grids:
            for name in names:
                result["schedule"] += schedule_rows(name, meshes.get(name) or load(name), grid, args.steps, schedules)
        result["schedule_means"] = schedule_means(result["schedule"])
    if args.refresh_study:
        for grid in args.refresh_grids:
            for name in args.meshes:
                result["refresh"] += refresh_rows(name, meshes[name], grid, args.steps, args.refresh_thresholds)
    result["machine"]["load_average_at_end"] = os.getloadavg()

    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "profile_fit.json").write_text(json.dumps(result, indent=1, default=float))
    text = "# VoroMesh fit profile\n\n" + f"Machine: {json.dumps(result['machine'])}\n\n"
    text += "\n".join(markdown(title, result[key]) for key, title in
                      (("phases", "Phases (wall-clock seconds)"), ("steps", "Loop parts (wall-clock seconds)"),
                       ("kernel", "Torch step vs compiled kernel (interleaved)"),
                       ("budget", "Samples per face and batch fraction vs quality"),
                       ("schedule_means", "kNN candidates and refresh threshold: means"),
                       ("schedule", "kNN candidates and refresh threshold, per mesh"),
                       ("refresh", "Candidate-search threshold vs quality")))
    (args.out / "profile_fit.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
