"""Cleaned vs uncleaned VoroMesh surfaces, and Marching Cubes, on the dev meshes.

For every mesh of a folder (default ``../shared/data/dev``) and every grid: fit a VoroMesh (the
generators are cached under ``out/bench_clean/`` with the fit's time, so a rerun refits nothing
unless ``--refit``), extract its surface, clean it (:func:`voro3d.cleaning.clean_surface`), and
build Marching Cubes from the SDF grid of the same resolution. Each surface is scored against the input: CD x1e5, F1
and NC (:func:`voro3d.metrics.evaluate`), the share of triangles more than 30 degrees off the
true normal and the share of slivers, smallest angle under 5 degrees
(:func:`voro3d.metrics.triangle_quality`), faces, and the full watertight check (exact crossing
test). The cleaned surface is also measured against the uncleaned one: sampled distances both ways
(in voxels, beside the bound ``clean`` guarantees) and the volume change. *output* is what the mesh
paths return: the cleaned surface fitted to the input (:func:`voro3d.snapping.snap_to_surface`). Clean time (wall
and CPU) is compared with the fit's, measured in the same process with ``--refit``; the clean's
peak memory is the process's peak RSS during the clean (reset through ``/proc/self/clear_refs``
before it, after handing freed heap back with ``malloc_trim``), and its rise over the RSS before. Each shape runs in its own process.

``--clouds`` does the same for the point-cloud outputs: clouds made as ``bench_pointcloud.py``
makes them (``CLOUD_CONDITIONS`` of its conditions) from ``CLOUD_SHAPES``, reconstructed by
:func:`voro3d.pointcloud.reconstruct_points` (grid auto), their surface before and after the clean,
Marching Cubes of the true mesh at the same grid beside them. Also the surface the library
returns (:func:`voro3d.pointcloud.cloud_mesh`: the cleaned one, fitted to the target surface,
smoothed on noisy clouds) and Marching Cubes of the cloud's own target surface at the same grid: the
comparison with the same information (noise, holes) that the true mesh does not have.

Writes ``benchmarks/results/clean_<grids>.{md,json}`` (``clean_clouds`` with ``--clouds``) and a
PNG of a few shapes before and after.

    python benchmarks/bench_clean.py [--grids 32 64] [--folder DIR] [--names a.obj b.off] [--limit N] [--refit]
    python benchmarks/bench_clean.py --clouds
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
CACHE = ROOT / "out" / "bench_clean"
SURFACES = ("uncleaned", "cleaned", "output", "mc")
CLOUD_SURFACES = ("uncleaned", "cleaned", "output", "mc", "mc_target", "poisson")
PICTURED = ("cad_fandisk.obj", "organic_bunny.off", "cad_rocker-arm.obj")
CLOUD_SHAPES = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "cad_rocker-arm.obj")
CLOUD_CONDITIONS = ("clean 20k", "noise 0.5%", "outliers 2%", "third missing")


def _peak_rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _reset_peak_rss() -> bool:
    """Hand freed heap back to the OS (glibc), then restart the peak at the current RSS (Linux)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _fitted(path: Path, grid: int, refit: bool):
    """The VoroMesh of ``path`` at ``grid`` and the fit's seconds, from the cache or a new fit."""
    import torch

    from voro3d.voromesh import VoroMesh
    from voro3d.fitting import fit
    from voro3d.io import load_mesh, mesh_arrays
    from voro3d.topology import open_edge_count

    stem = CACHE / f"{path.stem}_{grid}"
    if not refit and stem.with_suffix(".npz").exists() and stem.with_suffix(".json").exists():
        return VoroMesh.load(stem.with_suffix(".npz")), json.loads(stem.with_suffix(".json").read_text())
    torch.set_num_threads(1)
    source = load_mesh(path)
    open_input = open_edge_count(*mesh_arrays(source)) > 0
    start, cpu = time.perf_counter(), time.process_time()
    shape, _ = fit(source, grid, progress=False, allow_open=open_input)
    fit = dict(fit_seconds=time.perf_counter() - start, fit_cpu_seconds=time.process_time() - cpu,
               open_input=bool(open_input), fit_load_average=Path("/proc/loadavg").read_text().split()[:3])
    CACHE.mkdir(parents=True, exist_ok=True)
    shape.save(stem.with_suffix(".npz"))
    stem.with_suffix(".json").write_text(json.dumps(fit))
    return shape, fit


def _distances_voxels(a, b, voxel, n_samples=100_000):
    """Sampled distances from surface ``a`` to surface ``b`` (both (vertices, triangles)), in voxels."""
    import open3d as o3d

    from voro3d.sampling import sample_surface

    points, _ = sample_surface(a, n_samples, seed=1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(b[0].astype(np.float32)), o3d.core.Tensor(b[1].astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy() / voxel


def _grid_voxel(source, grid):
    """The fit grid's voxel in the input's units: 2 / (grid - 1) in the fit frame."""
    from voro3d.frames import fit_frame

    return 2.0 / (grid - 1) / fit_frame(source).scale


def _surfaces(source, shape, grid, open_input):
    """The uncleaned, cleaned and Marching Cubes surfaces, the clean's report, times and peak RSS."""
    from voro3d.baselines import marching_cubes
    from voro3d.cleaning import clean_surface
    from voro3d.extract import voronoi_surface
    from voro3d.frames import fit_frame
    from voro3d.queries import sdf_grid

    surfaces = {"uncleaned": voronoi_surface(shape.generators, shape.occupancy)}
    before_rss = _peak_rss_mib() if _reset_peak_rss() else float("nan")
    start, cpu = time.perf_counter(), time.process_time()
    vertices, triangles, info = clean_surface(*surfaces["uncleaned"], voxel=shape.voxel or _grid_voxel(source, grid))
    timing = dict(clean_seconds=time.perf_counter() - start, clean_cpu_seconds=time.process_time() - cpu,
                  clean_peak_rss_mib=_peak_rss_mib(), clean_rss_rise_mib=_peak_rss_mib() - before_rss,
                  clean_load_average=Path("/proc/loadavg").read_text().split()[:3])
    surfaces["cleaned"] = (vertices, triangles)
    frame = fit_frame(source)
    mc_vertices, mc_triangles = marching_cubes(sdf_grid(frame.apply_mesh(source), grid, allow_open=open_input))
    surfaces["mc"] = (frame.invert(mc_vertices), mc_triangles)
    return surfaces, info, timing


def _scores(surfaces, source, info):
    """Every surface scored against the input; the cleaned one measured against the uncleaned."""
    from voro3d.metrics import evaluate, triangle_quality
    from voro3d.watertight import check_watertight

    row = {}
    for name, surface in surfaces.items():
        scores = evaluate(surface, source)
        scores.update(triangle_quality(surface, source))
        report = check_watertight(surface)
        scores.update(watertight=report.watertight, self_intersecting_pairs=report.self_intersecting_pairs,
                      volume=report.volume)
        row[name] = scores
    to_input = _distances_voxels(surfaces["cleaned"], surfaces["uncleaned"], info.voxel)
    from_input = _distances_voxels(surfaces["uncleaned"], surfaces["cleaned"], info.voxel)
    row.update(distance_to_uncleaned_max=float(to_input.max()), distance_from_uncleaned_max=float(from_input.max()),
               distance_mean=float((to_input.mean() + from_input.mean()) / 2),
               distance_bound=info.max_distance / info.voxel,
               volume_change=row["cleaned"]["volume"] / row["uncleaned"]["volume"] - 1, clean=info.as_dict())
    return row


def _one(path, grid, refit, queue):
    from voro3d.cleaning import voxel_size
    from voro3d.io import load_mesh, mesh_arrays, save_mesh, to_triangle_mesh
    from voro3d.snapping import snap

    try:
        path = Path(path)
        source = load_mesh(path)
        shape, fit = _fitted(path, grid, refit)
        surfaces, info, timing = _surfaces(source, shape, grid, fit["open_input"])
        start = time.perf_counter()
        surfaces["output"] = mesh_arrays(snap(surfaces["cleaned"], source, voxel=info.voxel))
        timing["snap_seconds"] = time.perf_counter() - start
        row = dict(shape=path.name, grid=grid, status="ok", **fit, **timing,
                   clean_time_ratio=timing["clean_seconds"] / fit["fit_seconds"],
                   snap_time_ratio=timing["snap_seconds"] / fit["fit_seconds"])
        if "fit_cpu_seconds" in fit:
            row["clean_cpu_ratio"] = timing["clean_cpu_seconds"] / fit["fit_cpu_seconds"]
        row.update(_scores(surfaces, source, info))
        row["voxel_estimate_ratio"] = voxel_size(*surfaces["uncleaned"]) / info.voxel
        if path.name in PICTURED:
            for name in ("uncleaned", "cleaned", "output"):
                save_mesh(to_triangle_mesh(*surfaces[name]), CACHE / f"{path.stem}_{grid}_{name}.ply")
        queue.put(row)
    except Exception as error:  # one bad shape is recorded, not fatal
        queue.put(dict(shape=Path(path).name, grid=grid, status="failed", error=f"{type(error).__name__}: {error}"))


def _one_cloud(path, condition, queue):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_pointcloud import make_cloud

    from voro3d.baselines import marching_cubes
    from voro3d.cleaning import voxel_size
    from voro3d.frames import fit_frame
    from voro3d.io import load_mesh, mesh_arrays
    from voro3d.pointcloud import cloud_mesh, reconstruct_points
    from voro3d.queries import sdf_grid
    from voro3d.snapping import MAX_MOVE as SNAP_MAX_MOVE

    try:
        path = Path(path)
        source = load_mesh(path)
        start = time.perf_counter()
        cloud = make_cloud(source, condition)
        shape, target, cloud_info = reconstruct_points(cloud)
        reconstruct_seconds = time.perf_counter() - start
        surfaces, info, timing = _surfaces(source, shape, cloud_info.grid, False)
        start = time.perf_counter()
        surfaces["output"] = mesh_arrays(cloud_mesh(shape, target))
        output_seconds = time.perf_counter() - start
        frame = fit_frame(source)
        vertices, triangles = marching_cubes(sdf_grid(frame.apply_mesh((target.vertices, target.triangles)), cloud_info.grid,
                                                      allow_open=True))
        surfaces["mc_target"] = (frame.invert(vertices), triangles)
        surfaces["poisson"] = _best_poisson(cloud, source)
        row = dict(shape=path.name, condition=condition, grid=cloud_info.grid, status="ok", target=cloud_info.target,
                   snapped=target.snap, reconstruct_seconds=reconstruct_seconds, output_seconds=output_seconds,
                   **timing)
        row.update(_scores(surfaces, source, info))
        # The output against the uncleaned surface, in the grid's voxels: the clean's bound, plus the
        # snap's largest move where it snapped (both in the clean's estimated voxel).
        to_input = _distances_voxels(surfaces["output"], surfaces["uncleaned"], cloud_info.voxel)
        from_input = _distances_voxels(surfaces["uncleaned"], surfaces["output"], cloud_info.voxel)
        row.update(output_distance_max=float(max(to_input.max(), from_input.max())),
                   output_distance_bound=(info.max_distance + SNAP_MAX_MOVE * info.voxel * target.snap)
                   / cloud_info.voxel)
        row["voxel_estimate_ratio"] = voxel_size(*surfaces["uncleaned"]) / info.voxel
        queue.put(row)
    except Exception as error:  # one bad cloud is recorded, not fatal
        queue.put(dict(shape=Path(path).name, condition=condition, status="failed",
                       error=f"{type(error).__name__}: {error}"))


def run_in_process(target, *args):
    """``target(*args, queue)`` in a process of its own (so that its peak RSS is its own); its row."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=target, args=(*args, queue))
    process.start()
    row = queue.get()
    process.join()
    return row


METRICS = (("faces", "n_triangles", "{:.0f}"), ("off-normal %", "off_normal_share", "{:.1%}"),
           ("off-normal % of area", "off_normal_area_share", "{:.1%}"),
           ("slivers %", "sliver_share", "{:.1%}"), ("CD x1e5", "chamfer_x1e5", "{:.3f}"), ("F1", "f1", "{:.3f}"),
           ("NC", "nc", "{:.3f}"))


def _summary(rows, grid):
    ok = [r for r in rows if r["grid"] == grid and r["status"] == "ok"]
    out = dict(grid=grid, shapes=len(ok), failed=len([r for r in rows if r["grid"] == grid]) - len(ok))
    if not ok:
        return out
    for surface in SURFACES:
        for _, key, _ in METRICS:
            out[f"{surface}_{key}"] = float(np.mean([r[surface][key] for r in ok]))
        out[f"{surface}_watertight_pct"] = 100.0 * np.mean([r[surface]["watertight"] for r in ok])
    out["face_ratio"] = float(np.mean([r["uncleaned"]["n_triangles"] / r["cleaned"]["n_triangles"] for r in ok]))
    out["face_ratio_min"] = float(min(r["uncleaned"]["n_triangles"] / r["cleaned"]["n_triangles"] for r in ok))
    for key in ("chamfer_x1e5", "f1", "nc"):
        change = [r["cleaned"][key] / r["uncleaned"][key] - 1 for r in ok]
        out[f"{key}_change_mean"], out[f"{key}_change_worst"] = float(np.mean(change)), float(
            max(change) if key == "chamfer_x1e5" else min(change))
    out["off_normal_above_mc"] = int(sum(r["cleaned"]["off_normal_share"] > r["mc"]["off_normal_share"] for r in ok))
    out["output_off_normal_above_mc"] = int(sum(r["output"]["off_normal_share"] > r["mc"]["off_normal_share"]
                                                for r in ok))
    for against in ("cleaned", "uncleaned"):
        change = [r["output"]["chamfer_x1e5"] / r[against]["chamfer_x1e5"] - 1 for r in ok]
        out[f"output_cd_change_{against}_mean"], out[f"output_cd_change_{against}_worst"] = float(
            np.mean(change)), float(max(change))
    out["output_nc_change_worst"] = float(min(r["output"]["nc"] - r["cleaned"]["nc"] for r in ok))
    out["output_slivers_max"] = float(max(r["output"]["sliver_share"] for r in ok))
    out["snap_seconds_mean"] = float(np.mean([r["snap_seconds"] for r in ok]))
    out["snap_time_ratio_max"] = float(max(r["snap_time_ratio"] for r in ok))
    both = [r["clean_time_ratio"] + r["snap_time_ratio"] for r in ok]
    out["clean_snap_time_ratio_mean"], out["clean_snap_time_ratio_max"] = float(np.mean(both)), float(max(both))
    out["slivers_max"] = float(max(r["cleaned"]["sliver_share"] for r in ok))
    out["off_normal_max"] = float(max(r["cleaned"]["off_normal_share"] for r in ok))
    out["clean_seconds_mean"] = float(np.mean([r["clean_seconds"] for r in ok]))
    out["clean_time_ratio_mean"] = float(np.mean([r["clean_time_ratio"] for r in ok]))
    out["clean_time_ratio_max"] = float(max(r["clean_time_ratio"] for r in ok))
    cpu = [r["clean_cpu_ratio"] for r in ok if "clean_cpu_ratio" in r]
    out["clean_cpu_ratio_mean"] = float(np.mean(cpu)) if cpu else float("nan")
    out["clean_cpu_ratio_max"] = float(max(cpu)) if cpu else float("nan")
    out["clean_peak_rss_mib_max"] = float(max(r["clean_peak_rss_mib"] for r in ok))
    out["clean_rss_rise_mib_max"] = float(max(r["clean_rss_rise_mib"] for r in ok))
    out["distance_max"] = float(max(max(r["distance_to_uncleaned_max"], r["distance_from_uncleaned_max"]) for r in ok))
    out["distance_bound"] = float(ok[0]["distance_bound"])
    ratio = [r["voxel_estimate_ratio"] for r in ok]
    out["voxel_estimate_ratio_min"], out["voxel_estimate_ratio_max"] = float(min(ratio)), float(max(ratio))
    out["volume_change_max"] = float(max(abs(r["volume_change"]) for r in ok))
    out["rounds_max"] = int(max(r["clean"]["rounds"] for r in ok))
    return out


def write_tables(rows, grids, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    load = Path("/proc/loadavg").read_text().split()[:3]
    meta = dict(machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores",
                date=time.strftime("%Y-%m-%d %H:%M"), load_average_after=load)
    summaries = [_summary(rows, g) for g in grids]
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, summary=summaries, rows=rows), indent=2,
                                                   default=float))
    lines = [f"# Cleaned VoroMesh surfaces ({meta['date']}, {meta['machine']}, load average after {' '.join(load)})",
             "", "Means over shapes. Off-normal: triangles whose normal is more than 30 degrees from the input's "
             "normal at the point of the input nearest their centroid (unsigned, as NC), as a share of the "
             "triangles and of the area. Slivers: smallest "
             "angle under 5 degrees. CD x1e5, F1 at 0.003, NC against the input (100k samples each). "
             "Watertight: closed, manifold, oriented, positive volume, no crossing triangles (exact). Distances "
             "between the cleaned and uncleaned surfaces: 100k samples each way, in the grid's voxels (what "
             "`VoroMesh.to_open3d` gives `clean`; `voxel_size`'s estimate from the triangles, used where the grid "
             "is unknown, beside them as a ratio), against the bound it guarantees. "
             "*output*: what the mesh paths return (`reconstruct`, `voro3d fit`, `run_batch`: "
             "`VoroMesh.to_open3d(surface=input)`), the cleaned surface fitted to the input "
             "(`voro3d.snapping.snap_to_surface`, not part of `clean`).", "",
             "| grid | shapes | surface | " + " | ".join(name for name, _, _ in METRICS) + " | watertight % |",
             "|---|---|---|" + "---|" * len(METRICS) + "---|"]
    for s in summaries:
        if not s["shapes"]:
            continue
        for surface in SURFACES:
            cells = [fmt.format(s[f"{surface}_{key}"]) for _, key, fmt in METRICS]
            lines.append(f"| {s['grid']} | {s['shapes']} | {surface} | " + " | ".join(cells) +
                         f" | {s[surface + '_watertight_pct']:.0f} |")
    lines += ["", "| grid | faces fewer (mean, worst) | CD change (mean, worst) | F1 change (mean, worst) | "
              "NC change (mean, worst) | shapes off-normal above MC | slivers max | clean s (mean) | "
              "clean / fit wall (mean, max) | clean / fit CPU (mean, max) | clean peak RSS MiB, rise (max) | "
              "distance max / bound (voxels) | estimated / grid voxel | volume change max | rounds max |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        if not s["shapes"]:
            continue
        lines.append(
            f"| {s['grid']} | {s['face_ratio']:.2f}x, {s['face_ratio_min']:.2f}x | "
            f"{s['chamfer_x1e5_change_mean']:+.2%}, {s['chamfer_x1e5_change_worst']:+.2%} | "
            f"{s['f1_change_mean']:+.2%}, {s['f1_change_worst']:+.2%} | "
            f"{s['nc_change_mean']:+.2%}, {s['nc_change_worst']:+.2%} | {s['off_normal_above_mc']} | "
            f"{s['slivers_max']:.1%} | {s['clean_seconds_mean']:.2f} | "
            f"{s['clean_time_ratio_mean']:.1%}, {s['clean_time_ratio_max']:.1%} | "
            f"{s['clean_cpu_ratio_mean']:.1%}, {s['clean_cpu_ratio_max']:.1%} | "
            f"{s['clean_peak_rss_mib_max']:.0f}, {s['clean_rss_rise_mib_max']:.0f} | "
            f"{s['distance_max']:.3f} / {s['distance_bound']:.2f} | "
            f"{s['voxel_estimate_ratio_min']:.2f}-{s['voxel_estimate_ratio_max']:.2f} | "
            f"{s['volume_change_max']:.2e} | {s['rounds_max']} |")
    lines += ["", "| grid | output: CD change against cleaned (mean, worst) | against uncleaned (mean, worst) | "
              "NC change against cleaned (worst) | slivers max | shapes off-normal above MC | snap s (mean) | "
              "snap / fit wall (max) | clean + snap / fit wall (mean, max) |", "|---|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        if s["shapes"]:
            lines.append(f"| {s['grid']} | {s['output_cd_change_cleaned_mean']:+.2%}, "
                         f"{s['output_cd_change_cleaned_worst']:+.2%} | {s['output_cd_change_uncleaned_mean']:+.2%}, "
                         f"{s['output_cd_change_uncleaned_worst']:+.2%} | {s['output_nc_change_worst']:+.4f} | "
                         f"{s['output_slivers_max']:.1%} | {s['output_off_normal_above_mc']} | "
                         f"{s['snap_seconds_mean']:.2f} | {s['snap_time_ratio_max']:.1%} | "
                         f"{s['clean_snap_time_ratio_mean']:.1%}, {s['clean_snap_time_ratio_max']:.1%} |")
    lines += ["", "## Per shape", "",
              "| shape | grid | faces before -> after | off-normal % unclean / clean / MC | slivers % unclean / "
              "clean | CD unclean / clean | F1 unclean / clean | NC unclean / clean | clean s | fit s | "
              "watertight | rounds | output: off-normal % / CD / NC / s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['shape']} | {r['grid']} | failed: {r['error']} |" + " |" * 10)
            continue
        p = r["output"]
        lines.append(f"| {r['shape']}{' *' if r['open_input'] else ''} | {r['grid']} | {_before_after_cells(r)} | "
                     f"{r['fit_seconds']:.1f} | {r['cleaned']['watertight'] and p['watertight']} | "
                     f"{r['clean']['rounds']} | {p['off_normal_share']:.1%} / {p['chamfer_x1e5']:.3f} / {p['nc']:.3f} / "
                     f"{r['snap_seconds']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


def _before_after_cells(row) -> str:
    """The per-shape cells both tables share: faces, off-normal (with MC's), slivers, CD, F1, NC, clean s."""
    u, c, m = row["uncleaned"], row["cleaned"], row["mc"]
    return (f"{u['n_triangles']} -> {c['n_triangles']} | "
            f"{u['off_normal_share']:.1%} / {c['off_normal_share']:.1%} / {m['off_normal_share']:.1%} | "
            f"{u['sliver_share']:.1%} / {c['sliver_share']:.1%} | {u['chamfer_x1e5']:.3f} / {c['chamfer_x1e5']:.3f} | "
            f"{u['f1']:.3f} / {c['f1']:.3f} | {u['nc']:.3f} / {c['nc']:.3f} | {row['clean_seconds']:.2f}")


def _best_poisson(cloud, source):
    """Open3D's Poisson pipeline on the same cloud (``bench_pointcloud.best_poisson``), as a
    reference for what the input itself allows (noise, holes)."""
    from bench_pointcloud import best_poisson

    from voro3d.io import mesh_arrays

    return mesh_arrays(best_poisson(cloud, source)[1])


def write_cloud_tables(rows, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    load = Path("/proc/loadavg").read_text().split()[:3]
    meta = dict(machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores",
                date=time.strftime("%Y-%m-%d %H:%M"), load_average_after=load)
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, rows=rows), indent=2, default=float))
    ok = [r for r in rows if r["status"] == "ok"]
    lines = [f"# Cleaned point-cloud outputs ({meta['date']}, {meta['machine']}, load average after {' '.join(load)})",
             "", "Clouds made as `bench_pointcloud.py` makes them, reconstructed by "
             "`voro3d.pointcloud.reconstruct_points` (grid auto); metrics as in `clean_32_64.md`, against the "
             "mesh the cloud was sampled from; Marching Cubes of that mesh's SDF at the same grid, and Open3D's "
             "Poisson pipeline on the same cloud (as `bench_pointcloud.py` runs it, the better depth), for reference. "
             "*output*: what `voro3d.reconstruct` returns (`voro3d.pointcloud.cloud_mesh`: the cleaned surface fitted "
             "to the target surface, smoothed on noisy clouds; the target bilateral-filtered where the noise is "
             "heavy). *mc_target*: Marching Cubes of the cloud's own target surface "
             "(the smooth surface the VoroMesh is fitted to) at the same grid, which has the noise and the hole "
             "fills the cloud leaves and the true mesh does not.",
             "", "| surface | clouds | " + " | ".join(name for name, _, _ in METRICS) + " | watertight % |",
             "|---|---|" + "---|" * len(METRICS) + "---|"]
    for surface in CLOUD_SURFACES:
        if ok:
            cells = [fmt.format(np.mean([r[surface][key] for r in ok])) for _, key, fmt in METRICS]
            lines.append(f"| {surface} | {len(ok)} | " + " | ".join(cells) +
                         f" | {100 * np.mean([r[surface]['watertight'] for r in ok]):.0f} |")
    conditions = list(dict.fromkeys(r["condition"] for r in ok))
    lines += ["", "Off-normal share by condition, of the triangles / of the area:", "",
              "| condition | clouds | cleaned | output | MC of the true mesh | MC of the target | Poisson |",
              "|---|---|---|---|---|---|---|"]
    for condition in conditions:
        group = [r for r in ok if r["condition"] == condition]
        cells = [f"{np.mean([r[s]['off_normal_share'] for r in group]):.1%} / "
                 f"{np.mean([r[s]['off_normal_area_share'] for r in group]):.1%}" for s in ("cleaned", "output", "mc", "mc_target", "poisson")]
        lines.append(f"| {condition} | {len(group)} | " + " | ".join(cells) + " |")
    lines += ["", "| shape | condition | grid | faces before -> after | off-normal % unclean / clean / MC | "
              "slivers % unclean / clean | CD unclean / clean | F1 unclean / clean | NC unclean / clean | "
              "clean s | reconstruct s | watertight | distance max / bound (voxels) | output: off-normal % / CD / F1 / NC | "
              "output distance max / bound (voxels) | off-normal % MC of the target / Poisson |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['shape']} | {r['condition']} | | failed: {r['error']} |" + " |" * 12)
            continue
        o = r["output"]
        lines.append(
            f"| {r['shape']} | {r['condition']} | {r['grid']} | {_before_after_cells(r)} | "
            f"{r['reconstruct_seconds']:.1f} | {r['cleaned']['watertight']} | "
            f"{max(r['distance_to_uncleaned_max'], r['distance_from_uncleaned_max']):.3f} / {r['distance_bound']:.2f} | "
            f"{o['off_normal_share']:.1%}{' (snapped)' if r['snapped'] else ''} / {o['chamfer_x1e5']:.3f} / "
            f"{o['f1']:.3f} / {o['nc']:.3f} | {r['output_distance_max']:.3f} / {r['output_distance_bound']:.2f} | "
            f"{r['mc_target']['off_normal_share']:.1%} / {r['poisson']['off_normal_share']:.1%} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


def picture(rows, out_png: Path, folder: Path):
    """Input, uncleaned, cleaned and output side by side for the pictured shapes, one row each."""
    from figures import render_rows

    from voro3d.io import load_mesh

    figure = []
    for r in rows:
        if r["status"] != "ok" or r["shape"] not in PICTURED:
            continue
        stem = Path(r["shape"]).stem
        meshes = [load_mesh(folder / r["shape"])] + [
            load_mesh(CACHE / f"{stem}_{r['grid']}_{name}.ply", weld=False) for name in ("uncleaned", "cleaned", "output")]
        titles = [f"{stem} (input)",
                  f"VoroMesh {r['grid']}^3: {r['uncleaned']['n_triangles']} faces",
                  f"cleaned: {r['cleaned']['n_triangles']} faces", "output: cleaned, fitted to the input"]
        figure.append((meshes, titles))
    render_rows(figure, out_png, size=(420, 360))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DEV)
    parser.add_argument("--grids", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--names", nargs="+", default=None, help="only these files of the folder")
    parser.add_argument("--limit", type=int, default=None, help="first N meshes only")
    parser.add_argument("--refit", action="store_true", help="fit again instead of reading out/bench_clean/")
    parser.add_argument("--clouds", action="store_true", help="the point-cloud outputs instead of the meshes")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    from voro3d.io import MESH_SUFFIXES

    paths = sorted(p for p in args.folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if args.names:
        paths = [p for p in paths if p.name in args.names]
    paths = paths[: args.limit]
    if args.clouds:
        out = args.out or ROOT / "benchmarks" / "results" / "clean_clouds"
        rows = []
        for path in [p for p in paths if p.name in CLOUD_SHAPES]:
            for condition in CLOUD_CONDITIONS:
                rows.append(run_in_process(_one_cloud, str(path), condition))
                r = rows[-1]
                print(f"{path.name:28s} {condition:14s} " + (
                    f"faces {r['uncleaned']['n_triangles']} -> {r['cleaned']['n_triangles']} off "
                    f"{r['uncleaned']['off_normal_share']:.3f} -> {r['cleaned']['off_normal_share']:.3f} "
                    f"(MC {r['mc']['off_normal_share']:.3f}) wt {r['cleaned']['watertight']}"
                    if r["status"] == "ok" else f"FAILED {r['error']}"), flush=True)
                write_cloud_tables(rows, out)
        return
    out = args.out or ROOT / "benchmarks" / "results" / f"clean_{'_'.join(map(str, args.grids))}"
    rows = []
    for grid in args.grids:
        for path in paths:
            row = run_in_process(_one, str(path), grid, args.refit)
            rows.append(row)
            if row["status"] == "ok":
                u, c, m = row["uncleaned"], row["cleaned"], row["mc"]
                print(f"{grid:4d} {path.name:28s} faces {u['n_triangles']:6d} -> {c['n_triangles']:6d} "
                      f"off {u['off_normal_share']:.3f} -> {c['off_normal_share']:.3f} (MC {m['off_normal_share']:.3f}) "
                      f"slivers {u['sliver_share']:.3f} -> {c['sliver_share']:.3f} CD {u['chamfer_x1e5']:.3f} -> "
                      f"{c['chamfer_x1e5']:.3f} F1 {u['f1']:.3f} -> {c['f1']:.3f} NC {u['nc']:.3f} -> {c['nc']:.3f} "
                      f"wt {c['watertight']} {row['clean_seconds']:.2f}s/{row['fit_seconds']:.1f}s", flush=True)
            else:
                print(f"{grid:4d} {path.name:28s} FAILED {row['error']}", flush=True)
            write_tables(rows, args.grids, out)
    picture(rows, out.with_suffix(".png"), args.folder)


if __name__ == "__main__":
    main()
