"""VoroMesh direct fit vs Marching Cubes and Dual Contouring, with the paper's metrics.

For every mesh of a folder (default ``../shared/data/dev``, else the bundled examples) and
every grid: fit a VoroMesh and take its mesh as ``reconstruct`` returns it (cleaned, fitted to the
input: ``to_open3d(surface=input)``); build MC and DC from the same normalised SDF grid; score all
three against the input (CD x1e5, F1 at 0.003, NC, in the NDC frame of the input; faces, triangles
more than 30 degrees off the input's normal and slivers under 5 degrees,
:func:`voro3d.metrics.triangle_quality`) and check watertightness (with the exact self-intersection
test). The input is also scored against itself
(two independent 100k-point samplings): the CD that a perfect reconstruction would get, the floor
of this metric. An open input (boundary edges, no inside) is fitted with ``allow_open=True``
(inside by generalized winding number) and marked. Each shape runs in its own process so
its peak RSS is its own. Writes ``benchmarks/results/fit_<grids>.{md,json}`` and a PNG
comparing the three on a few shapes.

    python benchmarks/bench_fit.py [--grids 32 64] [--folder DIR] [--limit N] [--steps 400] [--boundary-steps 0]
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
METHODS = ("voromesh", "mc", "dc")


def _score(mesh, source, check_intersections=True):
    from voro3d.metrics import evaluate, triangle_quality
    from voro3d.watertight import check_watertight

    row = evaluate(mesh, source)
    row.update(triangle_quality(mesh, source))
    report = check_watertight(mesh, self_intersection=check_intersections)
    row.update(watertight=report.watertight, self_intersecting_pairs=report.self_intersecting_pairs)
    return row


def _one(path, grid, steps, picture_dir, queue, boundary_steps=0):
    import torch

    from voro3d.baselines import dual_contouring, marching_cubes
    from voro3d.fitting import fit
    from voro3d.frames import fit_frame
    from voro3d.io import load_mesh, mesh_arrays, save_mesh, to_triangle_mesh
    from voro3d.metrics import evaluate
    from voro3d.queries import sdf_grid
    from voro3d.topology import open_edge_count

    torch.set_num_threads(1)
    try:
        source = load_mesh(path)
        open_input = open_edge_count(*mesh_arrays(source)) > 0
        start = time.perf_counter()
        shape, info = fit(source, grid, steps=steps, allow_open=open_input, boundary_steps=boundary_steps)
        voromesh = shape.to_open3d(surface=source)
        seconds = {"voromesh": time.perf_counter() - start}
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        frame = fit_frame(source)
        framed = frame.apply_mesh(source)
        start = time.perf_counter()
        sdf = sdf_grid(framed, grid, allow_open=open_input)
        sdf_seconds = time.perf_counter() - start
        meshes = {"voromesh": voromesh}
        rows = {}
        for name, method in (("mc", lambda: marching_cubes(sdf)), ("dc", lambda: dual_contouring(sdf, framed))):
            start = time.perf_counter()
            try:
                vertices, triangles = method()
            except ValueError as error:  # e.g. a part thinner than a voxel: no sign change in the SDF
                rows[name] = dict(error=str(error), watertight=False)
                continue
            meshes[name] = to_triangle_mesh(frame.invert(vertices), triangles)
            seconds[name] = sdf_seconds + time.perf_counter() - start
        for name, mesh in meshes.items():
            rows[name] = _score(mesh, source, check_intersections=len(mesh.triangles) < 400_000)
            rows[name]["seconds"] = seconds[name]
        rows["voromesh"].update(peak_rss_mib=peak, generators=int(info.n_generators), final_loss=info.final_loss)
        if picture_dir is not None:
            for name, mesh in meshes.items():
                save_mesh(mesh, Path(picture_dir) / f"{Path(path).stem}_{grid}_{name}.ply")
        floor = evaluate(source, source)["chamfer_x1e5"]
        queue.put(dict(shape=Path(path).name, grid=grid, status="ok", open_input=bool(open_input), floor=floor,
                       **{m: rows[m] for m in METHODS}))
    except Exception as error:  # one bad shape is recorded, not fatal
        queue.put(dict(shape=Path(path).name, grid=grid, status="failed", error=f"{type(error).__name__}: {error}"))


def run_shape(path, grid, steps, picture_dir=None, boundary_steps=0):
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_one, args=(str(path), grid, steps, picture_dir, queue, boundary_steps))
    process.start()
    row = queue.get()
    process.join()
    return row


def _summary(rows, grid):
    """Means over the shapes where all three methods produced a mesh (the paper's protocol);
    watertight % over every shape that was fitted (a method that produced nothing is not
    watertight)."""
    fitted = [r for r in rows if r["grid"] == grid and r["status"] == "ok"]
    ok = [r for r in fitted if all("chamfer_x1e5" in r[m] for m in METHODS)]
    out = {"grid": grid, "shapes": len(ok), "fitted": len(fitted),
           "failed": len([r for r in rows if r["grid"] == grid]) - len(fitted)}
    for method in METHODS:
        for key in ("chamfer_x1e5", "f1", "nc", "seconds", "n_triangles", "off_normal_share", "sliver_share"):
            out[f"{method}_{key}"] = float(np.mean([r[method][key] for r in ok])) if ok else float("nan")
        out[f"{method}_watertight_pct"] = (100.0 * np.mean([r[method]["watertight"] for r in fitted])
                                          if fitted else float("nan"))
    out["voromesh_peak_rss_mib"] = float(max((r["voromesh"]["peak_rss_mib"] for r in ok), default=float("nan")))
    out["voromesh_seconds_max"] = float(max((r["voromesh"]["seconds"] for r in ok), default=float("nan")))
    out["cd_ratio_vs_mc"] = out["voromesh_chamfer_x1e5"] / out["mc_chamfer_x1e5"]
    out["floor_chamfer_x1e5"] = float(np.mean([r["floor"] for r in ok])) if ok else float("nan")
    out["floor_ratio_vs_mc"] = out["floor_chamfer_x1e5"] / out["mc_chamfer_x1e5"]
    return out


def write_tables(rows, grids, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else []
    meta = dict(machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores", date=time.strftime("%Y-%m-%d %H:%M"),
                load_average_after=load)
    summaries = [_summary(rows, g) for g in grids]
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, summary=summaries, rows=rows), indent=2, default=float))
    lines = [f"# Direct fit vs MC / DC ({meta['date']}, {meta['machine']}, load average after {' '.join(load)})", "",
             "Means over shapes; CD x1e5, F1 at 0.003 and NC in the NDC frame of the input (100k samples each); "
             "watertight = closed, manifold, oriented, positive volume, no exactly-confirmed crossing triangles. "
             "Faces, off-normal (triangles more than 30 degrees off the input's normal) and slivers (smallest "
             "angle under 5 degrees): `voro3d.metrics.triangle_quality`. "
             "VoroMesh: the mesh `reconstruct` returns (cleaned, fitted to the input); its seconds: whole fit "
             "(sampling, optimisation, occupancy, extraction, clean, fit to the input); MC/DC seconds: SDF grid "
             "+ meshing. *floor*: the input scored against itself (another 100k-point sampling), what a "
             "perfect reconstruction would score; *floor / MC* is the lowest CD ratio any method could reach.", "",
             "| grid | shapes | method | CD x1e5 | F1 | NC | faces | off-normal % | slivers % | watertight % | "
             "mean s | max s |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        for method in METHODS:
            top = f"{s[method + '_seconds']:.2f}" if method != "voromesh" else f"{s['voromesh_seconds']:.2f}"
            worst = f"{s['voromesh_seconds_max']:.1f}" if method == "voromesh" else ""
            lines.append(f"| {s['grid']} | {s['shapes']} | {method} | {s[method + '_chamfer_x1e5']:.3f} | "
                         f"{s[method + '_f1']:.3f} | {s[method + '_nc']:.3f} | {s[method + '_n_triangles']:.0f} | "
                         f"{s[method + '_off_normal_share']:.1%} | {s[method + '_sliver_share']:.1%} | "
                         f"{s[method + '_watertight_pct']:.0f} | "
                         f"{top} | {worst} |")
        lines.append(f"| {s['grid']} | {s['shapes']} | floor (input vs itself) | {s['floor_chamfer_x1e5']:.3f} |"
                     + " |" * 8)
        lines.append(f"| {s['grid']} | | VoroMesh CD / MC CD | {s['cd_ratio_vs_mc']:.3f} | | | | | | | peak RSS "
                     f"{s['voromesh_peak_rss_mib']:.0f} MiB | |")
        lines.append(f"| {s['grid']} | | floor / MC CD | {s['floor_ratio_vs_mc']:.3f} |" + " |" * 8)
    lines += ["", "## Per shape", "", "Shapes marked * are open inputs, fitted with `allow_open=True`.", "",
              "| shape | grid | floor | VoroMesh CD | MC CD | DC CD | VoroMesh F1 | VoroMesh NC | "
              "off-normal % V/MC | VoroMesh s | watertight V/MC/DC |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['shape']} | {r['grid']} | | failed: {r['error']} | | | | | | | |")
            continue
        v, m, d = r["voromesh"], r["mc"], r["dc"]
        cd = {k: f"{x['chamfer_x1e5']:.3f}" if "chamfer_x1e5" in x else "no mesh" for k, x in (("m", m), ("d", d))}
        name = r["shape"] + (" *" if r.get("open_input") else "")
        mc_off = f"{m['off_normal_share']:.1%}" if "off_normal_share" in m else "-"
        lines.append(f"| {name} | {r['grid']} | {r['floor']:.3f} | {v['chamfer_x1e5']:.3f} | {cd['m']} | "
                     f"{cd['d']} | {v['f1']:.3f} | {v['nc']:.3f} | {v['off_normal_share']:.1%}/{mc_off} | "
                     f"{v['seconds']:.1f} | {v['watertight']}/{m['watertight']}/{d['watertight']} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')}")


PICTURED = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "cad_rocker-arm.obj")


def picture(picture_dir: Path, rows, out_png: Path, count=3):
    """One row per shape (input, VoroMesh, MC, DC at one camera), rows stacked into one PNG."""
    from figures import render_rows

    from voro3d.io import load_mesh

    ok = [r for r in rows if r["status"] == "ok" and all("chamfer_x1e5" in r[m] for m in METHODS)]
    ok = sorted(ok, key=lambda r: (r["shape"] not in PICTURED, r["grid"]))[:count]
    figure = []
    for r in ok:
        stem = Path(r["shape"]).stem
        meshes = [load_mesh(Path(rows_folder(r)) / r["shape"])] + [
            load_mesh(picture_dir / f"{stem}_{r['grid']}_{m}.ply", weld=False) for m in METHODS]
        titles = [f"{stem} (input)"] + [f"{m} {r['grid']}^3: CD {r[m]['chamfer_x1e5']:.2f}" for m in METHODS]
        figure.append((meshes, titles))
    render_rows(figure, out_png)


def rows_folder(row) -> Path:
    return Path(row.get("folder", DEV))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DEV if DEV.is_dir() else None)
    parser.add_argument("--grids", type=int, nargs="+", default=[32, 64])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--boundary-steps", type=int, default=0, help="fit(boundary_steps=)")
    parser.add_argument("--limit", type=int, default=None, help="first N meshes only")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    from voro3d.io import MESH_SUFFIXES

    if args.folder is None:
        import tempfile

        from voro3d.io import save_mesh
        from voro3d.shapes import example_mesh, example_names

        args.folder = Path(tempfile.mkdtemp())
        for name in example_names():
            save_mesh(example_mesh(name), args.folder / f"{name}.ply")
    paths = sorted(p for p in args.folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)[: args.limit]
    out = args.out or ROOT / "benchmarks" / "results" / f"fit_{'_'.join(map(str, args.grids))}"
    picture_dir = ROOT / "out" / "bench_fit"
    picture_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for grid in args.grids:
        for path in paths:
            row = run_shape(path, grid, args.steps, picture_dir, args.boundary_steps)
            rows.append(row)
            if row["status"] == "ok":
                v, m = row["voromesh"], row["mc"]
                print(f"{grid:4d} {path.name:28s} V CD {v['chamfer_x1e5']:8.3f} F1 {v['f1']:.3f} NC {v['nc']:.3f} "
                      f"wt {v['watertight']} {v['seconds']:6.1f}s | MC CD {m.get('chamfer_x1e5', float('nan')):8.3f}",
                      flush=True)
            else:
                print(f"{grid:4d} {path.name:28s} FAILED {row['error']}", flush=True)
            write_tables(rows, args.grids, out)
    picture(picture_dir, rows, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
