"""Seven shapes none of the dev data holds: CAD parts with flat faces on the axes, a chair, a blob, a knot.

An L bracket with three holes, a gear with a bore, a pipe tee open at its three ends (walls 2 on a
radius of 12), a hex nut, a chair on four thin legs, a smooth blob (a sphere bumped by sines) and a
(2, 3) torus knot of tube radius 5. The parts are built with manifold3d in millimetres, their faces
on round coordinates as CAD gives them (where a flat face can hold the median of the points), and
written as PLY meshes into a folder for ``bench_pointcloud.py --folder``::

    python benchmarks/parts.py /tmp/parts
    python benchmarks/bench_pointcloud.py --folder /tmp/parts --alpha-wrap --pictured chair.ply knot.ply \
        --out benchmarks/results/pointcloud_parts
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

SEGMENTS = 64


def parts() -> dict:
    """``{name: (vertices (n, 3) float64, triangles (m, 3) int64)}`` of the seven shapes, each closed."""
    from manifold3d import CrossSection, Manifold

    from voro3d.shapes import _from_manifold

    cylinder = lambda height, radius: Manifold.cylinder(height, radius, radius, SEGMENTS)  # noqa: E731
    bracket = Manifold.cube([80.0, 40.0, 6.0]) + Manifold.cube([6.0, 40.0, 50.0])
    for x in (30.0, 60.0):
        bracket = bracket - cylinder(20.0, 5.0).translate([x, 20.0, -5.0])
    bracket = bracket - cylinder(20.0, 6.0).rotate([0.0, 90.0, 0.0]).translate([-5.0, 20.0, 30.0])
    # 18 teeth: radius 40 on two of every four profile vertices, 34 on the others.
    angles = np.arange(72) * 2.0 * np.pi / 72
    radii = np.where(np.arange(72) % 4 % 3 == 0, 34.0, 40.0)
    profile = [[float(r * np.cos(a)), float(r * np.sin(a))] for r, a in zip(radii, angles)]
    gear = Manifold.extrude(CrossSection([profile]), 12.0) - cylinder(30.0, 10.0).translate([0.0, 0.0, -5.0])
    tee = (cylinder(100.0, 12.0).translate([0.0, 0.0, -50.0]) + cylinder(60.0, 12.0).rotate([90.0, 0.0, 0.0])) - (
        cylinder(104.0, 10.0).translate([0.0, 0.0, -52.0]) + cylinder(64.0, 10.0).rotate([90.0, 0.0, 0.0])
        .translate([0.0, 2.0, 0.0]))
    hexagon = [[float(25.0 * np.cos(k * np.pi / 3)), float(25.0 * np.sin(k * np.pi / 3))] for k in range(6)]
    nut = Manifold.extrude(CrossSection([hexagon]), 18.0) - cylinder(30.0, 12.0).translate([0.0, 0.0, -5.0])
    chair = Manifold.cube([50.0, 50.0, 4.0]).translate([0.0, 0.0, 45.0])
    for x, y in ((3.0, 3.0), (47.0, 3.0), (3.0, 47.0), (47.0, 47.0)):
        chair = chair + cylinder(45.0, 2.5).translate([x, y, 0.0])
    chair = chair + Manifold.cube([50.0, 4.0, 50.0]).translate([0.0, 46.0, 49.0])
    shapes = {name: _from_manifold(solid) for name, solid in
              dict(bracket=bracket, gear=gear, tee=tee, nut=nut, chair=chair).items()}
    return dict(shapes, blob=_blob(), knot=_knot())


def _blob():
    """A sphere of radius 40 bumped by sines of its directions: smooth, no flat face."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=40.0)
    unit = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1)[:, None]
    bumps = 1.0 + 0.25 * np.sin(3.0 * unit[:, 0]) * np.cos(2.0 * unit[:, 1]) + 0.15 * np.sin(5.0 * unit[:, 2])
    return sphere.vertices * bumps[:, None], np.asarray(sphere.faces, np.int64)


def _knot(steps: int = 400, sides: int = 24):
    """A tube of radius 5 along the (2, 3) torus knot of radii 30 and 12, outward."""
    t = np.linspace(0.0, 2.0 * np.pi, steps, endpoint=False)
    centre = np.c_[(30.0 + 12.0 * np.cos(3 * t)) * np.cos(2 * t), (30.0 + 12.0 * np.cos(3 * t)) * np.sin(2 * t),
                   12.0 * np.sin(3 * t)]
    tangent = np.roll(centre, -1, axis=0) - np.roll(centre, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    normal = np.cross(tangent, [0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    binormal = np.cross(tangent, normal)
    around = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.cos(around)[None, :, None] * normal[:, None] + np.sin(around)[None, :, None] * binormal[:, None]
    vertices = (centre[:, None] + 5.0 * ring).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(steps), np.arange(sides), indexing="ij")
    a, b = i * sides + j, i * sides + (j + 1) % sides
    c, d = (i + 1) % steps * sides + j, (i + 1) % steps * sides + (j + 1) % sides
    triangles = np.stack([np.c_[a.ravel(), c.ravel(), b.ravel()], np.c_[b.ravel(), c.ravel(), d.ravel()]], 1)
    triangles = triangles.reshape(-1, 3)
    # The frame turns one way or the other along the knot: orient by the enclosed volume's sign.
    corners = vertices[triangles]
    if np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() < 0:
        triangles = triangles[:, ::-1]
    return vertices, triangles


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="where the PLY meshes are written (made if missing)")
    args = parser.parse_args()
    from voro3d.io import save_mesh

    args.folder.mkdir(parents=True, exist_ok=True)
    for name, (vertices, triangles) in parts().items():
        print(f"{save_mesh((vertices, triangles), args.folder / f'{name}.ply')}: {len(triangles):,} triangles")


if __name__ == "__main__":
    main()
