"""Closed shapes with a sealed cavity inside, none in the dev data: what a cloud sampled from a CAD model or a
scanned-and-merged sealed part gives, both the outside and the cavity's wall.

A hollow ball (radius 50, wall 10), two sealed boxes (100 mm, walls 10 and 6), a sealed box whose walls (3) are
as thin as a 20k cloud's spacing, and a sealed tank (a cylinder of radius 40 and height 100, walls 5). Built
with manifold3d, in millimetres, and written as PLY meshes into a folder for ``bench_pointcloud.py --folder``::

    python benchmarks/hollow.py /tmp/hollow --picture benchmarks/results/pointcloud_hollow_cut.png
    python benchmarks/bench_pointcloud.py --folder /tmp/hollow --alpha-wrap --conditions "clean 5k" "clean 20k" \
        "noise 0.25%" --out benchmarks/results/pointcloud_hollow

``--picture`` draws the meshes cut in half through their centre (their cavity shows): truth, VoroMesh without
``sides.cavity_walls`` and with it, alpha wrap, on each ``PICTURED`` cloud.
"""
from __future__ import annotations

import argparse
from pathlib import Path

SEGMENTS = 96
# The clouds of the picture: (shape, bench_pointcloud condition).
PICTURED = (("ball", "clean 20k"), ("box6", "clean 20k"), ("box3", "clean 20k"))


def shapes() -> dict:
    """``{name: (vertices (n, 3) float64, triangles (m, 3) int64)}`` of the five hollow shapes."""
    from manifold3d import Manifold

    from voro3d.shapes import _from_manifold

    def box(side: float, wall: float):
        return Manifold.cube([side] * 3) - Manifold.cube([side - 2.0 * wall] * 3).translate([wall] * 3)

    def tank(radius: float, height: float, wall: float):
        inner = Manifold.cylinder(height - 2.0 * wall, radius - wall, radius - wall, SEGMENTS).translate([0.0, 0.0, wall])
        return Manifold.cylinder(height, radius, radius, SEGMENTS) - inner

    solids = dict(ball=Manifold.sphere(50.0, SEGMENTS) - Manifold.sphere(40.0, SEGMENTS), box10=box(100.0, 10.0),
                  box6=box(100.0, 6.0), box3=box(100.0, 3.0), tank=tank(40.0, 100.0, 5.0))
    return {name: _from_manifold(solid) for name, solid in solids.items()}


def halved(mesh):
    """The triangles of an Open3D mesh whose centroid lies below its box's centre along x (its inside shows)."""
    import numpy as np
    import open3d as o3d

    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    centre = vertices[triangles].mean(axis=1)[:, 0]
    half = o3d.geometry.TriangleMesh(mesh.vertices, o3d.utility.Vector3iVector(triangles[centre < vertices[:, 0].mean()]))
    return half.remove_unreferenced_vertices()


def cut_picture(folder: Path, out: Path) -> None:
    """One row per ``PICTURED`` cloud, each mesh cut in half: truth, VoroMesh without and with the cavity rule,
    alpha wrap."""
    import numpy as np
    from bench_pointcloud import alpha_wrap, make_cloud
    from figures import render_rows

    import voro3d.pointcloud.sides as sides_module
    from voro3d.io import load_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, reconstruct_points

    rows, rule = [], sides_module.cavity_walls
    for name, condition in PICTURED:
        source = load_mesh(folder / f"{name}.ply")
        points = make_cloud(source, condition)
        truth = source
        while len(truth.triangles) < 20000:  # a box's 24 triangles would be halved whole
            truth = truth.subdivide_midpoint(1)
        meshes, titles = [halved(truth)], [f"{name}, {condition}, cut"]
        for label, walls in (("without the cavity rule", lambda points, *rest, **options: np.zeros(len(points), bool)),
                             ("with it", rule)):
            sides_module.cavity_walls = walls
            try:
                shape, target, info = reconstruct_points(points, grid=64)
            finally:
                sides_module.cavity_walls = rule
            mesh = cloud_mesh(shape, target)
            meshes.append(halved(mesh))
            titles.append(f"{label}: CD {evaluate(mesh, source)['chamfer_x1e5']:.1f}")
        wrap, _ = alpha_wrap(points)
        meshes.append(halved(wrap))
        titles.append(f"alpha wrap: CD {evaluate(wrap, source)['chamfer_x1e5']:.1f}")
        rows.append((meshes, titles))
    render_rows(rows, out, view=(-60.0, 25.0))
    print(f"wrote {out}")


def main() -> None:
    from voro3d.io import save_mesh

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--picture", type=Path, help="also draw the PICTURED clouds' meshes cut in half, here")
    args = parser.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    for name, (vertices, triangles) in shapes().items():
        print(f"{save_mesh((vertices, triangles), args.folder / f'{name}.ply')}: {len(vertices)} vertices, "
              f"{len(triangles)} triangles")
    if args.picture:
        cut_picture(args.folder, args.picture)


if __name__ == "__main__":
    main()
