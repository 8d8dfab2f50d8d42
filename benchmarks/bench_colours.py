"""Colours carried from a cloud onto the mesh: voro3d (split flat for colour, and not) against Open3D's Poisson.

Each dev mesh is sampled into a clean ``--points``-point cloud (no normals, as a user's scan) and
coloured two ways: RGB from the position in the box (smooth), and RGB = |true normal| (varies as
fast as the surface turns, the colouring issue 24 was filed with). For each colouring:

* ``voro3d``: ``voro3d.reconstruct(cloud)`` with the colours, as a user calls it (the mesh split flat
  until it has about one vertex per point, :func:`voro3d.pointcloud.colored_mesh`);
* ``voro3d, no split``: the same with ``MAX_COLOUR_SPLITS = 0`` (the colours of the unsplit mesh's
  vertices: what ``reconstruct`` gave before);
* ``poisson``: ``bench_pointcloud.poisson`` (outlier removal, normals, tangent-plane orientation,
  screened Poisson depth 7 and 8 with the colours; the depth of lower CD).

The error is the mean |RGB| difference (0-1, averaged over channels) at 20k ground-truth samples,
read two ways: the colour of the nearest mesh vertex (``bench_pointcloud``'s), and the colour
interpolated barycentrically at the closest point of the mesh (what a renderer shows). Methods of
one shape run back to back. Writes ``benchmarks/results/colours.md`` and ``colours.json``.

    python benchmarks/bench_colours.py [--shapes organic_bunny.off ...] [--points 20000]
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import dev_parser, dev_shapes, poisson, position_colours

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"
SHAPES = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "abc_00000005.stl",
          "thingi32_44234.obj", "organic_cow.obj")
METHODS = ("voro3d", "voro3d, no split", "poisson")


def _true_normals(points: np.ndarray, source) -> np.ndarray:
    """(n, 3) unit normal of the source triangle closest to each point."""
    import open3d as o3d

    from voro3d.io import mesh_arrays

    vertices, triangles = mesh_arrays(source)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices.astype(np.float32), triangles.astype(np.uint32))
    hit = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    corners = vertices[triangles[hit["primitive_ids"].numpy().astype(np.int64)]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)


def _errors(mesh, truth: np.ndarray, expected: np.ndarray) -> tuple[float, float]:
    """Mean |RGB error| at ``truth``: nearest vertex's colour, and the colour interpolated at the closest point."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    vertices = np.asarray(mesh.vertices)
    triangles = np.asarray(mesh.triangles)
    colours = np.asarray(mesh.vertex_colors)
    _, nearest = cKDTree(vertices).query(truth, workers=-1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices.astype(np.float32), triangles.astype(np.uint32))
    hit = scene.compute_closest_points(o3d.core.Tensor(truth.astype(np.float32)))
    face = triangles[hit["primitive_ids"].numpy().astype(np.int64)]
    uv = hit["primitive_uvs"].numpy().astype(np.float64)
    weights = np.column_stack([1.0 - uv.sum(axis=1), uv])
    interpolated = np.einsum("nk,nkc->nc", weights, colours[face])
    return (float(np.abs(colours[nearest] - expected).mean()), float(np.abs(interpolated - expected).mean()))


def run_shape(name: str, n_points: int) -> list:
    import open3d as o3d

    import voro3d
    import voro3d.pointcloud.colors as colour_module
    from voro3d.io import load_mesh, mesh_arrays
    from voro3d.metrics import evaluate

    source = load_mesh(DEV / name)
    points, _ = voro3d.sample_surface(source, n_points, seed=0)
    truth, truth_normals = voro3d.sample_surface(source, 20_000, seed=5)
    vertices, _ = mesh_arrays(source)
    low, high = vertices.min(0), vertices.max(0)
    colourings = {"position": (position_colours(points, low, high), position_colours(truth, low, high)),
                  "|normal|": (np.abs(_true_normals(points, source)), np.abs(truth_normals))}
    rows = []
    for colouring, (colours, expected) in colourings.items():
        for method in METHODS:
            start = time.perf_counter()
            if method == "poisson":
                meshes, _ = poisson(points, colours)
                mesh = min((m for m, _ in meshes.values()), key=lambda m: evaluate(m, source)["chamfer_x1e5"])
            else:
                cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
                cloud.colors = o3d.utility.Vector3dVector(colours)
                saved = colour_module.MAX_COLOUR_SPLITS
                colour_module.MAX_COLOUR_SPLITS = 0 if method.endswith("no split") else saved
                try:
                    mesh = voro3d.reconstruct(cloud, grid=64)
                finally:
                    colour_module.MAX_COLOUR_SPLITS = saved
            seconds = time.perf_counter() - start
            nearest, interpolated = _errors(mesh, truth, expected)
            rows.append(dict(shape=name, colouring=colouring, method=method, faces=len(mesh.triangles),
                             seconds=seconds, nearest_vertex=nearest, interpolated=interpolated,
                             cd=evaluate(mesh, source)["chamfer_x1e5"]))
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = dev_parser(__doc__, SHAPES, OUT)
    parser.add_argument("--points", type=int, default=20_000)
    args = parser.parse_args()
    shapes = dev_shapes(args.shapes, DEV)
    sys.path.insert(0, str(ROOT))
    rows = [row for name in shapes for row in run_shape(name, args.points)]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "colours.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), cpus=os.cpu_count(),
                                                           points=args.points, rows=rows), indent=1))
    lines = [f"# Colours: voro3d against Poisson ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs)", "",
             f"Clean {args.points:,}-point clouds of {len(shapes)} dev meshes without normals, coloured by position "
             "(smooth) or by |true normal| (fast); mean |RGB error| at 20k ground-truth samples, from the nearest "
             "vertex and interpolated at the closest surface point; voro3d at grid 64 "
             "(`python benchmarks/bench_colours.py`).", "",
             "| colouring | method | nearest-vertex error | interpolated error | faces | CD | seconds |",
             "|---|---|---|---|---|---|---|"]
    for colouring in ("position", "|normal|"):
        for method in METHODS:
            chosen = [r for r in rows if r["colouring"] == colouring and r["method"] == method]
            mean = {key: float(np.mean([r[key] for r in chosen])) for key in
                    ("nearest_vertex", "interpolated", "faces", "cd", "seconds")}
            lines.append(f"| {colouring} | {method} | {mean['nearest_vertex']:.4f} | {mean['interpolated']:.4f} | "
                         f"{mean['faces']:,.0f} | {mean['cd']:.3f} | {mean['seconds']:.1f} |")
    lines += ["", "Per shape:", "", "| shape | colouring | method | nearest | interpolated | faces |",
              "|---|---|---|---|---|---|"]
    lines += [f"| {r['shape']} | {r['colouring']} | {r['method']} | {r['nearest_vertex']:.4f} | {r['interpolated']:.4f} | "
              f"{r['faces']:,} |" for r in rows]
    (args.out / "colours.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
