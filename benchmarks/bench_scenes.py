"""Objects on a table, scanned from above: a scene as a range scanner gives it.

Each dev mesh stands, as stored (z up), on a plate ``PLATE_SPAN`` times its footprint and
``PLATE_THICKNESS`` of its diagonal thick, sunk ``SINK`` of its diagonal into it.
``bench_pointcloud.range_scan`` sees the scene from 1 or 3 viewpoints 30 degrees above the plate
(30k points, grazing hits dropped, depth noise along the ray): the undersides of the object and of
the plate are never seen, and the object stands on a surface seen from one side only. On each cloud:

* VoroMesh: ``reconstruct_points`` (no normals, ``--grid``) and ``cloud_mesh``;
* Open3D's Poisson pipeline as in ``bench_pointcloud`` (``best_poisson``; ``--no-poisson`` skips it).

CD x1e5, NC and F1 at 0.003 against the scene (object and plate, NDC frame), VoroMesh checked
closed with no crossing triangles, pieces counted. ``--shell-depth uniform`` holds every open
cloud's solid within ``SHELL_DEPTH`` of its points (the rule before ``surface.shell_depths``):
the ablation beside ``SHELL_DEPTH``. ``--hull on|off`` sets the plan's cut to the points' hull (default
``auto``, the plan's rule): the ablation beside ``HULL_MARGIN_NODES``.

Writes ``benchmarks/results/scenes.{md,json,png}`` (``--out``; the picture: each method on two
scenes, three views).

    python benchmarks/bench_scenes.py [--shapes ...] [--views 1 3] [--no-poisson] [--shell-depth uniform] [--hull on]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import SHARED, _mean, _pieces, add_hull_argument, best_poisson, dev_shapes, range_scan, set_hull_margin

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "scenes"
SHAPES = ("abc_00000005.stl", "abc_00000008.stl", "cad_fandisk.obj", "cad_rocker-arm.obj", "organic_armadillo.obj",
          "organic_bunny.off", "organic_cow.obj", "organic_elephant.obj", "organic_homer.obj", "organic_spot.obj",
          "thingi32_252119.obj", "thingi32_75655.obj")
PICTURED = ("organic_bunny.off", "cad_fandisk.obj")
POINTS = 30_000
PLATE_SPAN = 1.6
PLATE_THICKNESS = 0.03
SINK = 0.002


def table_scene(vertices, triangles):
    """``(vertices, triangles)`` of the object and a plate under it (two closed meshes that overlap by ``SINK``)."""
    import open3d as o3d

    low, high = vertices.min(0), vertices.max(0)
    diagonal = float(np.linalg.norm(high - low))
    half = 0.5 * PLATE_SPAN * (high - low)[:2].max()
    centre = 0.5 * (low + high)
    top = low[2] + SINK * diagonal
    plate = o3d.geometry.TriangleMesh.create_box(2 * half, 2 * half, PLATE_THICKNESS * diagonal)
    plate.translate([centre[0] - half, centre[1] - half, top - PLATE_THICKNESS * diagonal])
    return (np.vstack([vertices, np.asarray(plate.vertices)]),
            np.vstack([triangles, np.asarray(plate.triangles) + len(vertices)]))


def run(name, views, grid, *, with_poisson, picture_dir, hull="auto"):
    from voro3d.io import load_mesh, mesh_arrays, save_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, reconstruct_points
    from voro3d.reconstruction import _check_fit
    from voro3d.watertight import check_watertight

    scene = table_scene(*mesh_arrays(load_mesh(SHARED / "dev" / name)))
    points = range_scan(*scene, views, POINTS, np.random.default_rng(1))
    row = dict(shape=name, views=views, points=len(points))
    start = time.perf_counter()
    try:
        shape, target, info = reconstruct_points(points, grid=grid, plan={"hull": hull})
        mesh = cloud_mesh(shape, target)
        _check_fit(mesh, points, info.voxel, info.offset)
        seconds = time.perf_counter() - start
        report = check_watertight(mesh)
        row["voromesh"] = dict(evaluate(mesh, scene), seconds=seconds, target=info.target, level=info.level,
                               plan=str(info.plan), pieces=_pieces(mesh),
                               closed=bool(report.watertight and report.self_intersecting_pairs == 0))
        meshes = {"voromesh": mesh}
    except (ValueError, RuntimeError) as error:
        row["voromesh"] = dict(error=f"{type(error).__name__}: {error}", seconds=time.perf_counter() - start)
        meshes = {}
    if with_poisson:
        depth, mesh, scores, seconds, orientation = best_poisson(points, scene)
        row["poisson"] = dict(scores, seconds=seconds, depth=depth, pieces=_pieces(mesh), orientation=orientation)
        meshes["poisson"] = mesh
    if name in PICTURED:
        for method, mesh in meshes.items():
            save_mesh(mesh, picture_dir / f"{Path(name).stem}_{views}_{method}.ply")
    return row


def write(out: Path, meta, rows):
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, rows=rows), indent=1))
    methods = ["voromesh"] + (["poisson"] if any("poisson" in row for row in rows) else [])
    lines = [f"# Objects on a table, scanned from above ({meta['machine']}; {meta['date']}, load average "
             f"{meta['load_before']} before, {meta['load_after']} after)", "",
             f"Each of {len(meta['shapes'])} dev meshes on a plate {PLATE_SPAN}x its footprint, range-scanned "
             f"({POINTS:,} points) from 1 or 3 viewpoints 30 degrees above it; no normals, grid {meta['grid']}, shell "
             f"depth {meta['shell_depth']}, hull {meta.get('hull', 'auto')}. CD x1e5, NC, F1 at 0.003 against the "
             "scene (object and plate). Rerun: `python benchmarks/bench_scenes.py`.", "",
             "| views | clouds | " + " | ".join(f"{m} CD / NC / F1" for m in methods) + " | VoroMesh closed % | "
             "VoroMesh one piece % | " + " | ".join(f"{m} s" for m in methods) + " |",
             "|---" * (4 + 2 * len(methods)) + "|"]
    for views in meta["views"]:
        chosen = [row for row in rows if row["views"] == views]
        ok = [row for row in chosen if "error" not in row["voromesh"]]
        scores = " | ".join(" / ".join(f"{_mean(ok, m, k):.{p}f}" for k, p in (("chamfer_x1e5", 1), ("nc", 3), ("f1", 3)))
                            for m in methods)
        closed = 100.0 * sum(row["voromesh"].get("closed", False) for row in chosen) / len(chosen)
        one = 100.0 * sum(row["voromesh"].get("pieces") == 1 for row in chosen) / len(chosen)
        seconds = " | ".join(f"{_mean(chosen, m, 'seconds'):.1f}" for m in methods)
        lines.append(f"| {views} | {len(ok)} of {len(chosen)} | {scores} | {closed:.0f} | {one:.0f} | {seconds} |")
    lines += ["", "| shape | views | " + " | ".join(f"{m} CD / NC / F1" for m in methods) + " | target | s |",
              "|---" * (4 + len(methods)) + "|"]
    for row in rows:
        v = row["voromesh"]
        cells = []
        for m in methods:
            r = row.get(m, {})
            cells.append(r["error"] if "error" in r else " / ".join(f"{r[k]:.{p}f}" for k, p in
                                                                  (("chamfer_x1e5", 2), ("nc", 3), ("f1", 3))))
        lines.append(f"| {row['shape']} | {row['views']} | " + " | ".join(cells) +
                     f" | {v.get('target', '-')} | {v['seconds']:.1f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def picture(picture_dir: Path, out: Path, meta):
    """One row per pictured shape (each row at its own scale): each method from each viewpoint count."""
    import matplotlib.pyplot as plt

    from voro3d.io import load_mesh
    from voro3d.render import render_meshes

    rows = []
    for name in PICTURED:
        panels, titles = [], []
        for views in meta["views"]:
            for method in ("voromesh", "poisson"):
                path = picture_dir / f"{Path(name).stem}_{views}_{method}.ply"
                if path.exists():
                    panels.append(load_mesh(path))
                    titles.append(f"{Path(name).stem}, {views} view{'s' * (views > 1)}: {method}")
        if panels:
            row = picture_dir / f"{Path(name).stem}_row.png"
            render_meshes(panels, row, titles=titles, size=(360, 320), view=(-60.0, 35.0))
            rows.append(plt.imread(row))
    if rows:
        width = max(image.shape[1] for image in rows)
        padded = [np.pad(image, ((0, 0), (0, width - image.shape[1]), (0, 0)), constant_values=1.0) for image in rows]
        plt.imsave(out.with_suffix(".png"), np.vstack(padded))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=list(SHAPES))
    parser.add_argument("--views", nargs="+", type=int, default=[1, 3])
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--no-poisson", action="store_true")
    parser.add_argument("--shell-depth", choices=("local", "uniform"), default="local")
    parser.add_argument("--hull", choices=("auto", "on", "off"), default="auto")
    add_hull_argument(parser)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    import multiprocessing

    import voro3d.pointcloud.targets as targets_module

    if args.shell_depth == "uniform":
        targets_module.shell_depths = lambda points, normals, most, least: most
    set_hull_margin(args)
    shapes = dev_shapes(args.shapes)
    picture_dir = ROOT / "out" / "bench_scenes"
    picture_dir.mkdir(parents=True, exist_ok=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    load = lambda: " ".join(Path("/proc/loadavg").read_text().split()[:3])  # noqa: E731
    meta = dict(date=time.strftime("%Y-%m-%d %H:%M"), machine=f"x86_64, {multiprocessing.cpu_count()} cores",
                load_before=load(), grid=args.grid, shell_depth=args.shell_depth, hull=args.hull, shapes=shapes,
                hull_margin="default" if args.hull_margin is None else args.hull_margin,
                views=args.views)
    rows = []
    for views in args.views:
        for name in shapes:
            rows.append(run(name, views, args.grid, with_poisson=not args.no_poisson, picture_dir=picture_dir,
                            hull=args.hull))
            print(json.dumps(rows[-1]), flush=True)
    meta["load_after"] = load()
    write(args.out, meta, rows)
    picture(picture_dir, args.out, meta)
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
