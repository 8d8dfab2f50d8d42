"""Extraction time and peak memory for generator sets like those a fit produces.

Generators are the 8 corner nodes of every voxel holding a surface sample (the fit's initial
generators), for a sphere, a torus and dev meshes normalised into [-1, 1]^3, at grids 32, 64,
128; occupancy is given (inside test at each generator). Two variants per case:

* ``lattice``: the nodes exactly, the worst case: every predicate is degenerate.
* ``fit-like``: each node moved by a seeded uniform offset of up to 0.25 voxel per axis, as the
  optimisation moves them (the case extraction meets after a fit).

Each case runs in a fresh process so that its peak RSS (ru_maxrss) is its own. Writes
``benchmarks/results/extract.{md,json}``.

    python benchmarks/bench_extract.py [--grids 32 64 128] [--repeats 3] [--dev-meshes N]
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
DEFAULT_DEV = ["organic_bunny.off", "cad_fandisk.obj", "thingi32_44234.obj"]
PAPER_CGAL_SECONDS = {32: 0.03, 64: 0.11, 128: 0.46}


def _shape(name):
    import open3d as o3d

    from voro3d.frames import fit_frame

    from voro3d.io import load_mesh

    if name == "sphere":
        mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=120)
    elif name == "torus":
        mesh = o3d.geometry.TriangleMesh.create_torus(torus_radius=1.0, tube_radius=0.4, radial_resolution=160,
                                                      tubular_resolution=80)
    else:
        mesh = load_mesh(DEV / name)
    return fit_frame(mesh).apply_mesh(mesh)


def _prepare(name, grid, variant, path, queue):
    from voro3d.generators import initial_generators
    from voro3d.queries import InsideOutside
    from voro3d.sampling import sample_surface

    mesh = _shape(name)
    samples, _ = sample_surface(mesh, 150 * grid * grid, seed=0)
    generators = initial_generators(samples, grid)
    if variant == "fit-like":
        voxel = 2.0 / (grid - 1)
        generators = generators + np.random.default_rng(0).uniform(-0.25, 0.25, generators.shape) * voxel
    np.savez(path, generators=generators, occupancy=InsideOutside(mesh).occupancy(generators))
    queue.put(None)


def _extract(path, repeats, queue):
    """Runs in a fresh process holding only the inputs, so its peak RSS is extraction's."""
    from voro3d.extract import extract_mesh

    with np.load(path) as data:
        generators, occupancy = data["generators"], data["occupancy"]
    # The extraction alone: clean=False (benchmarks/bench_clean.py times the clean).
    extract_mesh(generators[:64], np.arange(64) % 2 == 0)  # load the compiled module and Open3D
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = extract_mesh(generators, occupancy)
        seconds.append(time.perf_counter() - start)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    queue.put(dict(generators=int(len(generators)), triangles=int(len(out.triangles)),
                   seconds=statistics.median(seconds), peak_rss_mib=peak / 1024, extra_rss_mib=(peak - before) / 1024))


def _in_process(target, *args):
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=target, args=(*args, queue))
    process.start()
    result = queue.get()
    process.join()
    return result


def run_case(name, grid, variant, repeats):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "case.npz"
        _in_process(_prepare, name, grid, variant, path)
        return dict(shape=name, grid=grid, variant=variant, **_in_process(_extract, path, repeats))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dev-meshes", nargs="*", default=DEFAULT_DEV)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "extract")
    args = parser.parse_args()
    shapes = ["sphere", "torus"] + ([m for m in args.dev_meshes if (DEV / m).is_file()] if DEV.is_dir() else [])
    rows = []
    for grid in args.grids:
        for name in shapes:
            for variant in ("fit-like", "lattice"):
                row = run_case(name, grid, variant, args.repeats if grid < 128 else 1)
                rows.append(row)
                print(f"{name:22s} {grid:4d} {variant:9s} {row['generators']:7d} gens "
                      f"{row['seconds']:7.3f} s  +{row['extra_rss_mib']:.0f} MiB", flush=True)
    write_tables(rows, args.out)


def write_tables(rows, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores", python=platform.python_version(),
                date=time.strftime("%Y-%m-%d"), paper_cgal_seconds=PAPER_CGAL_SECONDS)
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, rows=rows), indent=2))
    lines = [f"# Extraction benchmark ({meta['date']}, {meta['machine']})", "",
             "Median seconds of `extract_mesh` (occupancy given); peak RSS of the process and its growth "
             "during extraction. Paper (CGAL): 0.03 / 0.11 / 0.46 s at 32 / 64 / 128.", "",
             "| shape | grid | variant | generators | triangles | seconds | paper x2 bar | peak RSS MiB | extra MiB |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        bar = 2 * PAPER_CGAL_SECONDS.get(r["grid"], float("nan"))
        verdict = "ok" if r["seconds"] <= bar else "over"
        lines.append(f"| {r['shape']} | {r['grid']} | {r['variant']} | {r['generators']} | {r['triangles']} | "
                     f"{r['seconds']:.3f} | {bar:.2f} ({verdict}) | {r['peak_rss_mib']:.0f} | {r['extra_rss_mib']:.0f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.md')} and .json")


if __name__ == "__main__":
    main()
