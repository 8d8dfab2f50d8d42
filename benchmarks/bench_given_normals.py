"""Given normals are checked, not trusted: reconstruct on clouds whose normals come four ways.

Each dev mesh is sampled into 30k points (area-uniform) and reconstructed (grid "auto") with
no normals, the normals of a bare Open3D ``estimate_normals()`` (signs not made consistent, as
users often pass them), the true normals negated (consistent but inward, as
``orient_normals_consistent_tangent_plane`` can leave them), and the true normals. CD x1e5, NC,
F1 against the mesh, and where ``PointCloudInfo.normals`` says the normals came from.

Writes ``benchmarks/results/given_normals.{md,json}``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
SHAPES = ["organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "abc_00000005.stl", "thingi32_75655.obj",
          "organic_spot.obj", "cad_rocker-arm.obj", "organic_cow.obj", "organic_homer.obj", "thingi32_252119.obj",
          "organic_elephant.obj", "thingi32_75656.obj"]
VARIANTS = ("none", "estimate_normals()", "negated", "true")


def clouds(mesh, n: int):
    import open3d as o3d

    from voro3d.sampling import sample_surface

    points, normals = sample_surface(mesh, n, seed=0)
    bare = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    bare.estimate_normals()
    return points, dict(zip(VARIANTS, (None, np.asarray(bare.normals), -normals, normals)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="*", default=SHAPES)
    parser.add_argument("--points", type=int, default=30_000)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "given_normals")
    args = parser.parse_args()
    import voro3d
    from voro3d.pointcloud import cloud_mesh, reconstruct_points

    rows = []
    for name in args.shapes:
        mesh = voro3d.load_mesh(DEV / name)
        points, variants = clouds(mesh, args.points)
        for label, normals in variants.items():
            start = time.perf_counter()
            shape, target, info = reconstruct_points(points, normals)
            scores = voro3d.evaluate(cloud_mesh(shape, target), mesh)
            rows.append(dict(shape=name, normals=label, chamfer_x1e5=scores["chamfer_x1e5"], nc=scores["nc"],
                             f1=scores["f1"], source=info.normals, target=info.target,
                             seconds=time.perf_counter() - start))
            print(json.dumps(rows[-1]), flush=True)
    args.out.with_suffix(".json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), points=args.points,
                                                             rows=rows), indent=1))
    lines = [f"# Given normals ({time.strftime('%Y-%m-%d')}, {args.points} points, grid auto)", "",
             "CD x1e5 of `reconstruct_points` + `cloud_mesh` per way the normals came, and the ratio to the same cloud "
             "without normals; `source` is `PointCloudInfo.normals`.", "",
             "| shape | " + " | ".join(f"{v} CD (source)" for v in VARIANTS) + " | worst ratio to none |",
             "|---|" + "---|" * (len(VARIANTS) + 1)]
    for name in args.shapes:
        by = {r["normals"]: r for r in rows if r["shape"] == name}
        worst = max(by[v]["chamfer_x1e5"] / by["none"]["chamfer_x1e5"] for v in VARIANTS[1:])
        lines.append(f"| {name} | " + " | ".join(f"{by[v]['chamfer_x1e5']:.3f} ({by[v]['source']})" for v in VARIANTS)
                     + f" | {worst:.2f} |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
