"""Did a change move the point-cloud results? CD / NC / F1 of ``reconstruct`` on 4 dev meshes x 5 clouds.

Clouds per mesh (seeded, so every checkout sees the same points): 100k area-uniform samples with
their true normals, the same without normals, with Gaussian noise of 0.5% of the diagonal, with 2%
uniform outliers in the box, and a one-view range scan (``bench_pointcloud.range_scan``, 30k points).

``run`` scores whichever voro3d is imported (``PYTHONPATH`` picks a checkout) into a JSON file;
``table`` writes the markdown comparison of two such files (``benchmarks/results/cloud_regression.md``).

    PYTHONPATH=<before checkout> python benchmarks/bench_cloud_regression.py run before.json
    PYTHONPATH=<after checkout> python benchmarks/bench_cloud_regression.py run after.json [--cases noise]
    python benchmarks/bench_cloud_regression.py table before.json after.json [--note TEXT]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
MESHES = ["organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "abc_00000005.stl"]


def clouds(mesh) -> dict:
    """The five clouds of one mesh, drawn in a fixed order from one seeded generator."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_pointcloud import range_scan

    from voro3d.sampling import sample_surface

    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    points, normals = sample_surface(mesh, 100_000, seed=0)
    rng = np.random.default_rng(1)
    diagonal = np.linalg.norm(points.max(0) - points.min(0))
    return {"100k true normals": np.hstack([points, normals]), "100k no normals": points,
            "100k noise 0.5%": points + rng.normal(scale=0.005 * diagonal, size=points.shape),
            "100k + 2% outliers": np.vstack([points, rng.uniform(points.min(0), points.max(0), (2000, 3))]),
            "range scan 1 view": range_scan(vertices, triangles, 1, 30_000, rng)}


def run(out: Path, cases=None) -> None:
    """Score every cloud into ``out``; with ``cases`` (substrings of cloud labels) only those, their
    rows replacing the same rows of an existing ``out``."""
    import voro3d

    rows = []
    for name in MESHES:
        mesh = voro3d.load_mesh(DEV / name)
        for label, cloud in clouds(mesh).items():
            if cases and not any(case in label for case in cases):
                continue
            start = time.perf_counter()
            try:
                result = voro3d.reconstruct(cloud)
                scores = voro3d.evaluate(result, mesh)
                row = dict(mesh=name, case=label, cd=scores["chamfer_x1e5"], nc=scores["nc"], f1=scores["f1"],
                           faces=len(result.triangles))
            except ValueError as error:
                row = dict(mesh=name, case=label, error=str(error))
            row["seconds"] = round(time.perf_counter() - start, 1)
            rows.append(row)
            print(json.dumps(row), flush=True)
    if cases and out.exists():
        fresh = {(row["mesh"], row["case"]): row for row in rows}
        rows = [fresh.get((row["mesh"], row["case"]), row) for row in json.loads(out.read_text())["rows"]]
    out.write_text(json.dumps(dict(voro3d=voro3d.__file__, rows=rows), indent=1) + "\n")


def table(before: Path, after: Path, out: Path, note: str) -> None:
    old, new = (json.loads(path.read_text())["rows"] for path in (before, after))
    lines = ["# Point-cloud results before and after a change", "",
             "`benchmarks/bench_cloud_regression.py`: `reconstruct` (grid auto) on 4 dev meshes x 5 seeded clouds, "
             "CD x1e5 / NC / F1 against the mesh. Seconds are wall time on a shared machine (contended).", ""]
    lines += [note, ""] if note else []
    lines += ["| mesh | cloud | CD before | CD after | change | NC before | NC after | F1 before | F1 after | faces before "
              "| faces after | s before | s after |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for a, b in zip(old, new):
        if "error" in a or "error" in b:
            lines.append(f"| {a['mesh']} | {a['case']} | {a.get('error', '')} | {b.get('error', '')} | | | | | | | | | |")
            continue
        lines.append(f"| {a['mesh']} | {a['case']} | {a['cd']:.4f} | {b['cd']:.4f} | {100 * (b['cd'] / a['cd'] - 1):+.2f}% | "
                     f"{a['nc']:.4f} | {b['nc']:.4f} | {a['f1']:.3f} | {b['f1']:.3f} | {a['faces']:,} | {b['faces']:,} | "
                     f"{a['seconds']:.1f} | {b['seconds']:.1f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps(dict(before=old, after=new), indent=1) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    runner = sub.add_parser("run")
    runner.add_argument("out", type=Path)
    runner.add_argument("--cases", nargs="+", help="only clouds whose label holds one of these, updating OUT's rows")
    compare = sub.add_parser("table")
    compare.add_argument("before", type=Path)
    compare.add_argument("after", type=Path)
    compare.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cloud_regression")
    compare.add_argument("--note", default="")
    args = parser.parse_args()
    if args.command == "run":
        run(args.out, args.cases)
    else:
        table(args.before, args.after, args.out, args.note)


if __name__ == "__main__":
    main()
