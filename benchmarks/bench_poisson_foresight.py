"""Can a cloud's winding number foresee that its Poisson target will be refused, and spare the solve?

A closed cloud's target is screened Poisson, refused when its surface runs over
``MAX_POISSON_ESCAPE`` diagonals out of the points' box (``PoissonSurface.escape``); a refused
solve is time spent for nothing (depth 8, 1-2.5 s at 30k points). Far from the points Poisson's
indicator follows the points' generalized winding number, which takes milliseconds. For every
cloud whose auto plan solves Poisson this records, with the points and normals the solve gets,
the winding number's largest value over the faces of the points' box pushed out by 0.04, 0.08,
0.12 and 0.2 diagonals (24 x 24 probes a face), its mean at 5,000 of the points (Poisson's
iso-value is its indicator's mean there), then the solve's escape; the rest of the pipeline is
skipped. A foresight is useful only if some threshold skips refused solves without skipping a
kept one.

    python benchmarks/bench_poisson_foresight.py    # all 38 dev meshes x 6 conditions, about 10 minutes

Writes ``benchmarks/results/poisson_foresight.{md,json}``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench_pointcloud import SHARED, make_cloud

ROOT = Path(__file__).resolve().parents[1]
CONDITIONS = ("range scan 3 views", "range scan 6 views", "misaligned range scan 3 views", "third missing", "clean 5k",
              "noise 1%")
OFFSETS = (0.04, 0.08, 0.12, 0.2)


class _Solved(Exception):
    """Raised once the Poisson solve is measured: the fit after it is not needed."""


def box_probes(points, offset: float, per_side: int = 24) -> np.ndarray:
    """(6 per_side^2, 3) points on the faces of the points' bounding box grown by ``offset`` diagonals."""
    low, high = points.min(axis=0), points.max(axis=0)
    grow = offset * np.linalg.norm(high - low)
    low, high = low - grow, high + grow
    u, v = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, per_side), np.linspace(0, 1, per_side), indexing="ij"))
    faces = []
    for axis in range(3):
        first, second = (i for i in range(3) if i != axis)
        for side in (low[axis], high[axis]):
            face = np.empty((u.size, 3))
            face[:, axis] = side
            face[:, first] = low[first] + u * (high[first] - low[first])
            face[:, second] = low[second] + v * (high[second] - low[second])
            faces.append(face)
    return np.vstack(faces)


def measure(points, normals, depth, record: dict, solve, **options):
    """In place of ``poisson_surface``: the foresight's figures into ``record``, then the solve's escape."""
    from voro3d.queries import point_areas, point_winding_number

    start = time.perf_counter()
    at_points = points[np.random.default_rng(0).permutation(len(points))[:5000]]
    queries = [at_points] + [box_probes(points, offset) for offset in OFFSETS]
    winding = np.split(point_winding_number(points, normals, np.vstack(queries), areas=point_areas(points)),
                       np.cumsum([len(q) for q in queries])[:-1])
    record.update(iso=float(winding[0].mean()), box_max=[float(w.max()) for w in winding[1:]],
                  foresight_s=time.perf_counter() - start)
    start = time.perf_counter()
    surface = solve(points, normals, depth, **options)
    record.update(solve_s=time.perf_counter() - start, escape=surface.escape(points))
    raise _Solved


def write(out: Path, rows: list) -> None:
    from voro3d.pointcloud.tuning import MAX_POISSON_ESCAPE

    refused = np.array([r["escape"] > MAX_POISSON_ESCAPE for r in rows])
    lines = [f"# Foreseeing a refused Poisson target from the winding number ({time.strftime('%Y-%m-%d %H:%M')}, "
             f"{len(rows)} Poisson solves)", "",
             f"Clouds of {len({r['shape'] for r in rows})} dev meshes whose auto plan solves Poisson ({', '.join(CONDITIONS)}; "
             f"grid 64, no normals); refused: escape over {MAX_POISSON_ESCAPE} diagonals. Per offset of the probe box "
             "and score (the winding number's largest value on it, raw or less its mean at the points): the "
             "highest score of a kept solve, and the refused solves above it, which a threshold there would spare "
             "without refusing a kept one.", "",
             f"Refused {int(refused.sum())} of {len(rows)}; seconds solving: refused "
             f"{sum(r['solve_s'] for r, f in zip(rows, refused) if f):.1f} of {sum(r['solve_s'] for r in rows):.1f}; "
             f"the foresight {sum(r['foresight_s'] for r in rows):.1f} s in all.", "",
             "| probe box out (diagonals) | score | highest kept | refused above it | refused range |",
             "|---|---|---|---|---|"]
    for k, offset in enumerate(OFFSETS):
        raw = np.array([r["box_max"][k] for r in rows])
        for label, score in (("max", raw), ("max - mean at points", raw - np.array([r["iso"] for r in rows]))):
            top = score[~refused].max() if (~refused).any() else -np.inf
            lines.append(f"| {offset} | {label} | {top:.3f} | {int(np.sum(score[refused] > top))} of {int(refused.sum())} "
                         f"| {score[refused].min():.2f} to {score[refused].max():.2f} |" if refused.any() else
                         f"| {offset} | {label} | {top:.3f} | 0 of 0 | - |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), rows=rows), indent=1))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="*", help="dev mesh file names (default: all)")
    parser.add_argument("--conditions", nargs="*", default=list(CONDITIONS))
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "poisson_foresight")
    args = parser.parse_args()
    import voro3d.pointcloud.targets as targets
    from voro3d.io import load_mesh
    from voro3d.pointcloud import reconstruct_points

    folder = SHARED / "dev"
    names = args.shapes or sorted(p.name for p in folder.iterdir() if p.name != "README.md")
    solve, rows = targets.poisson_surface, []
    try:
        for condition in args.conditions:
            for name in names:
                record = dict(shape=name, condition=condition)
                targets.poisson_surface = lambda *a, **k: measure(*a, record=record, solve=solve, **k)
                try:
                    reconstruct_points(make_cloud(load_mesh(folder / name), condition), grid=64, progress=False)
                except _Solved:
                    rows.append(record)
                    print(json.dumps(record), flush=True)
                except ValueError:
                    pass  # refused before its target: no solve to foresee
    finally:
        targets.poisson_surface = solve
    write(args.out, rows)
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
