"""Thin walls sampled on both sides: where `reconstruct` fails today, and why.

A cup or a lid scanned all round is sampled on both sides of walls a few point spacings thick.
For each such dev mesh and point count (area-uniform samples), this measures:

* ``reconstruct`` as users call it, without normals (grid "auto"), and with the true normals
  (``normals given``): CD x1e5, NC, F1 against the mesh, the target the plan chose;
* what breaks first: the wall's thickness in nearest-neighbour spacings, the normals' axes (the
  median angle of Open3D's 16-neighbour plane fits, which :func:`voro3d.pointcloud.estimate_normals`
  uses, to the true normals) and their signs after our orientation (share wrong);
* screened Poisson at depth 8 on the true normals: what the target could be.

Writes ``benchmarks/results/thin_walls.{md,json,png}`` (the picture: truth, without normals, with
the true normals, for the first shape at the middle count).

    python benchmarks/bench_thin_walls.py [--shapes abc_00000009.stl ...] [--points 5000 20000 100000]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import dev_shapes

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results" / "thin_walls"
SHAPES = ("abc_00000009.stl", "abc_00000007.stl")  # a cup and a lid: walls 3-4 spacings thick at 20k points


def wall_thickness(mesh, points, normals) -> np.ndarray:
    """(n,) distance from each sample through the solid to the surface behind it (ray along -normal)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    rays = np.hstack([points - 1e-6 * normals, -normals]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=list(SHAPES))
    parser.add_argument("--points", type=int, nargs="+", default=[5_000, 20_000, 100_000])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    import open3d as o3d
    from scipy.spatial import cKDTree

    import voro3d
    from voro3d.frames import fit_frame
    from voro3d.pointcloud import cloud_mesh, estimate_normals, reconstruct_points
    from figures import render_rows

    rows, picture = [], None
    for name in dev_shapes(args.shapes, DEV):
        mesh = voro3d.load_mesh(DEV / name)
        for count in args.points:
            points, normals = voro3d.sample_surface(mesh, count, seed=0)
            nearest = float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))
            thickness = wall_thickness(mesh, points, normals)
            framed = fit_frame(points).apply(points)
            plane_fits = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(framed))
            plane_fits.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(16))
            axis = np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", np.asarray(plane_fits.normals), normals)), 0, 1)))
            signs = float(np.mean(np.einsum("ij,ij->i", estimate_normals(framed), normals) < 0))
            row = dict(shape=name, points=count, thickness_spacings=float(np.median(thickness[np.isfinite(thickness)]) / nearest),
                       axis_degrees=float(np.median(axis)), wrong_signs=signs)
            meshes = {}
            for label, given in (("none", None), ("true", normals)):
                start = time.perf_counter()
                shape, target, info = reconstruct_points(points, given)
                meshes[label] = cloud_mesh(shape, target)
                scores = voro3d.evaluate(meshes[label], mesh)
                row[label] = dict(chamfer_x1e5=scores["chamfer_x1e5"], nc=scores["nc"], f1=scores["f1"], target=info.target,
                                  denoise=info.plan.denoise, grid=info.grid, seconds=time.perf_counter() - start)
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            cloud.normals = o3d.utility.Vector3dVector(normals)
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
                poisson, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=8)
            scores = voro3d.evaluate(poisson, mesh)
            row["poisson_true"] = dict(chamfer_x1e5=scores["chamfer_x1e5"], nc=scores["nc"], f1=scores["f1"])
            rows.append(row)
            print(json.dumps(row), flush=True)
            if picture is None and count == args.points[len(args.points) // 2]:
                picture = ([mesh, meshes["none"], meshes["true"]],
                           [f"{Path(name).stem}, {count:,} points", f"no normals: CD {row['none']['chamfer_x1e5']:.1f}",
                            f"true normals: CD {row['true']['chamfer_x1e5']:.1f}"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), rows=rows), indent=1))
    if picture:
        render_rows([picture], args.out.with_suffix(".png"))
    lines = [f"# Thin walls sampled on both sides ({time.strftime('%Y-%m-%d')}, grid auto)", "",
             "Area-uniform samples of thin-walled dev meshes. *wall*: median thickness through the solid in "
             "nearest-neighbour spacings; *axes*: median angle of 16-neighbour plane fits to the true normals; "
             "*signs wrong*: share after `estimate_normals`. `reconstruct_points` + `cloud_mesh` without normals "
             "and with the true normals (CD x1e5 / NC / F1, target, denoise); Poisson depth 8 on the true normals. "
             "`python benchmarks/bench_thin_walls.py`.", "",
             "| shape | points | wall | axes deg | signs wrong | no normals | target | true normals | target | Poisson d8, true normals |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [f"{r[k]['chamfer_x1e5']:.2f} / {r[k]['nc']:.3f} / {r[k]['f1']:.3f}" for k in ("none", "true", "poisson_true")]
        lines.append(f"| {r['shape']} | {r['points']:,} | {r['thickness_spacings']:.1f} | {r['axis_degrees']:.1f} | "
                     f"{r['wrong_signs']:.3f} | {cells[0]} | {r['none']['target']}, denoise {r['none']['denoise']} | "
                     f"{cells[1]} | {r['true']['target']}, denoise {r['true']['denoise']} | {cells[2]} |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
