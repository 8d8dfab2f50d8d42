"""Open surfaces scanned from one side, none in the dev data: three terrain patches and a flat map.

A hill, a valley and a saddle (100 x 100 m, bumps 2 m high on a bowl or a saddle 10-20 m deep) and a
flat map with a coastline (a plate 80 m across, 0.3 m bumps, its outline bays 10-20 m deep): what
an airborne scan, a facade or a scanned drawing gives, a surface whose rim is where the data ends,
not where the surface turned away from the sensor. The truth is the open surface itself, so a
closure past it counts against a method: a valley filled up to its rim, a map out to its convex
outline. Written as PLY meshes into a folder for ``bench_pointcloud.py --folder``::

    python benchmarks/terrain.py /tmp/terrain
    python benchmarks/bench_pointcloud.py --folder /tmp/terrain --alpha-wrap --pictured valley.ply map.ply \
        --conditions "clean 5k" "clean 20k" "noise 0.25%" "range scan 1 view" --out benchmarks/results/pointcloud_terrain
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

# Nodes per side of each height field.
NODES = 201


def height_field(heights, inside=None):
    """``(vertices, triangles)`` of ``heights(x, y)`` over a ``NODES``-square grid of [0, 100]^2 m,
    without the triangles whose centroid is not ``inside(x, y)``."""
    ticks = np.linspace(0.0, 100.0, NODES)
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    vertices = np.c_[x.ravel(), y.ravel(), heights(x, y).ravel()]
    corner = (np.arange(NODES - 1)[:, None] * NODES + np.arange(NODES - 1)[None, :]).ravel()
    triangles = np.vstack([np.c_[corner, corner + NODES, corner + 1], np.c_[corner + 1, corner + NODES, corner + NODES + 1]])
    if inside is not None:
        centre = vertices[triangles].mean(axis=1)
        triangles = triangles[inside(centre[:, 0], centre[:, 1])]
    used = np.unique(triangles)
    renumber = np.full(len(vertices), -1)
    renumber[used] = np.arange(len(used))
    return vertices[used], renumber[triangles]


def shapes() -> dict:
    """``{name: (vertices (n, 3) float64, triangles (m, 3) int64)}`` of the three terrains and the map."""
    bumps = lambda x, y: 2.0 * np.sin(x / 8.0) * np.cos(y / 10.0)  # noqa: E731
    bowl = lambda x, y: 0.004 * ((x - 50.0) ** 2 + (y - 50.0) ** 2)  # noqa: E731

    def coast(x, y):
        angle = np.arctan2(y - 50.0, x - 50.0)
        return np.hypot(x - 50.0, y - 50.0) < 38.0 * (1.0 + 0.22 * np.sin(5.0 * angle) + 0.08 * np.sin(11.0 * angle + 1.0))

    return dict(hill=height_field(lambda x, y: bumps(x, y) - bowl(x, y)),
                valley=height_field(lambda x, y: bumps(x, y) + bowl(x, y)),
                saddle=height_field(lambda x, y: bumps(x, y) + 0.002 * (x - 50.0) * (y - 50.0)),
                map=height_field(lambda x, y: 0.15 * bumps(x, y), coast))


def main() -> None:
    from voro3d.io import save_mesh

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    args = parser.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    for name, (vertices, triangles) in shapes().items():
        print(f"{save_mesh((vertices, triangles), args.folder / f'{name}.ply')}: {len(vertices)} vertices, "
              f"{len(triangles)} triangles")


if __name__ == "__main__":
    main()
