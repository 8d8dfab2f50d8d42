"""The exact winding number: ``voro3d.queries.winding_number`` (NumPy) against libigl's ``igl.winding_number``.

Two checks. Correctness where the exact path is needed: an open hemisphere (the upper half of
Open3D's sphere, radius 0.5, resolution 40) has winding number 0.5 at the centre of its opening;
each implementation is called ``--repeats`` times with that point first among n - 1 random
others. Speed: a dev mesh in the fit frame, 20,000 uniform queries in ``[-1, 1]^3``, best of
``--repeats``. Writes ``benchmarks/results/winding.{md,json}``.

    python benchmarks/bench_winding.py [--mesh organic_bunny.off] [--repeats 5]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DEV = Path(os.environ.get("VORO3D_DEV_DATA") or ROOT.parent / "shared" / "data" / "dev")
QUERY_COUNTS = (1, 2, 10, 100, 1000, 20000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default="organic_bunny.off", help="dev mesh of the speed test")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    import igl
    import open3d as o3d

    from voro3d import queries, rowblocks
    from voro3d.frames import fit_frame
    from voro3d.io import load_mesh, mesh_arrays

    implementations = {"numpy": queries.winding_number, "igl": igl.winding_number}
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=40)
    vertices, triangles = mesh_arrays(sphere)
    upper = triangles[(vertices[triangles][:, :, 2] > -1e-9).all(axis=1)]
    rng = np.random.default_rng(0)
    centre = []
    for n in QUERY_COUNTS:
        points = np.vstack([np.zeros((1, 3)), rng.uniform(-1, 1, (n - 1, 3))])
        values = {name: [float(f(vertices, upper, points)[0]) for _ in range(args.repeats)]
                  for name, f in implementations.items()}
        centre.append({"queries": n, **values})
        print(f"hemisphere centre, {n} queries: " + "; ".join(f"{k} {np.round(v, 6).tolist()}" for k, v in values.items()),
              flush=True)

    mesh = load_mesh(DEV / args.mesh)
    vertices, triangles = mesh_arrays(fit_frame(mesh).apply_mesh(mesh))
    points = rng.uniform(-1, 1, (20000, 3))
    speed, results = {}, {}
    for name, function in implementations.items():
        best = float("inf")
        for _ in range(args.repeats):
            start = time.perf_counter()
            results[name] = function(vertices, triangles, points)
            best = min(best, time.perf_counter() - start)
        speed[name] = best
        print(f"{args.mesh} ({triangles.shape[0]} triangles, 20000 queries) {name}: {best:.3f} s", flush=True)
    difference = float(np.abs(results["numpy"] - results["igl"]).max())
    result = {"libigl": version("libigl"), "numpy_threads": rowblocks.ROW_THREADS,
              "machine": f"{platform.machine()}, {os.cpu_count()} cores", "load_average": os.getloadavg(),
              "hemisphere_centre": centre, "mesh": args.mesh, "triangles": int(triangles.shape[0]), "queries": 20000,
              "seconds": speed, "max_difference": difference}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "winding.json").write_text(json.dumps(result, indent=1) + "\n")
    (RESULTS / "winding.md").write_text(_markdown(result, args.repeats))


def _markdown(result: dict, repeats: int) -> str:
    lines = ["# Exact winding number: NumPy (voro3d.queries) vs libigl", "",
             f"libigl {result['libigl']}; {result['machine']}, NumPy on {result['numpy_threads']} threads; "
             f"load average {result['load_average'][0]:.2f}. `benchmarks/bench_winding.py`.", "",
             f"Open hemisphere, value at the centre of its opening (exact: 0.5), {repeats} calls each:", "",
             "| queries | numpy | igl |", "|---|---|---|"]
    lines += [f"| {row['queries']} | {', '.join(f'{v:.6f}' for v in row['numpy'])} | "
              f"{', '.join(f'{v:.6f}' for v in row['igl'])} |" for row in result["hemisphere_centre"]]
    lines += ["", f"{result['mesh']} ({result['triangles']} triangles), {result['queries']} queries, best of {repeats}: "
              f"numpy {result['seconds']['numpy']:.3f} s, igl {result['seconds']['igl']:.3f} s; "
              f"largest difference {result['max_difference']:.1e}.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
