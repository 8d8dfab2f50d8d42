"""Ten million oriented points: ``voro3d.reconstruct`` in tiles, local pool against Ray, and Open3D's Poisson.

One dev mesh is sampled area-uniformly into ``--points`` points with their true (face) normals
(:func:`voro3d.sampling.sample_surface`, seed 0) and written once; every method then runs in a
process of its own on the same file:

* ``voro3d-local``: ``voro3d.reconstruct(cloud, engine="local", workers=W)``: planned on a million
  points, fitted in tiles by a pool of ``W`` spawned processes;
* ``voro3d-ray``: the same with ``engine="ray"`` (a local Ray started by ``ray.init`` in the process,
  ``W`` CPUs);
* ``poisson9``, ``poisson10``: ``TriangleMesh.create_from_point_cloud_poisson(cloud, depth=d)``.

Peak memory is that of the whole process tree (the child, its pool workers, Ray's processes):
the parent sums the resident memory (RSS) of the child and all its descendants every
``--interval`` seconds and keeps the highest sum (``bench_large.run_child``). Each output is scored against the mesh
(:func:`voro3d.evaluate`), checked exactly (closed, manifold, no crossing triangles:
:func:`voro3d.watertight.check_watertight`) and its pieces counted; the two voro3d meshes are
compared vertex for vertex; ``tiles.png`` shows voro3d's mesh beside Poisson depth 9's. Methods run one after another on an otherwise idle machine; the load
average before each is recorded. Writes ``benchmarks/results/tiles.md``, ``tiles.json`` and ``tiles.png``.

``--seams``: instead, the ablation behind ``SEAM_WIDTH`` / ``SEAM_STEPS`` (``pointcloud/tuning.py``):
400k exact samples of the mesh, a 63^3 band over 2 levels, fitted whole and in 4 and 8 tiles
(:func:`voro3d.pointcloud.tiles.fit_tiles`), with and without the seam pass, seeds 0 and 1, the
cells labelled by the mesh itself and scored (``tiles_seams.md``, ``.json``).

    python benchmarks/bench_tiles.py [--mesh organic_bunny.off] [--points 10000000] [--workers 2]
        [--methods voro3d-local voro3d-ray poisson9 poisson10]
    python benchmarks/bench_tiles.py --seams [--mesh organic_bunny.off]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_large import run_child

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"

CHILD = r"""
import json, sys, time
import numpy as np, open3d as o3d
method, cloud_path, out_path, workers = sys.argv[1:5]
data = np.load(cloud_path)
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(data[:, :3]))
cloud.normals = o3d.utility.Vector3dVector(data[:, 3:])
del data
start = time.perf_counter()
if method.startswith("voro3d"):
    import voro3d
    mesh = voro3d.reconstruct(cloud, engine=method.split("-")[1], workers=int(workers), progress=True)
else:
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=int(method[len("poisson"):]))
seconds = time.perf_counter() - start
o3d.io.write_triangle_mesh(out_path, mesh)
print(json.dumps(dict(seconds=seconds, faces=len(mesh.triangles))))
"""


def _run(method: str, cloud: Path, out: Path, workers: int, interval: float) -> dict:
    load = os.getloadavg()[0]
    result, stderr, peak = run_child([CHILD, method, str(cloud), str(out), str(workers)], interval)
    phases = [line for line in stderr.replace("\r", "\n").splitlines() if line.startswith("voro3d ") and "%|" not in line]
    return dict(result, peak_gb=peak, load_before=load, phases=phases)


def _score(path: Path, reference) -> dict:
    import open3d as o3d

    from voro3d import evaluate
    from voro3d.watertight import check_watertight

    mesh = o3d.io.read_triangle_mesh(str(path))
    scores = evaluate(mesh, reference)
    row = dict(cd=scores["chamfer_x1e5"], f1=scores["f1"], nc=scores["nc"])
    report = check_watertight(mesh)
    pieces = np.asarray(mesh.cluster_connected_triangles()[0])
    row.update(watertight=report.watertight, crossing_pairs=report.self_intersecting_pairs,
               pieces=int(len(np.unique(pieces))))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default="organic_bunny.off")
    parser.add_argument("--points", type=int, default=10_000_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", nargs="+", default=["voro3d-local", "voro3d-ray", "poisson9", "poisson10"])
    parser.add_argument("--interval", type=float, default=0.5)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--seams", action="store_true", help="the seam pass's ablation instead")
    args = parser.parse_args()
    if not (DEV / args.mesh).exists():
        raise SystemExit(f"no dev mesh {DEV / args.mesh}")
    sys.path.insert(0, str(ROOT))
    if args.seams:
        seams(args.mesh, args.out)
        return
    import open3d as o3d

    from voro3d.io import load_mesh
    from voro3d.sampling import sample_surface

    reference = load_mesh(DEV / args.mesh)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        cloud = Path(folder) / "cloud.npy"
        np.save(cloud, np.hstack(sample_surface(reference, args.points, seed=0)))
        for method in args.methods:
            out = Path(folder) / f"{method}.ply"
            row = dict(mesh=args.mesh, points=args.points, method=method, workers=args.workers)
            row.update(_run(method, cloud, out, args.workers, args.interval))
            row.update(_score(out, reference))
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "phases"}), flush=True)
        same = None
        if {"voro3d-local", "voro3d-ray"} <= set(args.methods):
            meshes = [o3d.io.read_triangle_mesh(str(Path(folder) / f"{m}.ply")) for m in ("voro3d-local", "voro3d-ray")]
            arrays = [(np.asarray(m.vertices), np.asarray(m.triangles)) for m in meshes]
            same = bool(arrays[0][0].shape == arrays[1][0].shape and np.array_equal(arrays[0][0], arrays[1][0])
                        and np.array_equal(arrays[0][1], arrays[1][1]))
        _picture(Path(folder), rows, args.out / "tiles.png")
    args.out.mkdir(parents=True, exist_ok=True)
    result = dict(date=time.strftime("%Y-%m-%d %H:%M"), cpus=os.cpu_count(), rows=rows, local_equals_ray=same)
    (args.out / "tiles.json").write_text(json.dumps(result, indent=1))
    (args.out / "tiles.md").write_text(_table(result))


def seams(name: str, out: Path) -> None:
    """Whole fit against 4 and 8 tiles with and without the seam pass: CD, NC, F1 (module docstring)."""
    from voro3d.fitting import fit_schedule, labelled_voromesh, refresh_reach
    from voro3d.frames import fit_frame
    from voro3d.generators import AdaptiveBand
    from voro3d.io import load_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud.tiles import fit_tiles, split_tiles
    from voro3d.queries import InsideOutside
    from voro3d.sampling import sample_surface

    mesh = load_mesh(DEV / name)
    points, _ = sample_surface(mesh, 400_000, seed=1)
    frame = fit_frame(points)
    samples = frame.apply(points)
    grid, levels = 63, 1
    generators = AdaptiveBand(samples, grid, levels=levels, tolerance=0.05).generators()
    reach = refresh_reach(generators, grid)
    coarsest = 2.0 / (grid - 1) * 2**levels
    inside = InsideOutside(mesh)
    rows = []
    for label, max_samples, seam in (("whole", 10**9, 0.0), ("4 tiles, no seam pass", 100_000, 0.0),
                                     ("4 tiles, seam pass", 100_000, coarsest), ("8 tiles, no seam pass", 50_000, 0.0),
                                     ("8 tiles, seam pass", 50_000, coarsest)):
        for seed in (0, 1):
            tiles = split_tiles(samples, generators, max_samples=max_samples, margin=2 * coarsest)
            fitted = fit_tiles(samples, generators, grid, reach=reach, tiles=tiles, seam=seam, workers=1,
                               options=fit_schedule(steps=200, seed=seed))
            shape = labelled_voromesh(fitted, lambda q: inside.occupancy(frame.invert(q)), grid, frame=frame)
            scores = evaluate(shape.to_open3d(clean=False), mesh)
            rows.append(dict(run=label, tiles=len(tiles), seed=seed, cd=scores["chamfer_x1e5"], nc=scores["nc"],
                             f1=scores["f1"]))
            print(rows[-1], flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "tiles_seams.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), mesh=name, rows=rows),
                                                     indent=1))
    lines = ["# Tiles: the seam pass", "", f"400k exact samples of `{name}`, a 63^3 adaptive band over 2 levels, "
             "200 steps, the cells labelled by the mesh, the Voronoi surface uncleaned; tiles with a margin of 2 "
             "coarsest voxels; the seam pass refits the generators within 1 coarsest voxel of a cut for 100 steps "
             "with their neighbours held (`python benchmarks/bench_tiles.py --seams`).", "",
             "| run | tiles | seed | CD x1e5 | NC | F1 |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['run']} | {r['tiles']} | {r['seed']} | {r['cd']:.4f} | {r['nc']:.4f} | {r['f1']:.4f} |" for r in rows]
    (out / "tiles_seams.md").write_text("\n".join(lines) + "\n")


def _picture(folder: Path, rows: list, path: Path) -> None:
    """The meshes side by side, each titled with its method and faces."""
    from voro3d.io import load_mesh
    from voro3d.render.pictures import render_meshes

    shown = [row for row in rows if row["method"] in ("voro3d-local", "poisson9")]
    if shown:
        path.parent.mkdir(parents=True, exist_ok=True)
        render_meshes([load_mesh(folder / f"{row['method']}.ply", weld=False) for row in shown], path,
                      titles=[f"{row['method']}: {row['faces']:,} faces, CD {row['cd']:.3f}" for row in shown],
                      size=(560, 440), view="front", up="y")


def _table(result: dict) -> str:
    rows = result["rows"]
    lines = ["# Tens of millions of points: tiles, local pool and Ray", "",
             f"{rows[0]['points']:,} area-uniform samples of `{rows[0]['mesh']}` with their true normals, each method "
             "in a process of its own, one after another, on this machine "
             f"({result['cpus']} CPUs; {result['date']}; `benchmarks/bench_tiles.py`). Peak = highest resident memory "
             "of the process and all its descendants (pool workers, Ray), sampled every 0.5 s. Closed and crossings: "
             "`check_watertight`, exact.", "",
             "| method | seconds | peak GB | faces | CD x1e5 | NC | F1 | watertight | crossing pairs | pieces | load before |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['method']} | {row['seconds']:.1f} | {row['peak_gb']:.2f} | {row['faces']:,} | "
                     f"{row['cd']:.3f} | {row['nc']:.4f} | {row['f1']:.3f} | {row['watertight']} | "
                     f"{row['crossing_pairs']} | {row['pieces']} | {row['load_before']:.1f} |")
    if result["local_equals_ray"] is not None:
        lines += ["", f"voro3d-local and voro3d-ray meshes identical (vertices and triangles): "
                      f"**{result['local_equals_ray']}**."]
    for row in rows:
        if row["phases"]:
            lines += ["", f"`{row['method']}` phases:", "", "```", *row["phases"], "```"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
