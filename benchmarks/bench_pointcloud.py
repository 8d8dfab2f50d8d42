"""Point clouds in, watertight meshes out: VoroMesh from a cloud vs the fit that had the mesh,
vs Open3D's screened Poisson reconstruction; then robustness to noise and drop-out.

Every dev mesh (default ``../shared/data/dev``, else the bundled examples) is sampled into a
cloud of ``--points`` area-uniform points, *without normals*: the methods get the points only.
VoroMesh estimates normals itself (on its averaged support cloud, timed with it); Poisson gets
normals estimated and oriented on all the points by the same code
(:func:`voro3d.reconstruction.estimate_normals`), their time added to Poisson's.

* Main table at ``--grid``: VoroMesh from the cloud (``voro3d.reconstruct``), VoroMesh fitted to
  the mesh itself (``voro3d.fit``, same grid and seed), and Poisson at the octree depth (6-9)
  whose vertex count is nearest VoroMesh's. CD x1e5, F1, NC against the mesh (NDC frame, 100k
  points), watertight % (closed, manifold, oriented, no self-intersection), seconds.
* Robustness table at ``--noise-grid``: clean cloud, Gaussian noise of 0.5% and 1% of the
  bounding-box diagonal (per coordinate), and 50% of the points dropped at random; each without
  and with ``denoise=True``.
* Speed of the point-cloud parts at 10^5 points: normal estimation + orientation, point areas,
  and the winding number at 10^5 query points.

Writes ``benchmarks/results/pointcloud.{md,json,png}``. The two parts can run in two processes
(``--part main``, ``--part noise --reverse --out OTHER``) and be joined with ``--merge``.

    python benchmarks/bench_pointcloud.py [--grid 64] [--noise-grid 32] [--points 100000] [--limit N]
    python benchmarks/bench_pointcloud.py --merge A.json B.json [--out OUT]
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
RESULTS = ROOT / "benchmarks" / "results"
CONDITIONS = (("clean", 0.0, 1.0), ("noise 0.5%", 0.005, 1.0), ("noise 1%", 0.01, 1.0), ("drop-out 50%", 0.0, 0.5))
PICTURED = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj")


def sample_cloud(mesh, n_points, *, noise=0.0, keep=1.0, seed=0):
    """``n_points`` area-uniform surface points, Gaussian noise of ``noise`` times the bounding-box
    diagonal per coordinate, then a random ``keep`` share of them."""
    from voro3d.io import mesh_arrays
    from voro3d.sampling import sample_surface

    vertices, triangles = mesh_arrays(mesh)
    points, _ = sample_surface((vertices, triangles), n_points, seed=seed)
    rng = np.random.default_rng(seed + 1)
    diagonal = np.linalg.norm(vertices.max(0) - vertices.min(0))
    points = points + rng.normal(scale=noise * diagonal, size=points.shape)
    if keep < 1.0:
        points = points[rng.random(points.shape[0]) < keep]
    return points


def _score(mesh, source):
    from voro3d.metrics import evaluate
    from voro3d.watertight import check_watertight

    row = evaluate(mesh, source)
    report = check_watertight(mesh, self_intersection=len(mesh.triangles) < 400_000)
    row.update(watertight=bool(report.watertight), self_intersecting_pairs=int(report.self_intersecting_pairs))
    return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in row.items()}


def _voromesh_cloud(points, grid, denoise=False):
    from voro3d import reconstruct

    start = time.perf_counter()
    mesh = reconstruct(points, grid, denoise=denoise)
    return mesh, time.perf_counter() - start


def _poisson(points, normals, target_vertices, normals_seconds):
    """Screened Poisson at the depth whose vertex count is nearest ``target_vertices``."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    tried = {}

    def run(depth):
        start = time.perf_counter()
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
        tried[depth] = (mesh, time.perf_counter() - start)
        return abs(len(mesh.vertices) - target_vertices)

    depth = 7
    gap = run(depth)
    step = 1 if len(tried[depth][0].vertices) < target_vertices else -1
    while 6 <= depth + step <= 9:
        next_gap = run(depth + step)
        if next_gap >= gap:
            break
        depth, gap = depth + step, next_gap
    mesh, seconds = tried[depth]
    return mesh, normals_seconds + seconds, depth


def main_row(path, grid, n_points, picture_dir, fitted=None):
    from voro3d import fit
    from voro3d.io import load_mesh, save_mesh
    from voro3d.reconstruction import estimate_normals

    source = load_mesh(path)
    row = dict(shape=path.name, grid=grid)
    points = sample_cloud(source, n_points)
    start = time.perf_counter()
    try:
        normals = estimate_normals(points)
    except ValueError as error:
        return dict(row, status="failed", error=f"normals: {error}")
    normals_seconds = time.perf_counter() - start
    row["normals_seconds"] = normals_seconds
    meshes = {}
    try:
        meshes["cloud"], seconds = _voromesh_cloud(points, grid)
        row["cloud"] = dict(_score(meshes["cloud"], source), seconds=seconds)
    except (ValueError, RuntimeError) as error:
        row["cloud"] = dict(error=f"{type(error).__name__}: {error}", watertight=False)
    if fitted and path.name in fitted:  # the same fit (same code, grid and seed) already scored
        row["mesh"] = dict(fitted[path.name], reused=True)
    else:
        try:
            start = time.perf_counter()
            meshes["mesh"] = fit(source, grid, progress=False).to_open3d()
            row["mesh"] = dict(_score(meshes["mesh"], source), seconds=time.perf_counter() - start)
        except ValueError as error:  # an open input mesh has no inside: only the cloud methods run
            row["mesh"] = dict(error=str(error))
    target = len(meshes["cloud"].vertices) if "cloud" in meshes else 30_000
    meshes["poisson"], seconds, depth = _poisson(points, normals, target, normals_seconds)
    row["poisson"] = dict(_score(meshes["poisson"], source), seconds=seconds, depth=depth)
    if path.name in PICTURED:
        for name, mesh in meshes.items():
            save_mesh(mesh, picture_dir / f"{path.stem}_{name}.ply")
    return dict(row, status="ok")


def noise_rows(path, grid, n_points, denoise_options=(False, True)):
    from voro3d.io import load_mesh

    source = load_mesh(path)
    rows = []
    for name, noise, keep in CONDITIONS:
        points = sample_cloud(source, n_points, noise=noise, keep=keep)
        for denoise in denoise_options:
            row = dict(shape=path.name, grid=grid, condition=name, denoise=denoise)
            try:
                mesh, seconds = _voromesh_cloud(points, grid, denoise)
                row.update(status="ok", seconds=seconds, **_score(mesh, source))
            except (ValueError, RuntimeError) as error:
                row.update(status="failed", error=f"{type(error).__name__}: {error}", watertight=False)
            rows.append(row)
    return rows


def speed(path, n_points=100_000, n_queries=100_000):
    """Seconds of the point-cloud steps at 10^5 points (median of 3)."""
    from voro3d.io import fit_frame, load_mesh
    from voro3d.reconstruction import estimate_normals
    from voro3d.sampling import point_areas, point_winding_number

    source = load_mesh(path)
    points = fit_frame(source).apply(sample_cloud(source, n_points))
    queries = np.random.default_rng(0).uniform(-1, 1, (n_queries, 3))

    def median(call):
        times = []
        for _ in range(3):
            start = time.perf_counter()
            value = call()
            times.append(time.perf_counter() - start)
        return value, float(np.median(times))

    normals, normals_s = median(lambda: estimate_normals(points))
    areas, areas_s = median(lambda: point_areas(points))
    _, winding_s = median(lambda: point_winding_number(points, normals, queries, areas=areas))
    return dict(shape=path.name, points=n_points, queries=n_queries, normals_seconds=normals_s,
                areas_seconds=areas_s, winding_seconds=winding_s)


def _mean(rows, method, key):
    values = [r[method][key] for r in rows if key in r.get(method, {})]
    return float(np.mean(values)) if values else float("nan")


def write(out: Path, meta, main, noise, timing):
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, main=main, noise=noise, speed=timing), indent=2))
    ok = [r for r in main if r["status"] == "ok"]
    both = [r for r in ok if "chamfer_x1e5" in r["cloud"] and "chamfer_x1e5" in r["mesh"]]
    lines = [f"# Point clouds -> watertight meshes ({meta['date']}, {meta['machine']}, load average "
             f"{meta['load_before']} before, {meta['load_after']} after)", "",
             f"Clouds of {meta['points']} area-uniform points sampled from each dev mesh, without normals: VoroMesh "
             "estimates its own (time included); Poisson gets normals estimated and oriented on all points by "
             "`voro3d.reconstruction.estimate_normals` (time included). CD x1e5, F1 at 0.003, "
             "NC against the mesh in its NDC frame (100k points each); watertight = closed, manifold, oriented, "
             "positive volume, no self-intersection. Poisson: untrimmed, octree depth 6-9 chosen per shape for the "
             "vertex count nearest VoroMesh-cloud's.", "",
             f"## VoroMesh from the cloud vs from the mesh vs Poisson, {meta['grid']}^3", "",
             "| method | shapes | CD x1e5 | F1 | NC | watertight % | mean s | mean vertices |", "|---|---|---|---|---|---|---|---|"]
    for method, label in (("cloud", "VoroMesh, cloud"), ("mesh", "VoroMesh, mesh (fit)"), ("poisson", "Poisson")):
        rows = both if method == "mesh" else ok
        attempted = [r for r in rows if method in r and (method != "mesh" or "error" not in r["mesh"])]
        watertight = 100.0 * np.mean([r[method].get("watertight", False) for r in attempted]) if attempted else float("nan")
        lines.append(f"| {label} | {len(attempted)} | {_mean(rows, method, 'chamfer_x1e5'):.3f} | "
                     f"{_mean(rows, method, 'f1'):.3f} | {_mean(rows, method, 'nc'):.3f} | {watertight:.0f} | "
                     f"{_mean(rows, method, 'seconds'):.2f} | {_mean(rows, method, 'n_vertices'):.0f} |")
    if both:
        ratio = _mean(both, "cloud", "chamfer_x1e5") / _mean(both, "mesh", "chamfer_x1e5")
        lines += ["", f"On the {len(both)} shapes with a closed mesh: mean CD cloud / mean CD mesh = **{ratio:.2f}x** "
                      f"(VoroMesh-cloud {_mean(both, 'cloud', 'chamfer_x1e5'):.3f}, mesh fit "
                      f"{_mean(both, 'mesh', 'chamfer_x1e5'):.3f}); Poisson on the same shapes "
                      f"{_mean(both, 'poisson', 'chamfer_x1e5'):.3f}."]
    failed = [r for r in main if r["status"] != "ok"]
    if failed:
        lines += ["", "Failed: " + "; ".join(f"{r['shape']}: {r['error']}" for r in failed)]
    lines += ["", "## Robustness (VoroMesh from the cloud, normals estimated), "
                  f"{meta['noise_grid']}^3", "",
              "Noise: Gaussian per coordinate, sigma = share of the bounding-box diagonal. Drop-out: each point kept "
              "with probability 1/2. *denoise*: `reconstruct(..., denoise=True)`, points projected onto local planes "
              "about one grid step wide. Means over the shapes that produced a mesh; watertight % over all shapes.", "",
              "| condition | denoise | shapes | meshes | CD x1e5 | median CD | F1 | NC | watertight % | mean s |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for name, _, _ in CONDITIONS:
        for denoise in (False, True):
            rows = [r for r in noise if r["condition"] == name and r["denoise"] == denoise]
            good = [r for r in rows if r["status"] == "ok"]
            mean = {k: float(np.mean([r[k] for r in good])) if good else float("nan")
                    for k in ("chamfer_x1e5", "f1", "nc", "seconds")}
            median = float(np.median([r["chamfer_x1e5"] for r in good])) if good else float("nan")
            watertight = 100.0 * np.mean([r["watertight"] for r in rows]) if rows else float("nan")
            lines.append(f"| {name} | {'yes' if denoise else 'no'} | {len(rows)} | {len(good)} | "
                         f"{mean['chamfer_x1e5']:.3f} | {median:.3f} | {mean['f1']:.3f} | {mean['nc']:.3f} | "
                         f"{watertight:.0f} | {mean['seconds']:.2f} |")
    if timing:
        lines += ["", f"## Point-cloud steps at 10^5 points ({timing['shape']}, median of 3)", "",
                  "| step | seconds |", "|---|---|",
                  f"| normal estimation (Open3D PCA, k=16) + orientation (MST, scipy) | {timing['normals_seconds']:.2f} |",
                  f"| point areas (k-th neighbour discs) | {timing['areas_seconds']:.3f} |",
                  f"| generalized winding number, {timing['queries']} queries (libigl, Barnes-Hut) | "
                  f"{timing['winding_seconds']:.3f} |"]
    lines += ["", "## Per shape", "", "| shape | cloud CD | mesh CD | Poisson CD (depth) | cloud F1 | Poisson F1 | "
                  "cloud s | Poisson s | watertight cloud/Poisson |", "|---|---|---|---|---|---|---|---|---|"]
    for r in main:
        if r["status"] != "ok":
            lines.append(f"| {r['shape']} | failed: {r['error']} | | | | | | | |")
            continue
        c, m, p = r["cloud"], r["mesh"], r["poisson"]
        fmt = lambda d, k, f: format(d[k], f) if k in d else "-"  # noqa: E731
        lines.append(f"| {r['shape']} | {fmt(c, 'chamfer_x1e5', '.3f')} | {fmt(m, 'chamfer_x1e5', '.3f')} | "
                     f"{p['chamfer_x1e5']:.3f} ({p['depth']}) | {fmt(c, 'f1', '.3f')} | {p['f1']:.3f} | "
                     f"{fmt(c, 'seconds', '.1f')} | {p['seconds']:.1f} | {c.get('watertight')}/{p['watertight']} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def picture(picture_dir: Path, main, folder: Path, out_png: Path):
    """Input, VoroMesh from the cloud, Poisson: one row per pictured shape."""
    from figures import render_rows

    from voro3d.io import load_mesh

    rows = [r for r in main if r["shape"] in PICTURED and r["status"] == "ok"
            and (picture_dir / f"{Path(r['shape']).stem}_cloud.ply").exists()]
    figure = []
    for r in rows:
        stem = Path(r["shape"]).stem
        meshes = [load_mesh(folder / r["shape"]), load_mesh(picture_dir / f"{stem}_cloud.ply", weld=False),
                  load_mesh(picture_dir / f"{stem}_poisson.ply", weld=False)]
        titles = [f"{stem} (input)", f"VoroMesh from cloud {r['grid']}^3: CD {r['cloud']['chamfer_x1e5']:.2f}",
                  f"Poisson depth {r['poisson']['depth']}: CD {r['poisson']['chamfer_x1e5']:.2f}"]
        figure.append((meshes, titles))
    render_rows(figure, out_png)


def merge(sources, out: Path, folder: Path):
    """One table from the JSON results of runs over parts of the work; a later row replaces an
    earlier one of the same shape (and condition)."""
    runs = [json.loads(Path(source).read_text()) for source in sources]
    main_rows = {r["shape"]: r for run in runs for r in run["main"]}
    noise = {(r["shape"], r["condition"], r["denoise"]): r for run in runs for r in run["noise"]}
    meta = dict(runs[0]["meta"], load_after=runs[-1]["meta"].get("load_after", ""))
    timing = next((run["speed"] for run in runs if run["speed"]), None)
    main_rows = [main_rows[k] for k in sorted(main_rows)]
    noise = [noise[k] for k in sorted(noise)]
    write(out, meta, main_rows, noise, timing)
    picture(ROOT / "out" / "bench_pointcloud", main_rows, folder, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.md')}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DEV if DEV.is_dir() else None)
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--noise-grid", type=int, default=32)
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--limit", type=int, default=None, help="first N meshes only")
    parser.add_argument("--out", type=Path, default=RESULTS / "pointcloud")
    parser.add_argument("--part", choices=("all", "main", "noise"), default="all")
    parser.add_argument("--reverse", action="store_true", help="shapes in reverse order")
    parser.add_argument("--denoise", choices=("both", "off", "on"), default="both",
                        help="robustness rows without and/or with denoise=True")
    parser.add_argument("--merge", type=Path, nargs="+", help="join the rows of these JSON results instead of running")
    parser.add_argument("--mesh-fit-from", type=Path,
                        help="bench_fit.py JSON whose VoroMesh rows (same grid) stand for the mesh fit instead of "
                             "fitting again; the fit is deterministic, so only its seconds differ")
    args = parser.parse_args()
    import multiprocessing

    if args.merge:
        merge(args.merge, args.out, args.folder)
        return

    from voro3d.io import MESH_SUFFIXES

    if args.folder is None:
        import tempfile

        from voro3d.io import save_mesh
        from voro3d.shapes import example_mesh, example_names

        args.folder = Path(tempfile.mkdtemp())
        for name in example_names():
            save_mesh(example_mesh(name), args.folder / f"{name}.ply")
    paths = sorted(p for p in args.folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)[: args.limit]
    if args.reverse:
        paths.reverse()
    picture_dir = ROOT / "out" / "bench_pointcloud"
    picture_dir.mkdir(parents=True, exist_ok=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    load = lambda: " ".join(Path("/proc/loadavg").read_text().split()[:3])  # noqa: E731
    meta = dict(date=time.strftime("%Y-%m-%d %H:%M"), machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores",
                load_before=load(), points=args.points, grid=args.grid, noise_grid=args.noise_grid)
    timing = speed(next((p for p in paths if p.name == "organic_bunny.off"), paths[0]))
    print(json.dumps(timing), flush=True)
    fitted = None
    if args.mesh_fit_from:
        fitted = {r["shape"]: r["voromesh"] for r in json.loads(args.mesh_fit_from.read_text())["rows"]
                  if r["grid"] == args.grid and r["status"] == "ok"}
    main_rows, noise = [], []
    for path in paths if args.part in ("all", "main") else []:
        row = main_row(path, args.grid, args.points, picture_dir, fitted)
        main_rows.append(row)
        print(json.dumps({k: row.get(k) for k in ("shape", "status", "error")} |
                         {m: {k: row[m].get(k) for k in ("chamfer_x1e5", "f1", "watertight", "seconds", "error")}
                          for m in ("cloud", "mesh", "poisson") if m in row}), flush=True)
        meta["load_after"] = load()
        write(args.out, meta, main_rows, noise, timing)
    for path in paths if args.part in ("all", "noise") else []:
        rows = noise_rows(path, args.noise_grid, args.points,
                          {"both": (False, True), "off": (False,), "on": (True,)}[args.denoise])
        noise += rows
        print(json.dumps([{k: r.get(k) for k in ("shape", "condition", "denoise", "chamfer_x1e5", "watertight", "error")}
                          for r in rows]), flush=True)
        meta["load_after"] = load()
        write(args.out, meta, main_rows, noise, timing)
    picture(picture_dir, main_rows, args.folder, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
