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
the true normals, a row per shape at the middle count).

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


NEIGHBOURHOODS = (6, 8, 12, 16, 24, 32)
# The mixed rule of the last table: the 8-neighbour plane where the 16-neighbour one is this many times
# less flat (it straddles the two sides of a wall).
STRADDLE_RATIO = 3.0


def plane_fit_errors(points, normals) -> dict:
    """Median angle (degrees) of plane fits to the true ``normals`` and share over 30 degrees, per
    neighbourhood size (``NEIGHBOURHOODS``), and for the mixed rule (``"mixed"``): the 8-neighbour
    plane where the 16-neighbour plane's flatness (smallest covariance eigenvalue over their sum)
    is ``STRADDLE_RATIO`` times worse, else the 16-neighbour one."""
    from scipy.spatial import cKDTree

    _, neighbours = cKDTree(points).query(points, k=max(NEIGHBOURHOODS) + 1)
    fits, flatness = {}, {}
    for k in NEIGHBOURHOODS:
        local = points[neighbours[:, :k + 1]]
        local = local - local.mean(axis=1, keepdims=True)
        values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))
        fits[k], flatness[k] = vectors[:, :, 0], values[:, 0] / np.maximum(values.sum(axis=1), 1e-300)
    straddles = flatness[16] > STRADDLE_RATIO * np.maximum(flatness[8], 1e-300)
    fits["mixed"] = np.where(straddles[:, None], fits[8], fits[16])
    errors = {}
    for key, fit in fits.items():
        cosine = np.clip(np.abs(np.einsum("ij,ij->i", fit, normals)), 0.0, 1.0)
        errors[str(key)] = dict(median_degrees=float(np.degrees(np.arccos(np.median(cosine)))),
                                over_30=float(np.mean(cosine < np.cos(np.radians(30.0)))))
    return errors


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

    rows, pictures = [], []
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
                       axis_degrees=float(np.median(axis)), wrong_signs=signs, plane_fits=plane_fit_errors(points, normals))
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
            if count == args.points[len(args.points) // 2]:
                pictures.append(([mesh, meshes["none"], meshes["true"]],
                                 [f"{Path(name).stem}, {count:,} points",
                                  f"no normals ({row['none']['target']}): CD {row['none']['chamfer_x1e5']:.1f}",
                                  f"true normals ({row['true']['target']}): CD {row['true']['chamfer_x1e5']:.1f}"]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), rows=rows), indent=1))
    if pictures:
        render_rows(pictures, args.out.with_suffix(".png"))
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
    keys = [str(k) for k in NEIGHBOURHOODS] + ["mixed"]
    lines += ["", "Plane fits by neighbourhood size, median angle to the true normals in degrees / share over 30 "
              "degrees (*mixed*: the 8-neighbour plane where the 16-neighbour one is "
              f"{STRADDLE_RATIO:g} times less flat, else the 16-neighbour one; not what `estimate_normals` uses):", "",
              "| shape | points | " + " | ".join(f"{k} neighbours" if k != "mixed" else k for k in keys) + " |",
              "|---|---|" + "---|" * len(keys)]
    for r in rows:
        lines.append(f"| {r['shape']} | {r['points']:,} | " + " | ".join(
            f"{r['plane_fits'][k]['median_degrees']:.1f} / {r['plane_fits'][k]['over_30']:.2f}" for k in keys) + " |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
