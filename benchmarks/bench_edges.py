"""Sharp edges kept: edge F-score of CAD dev meshes reconstructed from dense oriented points, against Poisson.

What the VoroMesh gives that Poisson cannot: its faces are planes between generators, so a crease
between two of them stays a crease. Each CAD dev mesh (``abc_*``, ``cad_*``) is sampled into
``--points`` area-uniform points with their true normals; ``voro3d.reconstruct`` (grid "auto") and
Open3D's screened Poisson at depths 8 and 9 reconstruct the same oriented points.

Edge samples as in the NDC evaluation (Chen et al. 2022): of 100k area-uniform samples of a mesh
(NDC frame, diagonal 1), those with a sample within ``EDGE_RADIUS`` whose face normal differs by
more than ``EDGE_ANGLE`` degrees. The edge F-score is that of the two edge sample sets at
``EDGE_THRESHOLD`` (precision: share of the reconstruction's edge samples within it of a true one;
recall the other way). Also CD x1e5, NC and faces.

Writes ``benchmarks/results/edges.{md,json}``.

    python benchmarks/bench_edges.py [--shapes ...] [--points 200000]
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import dev_parser, dev_shapes

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results" / "edges"
EDGE_RADIUS = 0.004
EDGE_ANGLE = 78.0
EDGE_THRESHOLD = 0.005
EDGE_SAMPLES = 100_000


def edge_samples(mesh, frame) -> np.ndarray:
    """The (e, 3) edge samples of ``mesh`` in ``frame`` (see the module docstring)."""
    from scipy.spatial import cKDTree

    from voro3d.io import mesh_arrays
    from voro3d.sampling import sample_surface

    vertices, triangles = mesh_arrays(mesh)
    points, normals = sample_surface((frame.apply(vertices), triangles), EDGE_SAMPLES, seed=7)
    distance, neighbour = cKDTree(points).query(points, k=16, distance_upper_bound=EDGE_RADIUS, workers=-1)
    # A missing neighbour (beyond the radius) is the sample itself, which turns by nothing.
    neighbour = np.where(np.isfinite(distance), neighbour, np.arange(len(points))[:, None])
    turn = np.einsum("ij,ikj->ik", normals, normals[neighbour])
    return points[(turn < np.cos(np.radians(EDGE_ANGLE))).any(axis=1)]


def edge_fscore(found: np.ndarray, truth: np.ndarray) -> dict:
    """Precision, recall and F-score of edge samples ``found`` against ``truth`` at ``EDGE_THRESHOLD``."""
    from scipy.spatial import cKDTree

    if len(found) == 0 or len(truth) == 0:
        return dict(edge_precision=0.0, edge_recall=0.0, edge_f=0.0, edge_samples=int(len(found)))
    precision = float(np.mean(cKDTree(truth).query(found, workers=-1)[0] < EDGE_THRESHOLD))
    recall = float(np.mean(cKDTree(found).query(truth, workers=-1)[0] < EDGE_THRESHOLD))
    f = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return dict(edge_precision=precision, edge_recall=recall, edge_f=f, edge_samples=int(len(found)))


def main() -> None:
    cad = sorted(p.name for p in DEV.iterdir() if p.name.startswith(("abc_", "cad_"))) if DEV.is_dir() else ["cad_fandisk.obj"]
    parser = dev_parser(__doc__, cad, OUT)
    parser.add_argument("--points", type=int, default=200_000)
    args = parser.parse_args()
    import open3d as o3d

    import voro3d
    from voro3d.frames import ndc_frame
    from voro3d.sampling import sample_surface

    rows = []
    for name in dev_shapes(args.shapes, DEV):
        mesh = voro3d.load_mesh(DEV / name)
        frame = ndc_frame(mesh)
        truth = edge_samples(mesh, frame)
        points, normals = sample_surface(mesh, args.points, seed=0)
        row = dict(shape=name, points=args.points, true_edge_samples=int(len(truth)))
        start = time.perf_counter()
        try:
            ours = voro3d.reconstruct(np.hstack([points, normals]))
            row["voromesh"] = dict(voro3d.evaluate(ours, mesh), seconds=time.perf_counter() - start,
                                   **edge_fscore(edge_samples(ours, frame), truth))
        except ValueError as error:
            row["voromesh"] = dict(error=str(error))
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.normals = o3d.utility.Vector3dVector(normals)
        for depth in (8, 9):
            start = time.perf_counter()
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
                poisson, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
            row[f"poisson{depth}"] = dict(voro3d.evaluate(poisson, mesh), seconds=time.perf_counter() - start,
                                          **edge_fscore(edge_samples(poisson, frame), truth))
        rows.append(row)
        print(json.dumps({k: (v if not isinstance(v, dict) else {m: v.get(m) for m in ("edge_f", "chamfer_x1e5", "n_triangles", "seconds", "error")}) for k, v in row.items()}), flush=True)
        write(args.out, rows)


def write(out: Path, rows) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), rows=rows), indent=1))
    methods = ("voromesh", "poisson8", "poisson9")
    label = dict(voromesh="VoroMesh", poisson8="Poisson d8", poisson9="Poisson d9")
    lines = [f"# Sharp edges kept ({time.strftime('%Y-%m-%d')})", "",
             f"CAD dev meshes sampled into {rows[0]['points']:,} points with their true normals (`python "
             "benchmarks/bench_edges.py`): `voro3d.reconstruct` (grid auto) and Open3D's screened Poisson on the "
             f"same oriented points. Edge F-score: edge samples (of {EDGE_SAMPLES:,}, NDC frame, a neighbour within "
             f"{EDGE_RADIUS} whose normal turns more than {EDGE_ANGLE:.0f} degrees) of the two meshes at "
             f"{EDGE_THRESHOLD}. CD x1e5.", "",
             "| shape | " + " | ".join(f"{label[m]} edge F" for m in methods) + " | " +
             " | ".join(f"{label[m]} CD" for m in methods) + " | " + " | ".join(f"{label[m]} faces" for m in methods) +
             " | VoroMesh s | Poisson d8 / d9 s |", "|---" * 11 + "|"]
    for r in rows:
        if "error" in r["voromesh"]:
            lines.append(f"| {r['shape']} | error: {r['voromesh']['error']} |" + " |" * 10)
            continue
        lines.append(f"| {r['shape']} | " + " | ".join(f"{r[m]['edge_f']:.3f}" for m in methods) + " | " +
                     " | ".join(f"{r[m]['chamfer_x1e5']:.3f}" for m in methods) + " | " +
                     " | ".join(f"{r[m]['n_triangles']:,}" for m in methods) +
                     f" | {r['voromesh']['seconds']:.1f} | {r['poisson8']['seconds']:.1f} / {r['poisson9']['seconds']:.1f} |")
    ok = [r for r in rows if "error" not in r["voromesh"]]
    if ok:
        mean = {m: float(np.mean([r[m]["edge_f"] for r in ok])) for m in methods}
        lines += ["", f"Mean edge F-score over {len(ok)} meshes: " +
                  ", ".join(f"{label[m]} {mean[m]:.3f}" for m in methods) + "; mean CD " +
                  ", ".join(f"{label[m]} {np.mean([r[m]['chamfer_x1e5'] for r in ok]):.3f}" for m in methods) + "."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
