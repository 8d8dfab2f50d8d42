"""Thin-walled containers and sheets, none in the dev data: a bowl, a mug, a tray, a lid, a vase, a card, an angle.

Walls 1.3-2.5% of the diagonal thick, open where a container is open: the shapes where a cloud
sampled on both sides of a wall is easy to close into a solid (a bowl into a dome); and two sheets
thinner still, a flat card 0.9% of its diagonal thick and a bent sheet-metal angle 1.7%, whose two
sides a sparse cloud samples closer than its spacing. Built with
manifold3d, in millimetres, and written as PLY meshes into a folder for ``bench_pointcloud.py --folder``::

    python benchmarks/containers.py /tmp/containers
    python benchmarks/bench_pointcloud.py --folder /tmp/containers --alpha-wrap --pictured bowl.ply vase.ply \
        --conditions "clean 5k" "clean 20k" "noise 0.5%" "noise 1%" "third missing" "range scan 1 view" \
        "range scan 3 views" "range scan 6 views" --out benchmarks/results/pointcloud_containers

``--picture`` draws the clouds whose target the walls' share (``tuning.SHEET_WALLS``) changed:
truth, the mesh without that rule, with it, and alpha wrap.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

SEGMENTS = 96
# The clouds of the picture: (container, bench_pointcloud condition).
PICTURED = (("bowl", "clean 20k"), ("bowl", "range scan 6 views"), ("vase", "clean 20k"))


def containers() -> dict:
    """``{name: (vertices (n, 3) float64, triangles (m, 3) int64)}`` of the five containers and two sheets."""
    from manifold3d import CrossSection, Manifold

    from voro3d.shapes import _from_manifold

    cylinder = lambda height, radius: Manifold.cylinder(height, radius, radius, SEGMENTS)  # noqa: E731
    # A hemispherical shell 2 thick on a radius of 50, open at the top.
    bowl = (Manifold.sphere(50.0, SEGMENTS) - Manifold.sphere(48.0, SEGMENTS)) \
        - Manifold.cube([200.0, 200.0, 100.0]).translate([-100.0, -100.0, 0.0])
    # A cylinder 3 thick with a floor 4 thick, and a ring handle.
    handle = (cylinder(8.0, 25.0) - cylinder(8.0, 18.0)).rotate([90.0, 0.0, 0.0]).translate([40.0, 4.0, 45.0])
    mug = cylinder(90.0, 40.0) - cylinder(90.0, 37.0).translate([0.0, 0.0, 4.0]) + (handle - cylinder(90.0, 39.0))
    tray = Manifold.cube([120.0, 80.0, 30.0]) - Manifold.cube([114.0, 74.0, 30.0]).translate([3.0, 3.0, 3.0])
    # A shallow cylinder 2 thick, open underneath, with a lip round its rim.
    lid = (cylinder(15.0, 45.0) - cylinder(13.0, 43.0)) + (cylinder(2.0, 48.0) - cylinder(2.0, 45.0))
    # A profile 2.5 thick with a floor 4 thick, revolved: a vase that bulges and narrows.
    heights = np.linspace(0.0, 120.0, 40)
    radii = 30.0 + 12.0 * np.sin(heights / 120.0 * np.pi * 1.5)
    outer = [[float(r), float(z)] for r, z in zip(radii, heights)]
    inner = [[float(r - 2.5), float(max(z, 4.0))] for r, z in zip(radii[::-1], heights[::-1])]
    vase = CrossSection([[[0.0, 0.0]] + outer + inner[:-1] + [[0.0, 4.0]]]).revolve(SEGMENTS)
    card = Manifold.cube([100.0, 60.0, 1.0])
    # Two flanges 60 and 40 wide, 1.5 thick, bent at a right angle along 50.
    angle = Manifold.cube([60.0, 50.0, 1.5]) + Manifold.cube([1.5, 50.0, 40.0])
    solids = dict(bowl=bowl, mug=mug, tray=tray, lid=lid, vase=vase, card=card, angle=angle)
    return {name: _from_manifold(solid) for name, solid in solids.items()}


def walls_picture(folder: Path, out: Path) -> None:
    """One row per ``PICTURED`` cloud: truth, VoroMesh without and with the walls' rule, alpha wrap."""
    from bench_pointcloud import alpha_wrap, make_cloud
    from figures import render_rows

    import voro3d.pointcloud.plan as plan_module
    from voro3d.io import load_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, reconstruct_points

    rows, rule = [], plan_module.SHEET_WALLS
    for name, condition in PICTURED:
        source = load_mesh(folder / f"{name}.ply")
        points = make_cloud(source, condition)
        meshes, titles = [source], [f"{name}, {condition} ({len(points):,} points)"]
        for label, share in (("without the walls' rule", float("inf")), ("with it", rule)):
            plan_module.SHEET_WALLS = share
            try:
                shape, target, info = reconstruct_points(points, grid=64)
            finally:
                plan_module.SHEET_WALLS = rule
            mesh = cloud_mesh(shape, target)
            meshes.append(mesh)
            titles.append(f"{label}: {info.target}, CD {evaluate(mesh, source)['chamfer_x1e5']:.1f}")
        wrap, _ = alpha_wrap(points)
        meshes.append(wrap)
        titles.append(f"alpha wrap: CD {evaluate(wrap, source)['chamfer_x1e5']:.1f}")
        rows.append((meshes, titles))
    render_rows(rows, out)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="where the PLY meshes are written (made if missing)")
    parser.add_argument("--picture", type=Path, help="also draw PICTURED into this PNG (needs the CGAL headers)")
    args = parser.parse_args()
    from voro3d.io import save_mesh

    args.folder.mkdir(parents=True, exist_ok=True)
    for name, (vertices, triangles) in containers().items():
        print(f"{save_mesh((vertices, triangles), args.folder / f'{name}.ply')}: {len(triangles):,} triangles")
    if args.picture:
        walls_picture(args.folder, args.picture)


if __name__ == "__main__":
    main()
