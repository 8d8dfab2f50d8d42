"""The plan's rules, each on and off (an ablation): what the "auto" choices of a CloudPlan are worth.

Each dev mesh is sampled into clouds without normals under some of ``bench_pointcloud``'s
conditions and reconstructed with the plan all ``"auto"``. Then, per cloud, each rule of
:mod:`voro3d.pointcloud.plan` is turned the other way, by setting the field it decides (the
other fields left ``"auto"``):

* ``denoise``: the smoothing pass the other way (``"on"`` <-> ``"off"``);
* ``poisson escape``: where the cloud read closed but its Poisson surface was refused for
  flapping past the points (``MAX_POISSON_ESCAPE``), Poisson kept (``target="poisson"``);
* ``shell``: where the offset shell was chosen (``SHEET_*``), the target it replaced (``"poisson"``
  for a closed cloud, else ``"imls"``);
* ``closed``: the target the other way between Poisson and IMLS (``CLOSED_LEVEL``);
* ``hull``: the target cut back to the points' hull (``hull="on"``; auto leaves it off), where
  the target is not the shell;
* ``views``: what the README advises for scans from a few viewpoints, the IMLS target cut back
  to the hull (``target="imls"``, ``hull="on"``), where the target is not the shell.

A rule that did not fire on a cloud is not rerun for ``poisson escape`` and ``shell`` (its
result is the auto one). CD x1e5, NC, F1 against the mesh; a run refused by
``reconstruct``'s check counts as an error. Writes ``benchmarks/results/plan.{md,json}``, or
``plan_<rules>.{md,json}`` for some of the rules (``--rules``), and with ``--pictures`` a PNG
beside them: each cloud named auto, with each rule turned, and the mesh it was sampled from.

    python benchmarks/bench_plan.py [--shapes ...] [--conditions ...] [--rules ...] [--grid 64] [--jobs 1]
                                    [--pictures SHAPE:CONDITION ...]
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from bench_pointcloud import dev_parser, dev_shapes

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
OUT = ROOT / "benchmarks" / "results"
SHAPES = ("organic_bunny.off", "cad_fandisk.obj", "organic_armadillo.obj", "abc_00000005.stl", "thingi32_75655.obj",
          "abc_00000007.stl", "organic_cow.obj", "cad_rocker-arm.obj")
CONDITIONS = ("clean 5k", "noise 0.5%", "third missing", "range scan 1 view", "range scan 3 views")
RULES = ("denoise", "poisson escape", "shell", "closed", "hull", "views")


def _variants(info) -> dict:
    """Rule -> the plan fields that turn it the other way on this cloud, for the rules that apply."""
    from voro3d.pointcloud.tuning import CLOSED_LEVEL

    closed = info.level > CLOSED_LEVEL
    variants = {"denoise": {"denoise": "off" if info.plan.denoise == "on" else "on"},
                "closed": {"target": "imls" if closed else "poisson"}}
    if closed and info.plan.target == "imls":
        variants["poisson escape"] = {"target": "poisson"}
    if info.plan.target == "sheet":
        variants["shell"] = {"target": "poisson" if closed else "imls"}
    else:
        variants["hull"] = {"hull": "off" if info.plan.hull == "on" else "on"}
        if (info.plan.target, info.plan.hull) != ("imls", "on"):
            variants["views"] = {"target": "imls", "hull": "on"}
    return variants


def _run(points, source, grid, plan=None) -> tuple[dict, object]:
    from bench_pointcloud import _pieces

    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, reconstruct_points
    from voro3d.reconstruction import _check_fit

    start = time.perf_counter()
    try:
        shape, target, info = reconstruct_points(points, grid=grid, plan=plan)
        mesh = cloud_mesh(shape, target)
        _check_fit(mesh, points, info.voxel, info.offset)
    except (ValueError, RuntimeError) as error:
        return dict(error=f"{type(error).__name__}: {error}", seconds=time.perf_counter() - start), None
    seconds = time.perf_counter() - start
    scores = evaluate(mesh, source)
    return dict(cd=scores["chamfer_x1e5"], nc=scores["nc"], f1=scores["f1"], seconds=seconds, plan=str(info.plan),
                level=info.level, pieces=_pieces(mesh)), info


def run_cloud(name: str, condition: str, grid, rules=RULES) -> dict:
    from bench_pointcloud import make_cloud
    from voro3d.io import load_mesh

    source = load_mesh(DEV / name)
    points = make_cloud(source, condition)
    auto, info = _run(points, source, grid)
    row = dict(shape=name, condition=condition, auto=auto, rules={})
    if info is not None:
        for rule, fields in _variants(info).items():
            if rule not in rules:
                continue
            row["rules"][rule] = dict(_run(points, source, grid, fields)[0], set=fields)
    print(json.dumps(row), flush=True)
    return row


def _table(rows: list, grid, rules=RULES) -> str:
    lines = [f"# The plan's rules, on and off ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs)", "",
             f"{len({r['shape'] for r in rows})} dev meshes x {len({r['condition'] for r in rows})} conditions, no normals "
             f"given, grid {grid} (`python benchmarks/bench_plan.py`). Per rule and condition: the clouds where "
             "the rule applies, mean CD x1e5 / NC / F1 with the rule as the plan decides it (auto) and turned the "
             "other way, and how many clouds it helped (lower CD). A refused run (reconstruct's check) counts as an "
             "error and is left out of the means.", "",
             "| rule | condition | clouds | auto CD / NC / F1 | turned CD / NC / F1 | turned better (CD) | errors auto / turned "
             "| s auto / turned |",
             "|---|---|---|---|---|---|---|---|"]
    for rule in rules:
        for condition in dict.fromkeys(r["condition"] for r in rows):
            pairs = [(r["auto"], r["rules"][rule]) for r in rows if r["condition"] == condition and rule in r["rules"]]
            if not pairs:
                continue
            good = [(a, t) for a, t in pairs if "cd" in a and "cd" in t]
            errors = (sum("error" in a for a, _ in pairs), sum("error" in t for _, t in pairs))

            def mean(runs, key):
                return float(np.mean([run[key] for run in runs])) if runs else float("nan")

            auto, turned = [a for a, _ in good], [t for _, t in good]
            better = sum(t["cd"] < a["cd"] for a, t in good)
            lines.append(f"| {rule} | {condition} | {len(pairs)} | {mean(auto, 'cd'):.2f} / {mean(auto, 'nc'):.3f} / "
                         f"{mean(auto, 'f1'):.3f} | {mean(turned, 'cd'):.2f} / {mean(turned, 'nc'):.3f} / "
                         f"{mean(turned, 'f1'):.3f} | {better} of {len(good)} | {errors[0]} / {errors[1]} | "
                         f"{sum(a['seconds'] for a in auto):.0f} / {sum(t['seconds'] for t in turned):.0f} |")
    lines += ["", "Per cloud (CD; the plan the auto run chose):", "", "| shape | condition | auto plan | auto CD | "
              + " | ".join(rules) + " |", "|---|---|---|---|" + "---|" * len(rules)]
    for r in rows:
        cells = [_cd(r["rules"][rule]) if rule in r["rules"] else "" for rule in rules]
        lines.append(f"| {r['shape']} | {r['condition']} | {r['auto'].get('plan', '')} | {_cd(r['auto'])} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def figure(clouds, grid, rules, out_png) -> None:
    """``SHAPE:CONDITION`` clouds drawn one row each: auto, each of ``rules`` turned, the mesh."""
    from bench_pointcloud import make_cloud
    from figures import render_rows

    from voro3d.io import load_mesh
    from voro3d.pointcloud import cloud_mesh, reconstruct_points

    rows = []
    for cloud in clouds:
        name, condition = cloud.split(":", 1)
        source = load_mesh(DEV / name)
        points = make_cloud(source, condition)
        shape, target, info = reconstruct_points(points, grid=grid)
        meshes, titles = [cloud_mesh(shape, target)], [f"{Path(name).stem}, {condition}: auto"]
        for rule, fields in _variants(info).items():
            if rule in rules:
                shape, target, _ = reconstruct_points(points, grid=grid, plan=fields)
                meshes.append(cloud_mesh(shape, target))
                titles.append(f"{rule}: {', '.join(f'{k} {v}' for k, v in fields.items())}")
        rows.append((meshes + [source], titles + ["the mesh"]))
    render_rows(rows, out_png, size=(420, 340))


def _cd(run: dict) -> str:
    return f"{run['cd']:.2f}" if "cd" in run else "error"


def main() -> None:
    parser = dev_parser(__doc__, SHAPES, OUT)
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS))
    parser.add_argument("--rules", nargs="+", default=list(RULES), choices=RULES)
    parser.add_argument("--grid", default="64", help="an integer, or auto")
    parser.add_argument("--jobs", type=int, default=1, help="clouds run at once, each in its own process")
    parser.add_argument("--pictures", nargs="+", default=[], metavar="SHAPE:CONDITION",
                        help="clouds drawn auto, with each rule turned and the mesh, into the results' PNG")
    parser.add_argument("--pictures-only", action="store_true", help="draw --pictures without running the table")
    args = parser.parse_args()
    grid = args.grid if args.grid == "auto" else int(args.grid)
    shapes = dev_shapes(args.shapes, DEV)
    sys.path.insert(0, str(ROOT))
    rules = tuple(rule for rule in RULES if rule in args.rules)
    stem = "plan" if rules == RULES else "plan_" + "_".join(rule.replace(" ", "-") for rule in rules)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.pictures:
        figure(args.pictures, grid, rules, args.out / f"{stem}.png")
    if args.pictures_only:
        return
    tasks = [(name, condition, grid, rules) for name in shapes for condition in args.conditions]
    if args.jobs > 1:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            rows = pool.starmap(run_cloud, tasks, chunksize=1)
    else:
        rows = [run_cloud(*task) for task in tasks]
    (args.out / f"{stem}.json").write_text(json.dumps(dict(date=time.strftime("%Y-%m-%d %H:%M"), grid=grid, jobs=args.jobs,
                                                           cpus=os.cpu_count(), rows=rows), indent=1))
    (args.out / f"{stem}.md").write_text(_table(rows, grid, rules))
    print(_table(rows, grid, rules))


if __name__ == "__main__":
    main()
