"""How many separate islands the benchmark's clouds are, beside the pieces each method made of them.

"One piece for one-object inputs" asks for one connected output per object, but a cloud can be
several islands itself: a third of the surface cut away can leave a part (a trunk's tip) with no
point between it and the rest, and a single range view can see a part only through a gap. No
method can join those without inventing surface. This rebuilds every cloud of
``bench_pointcloud``'s results (``make_cloud``, the same seed), drops what our outlier test drops
(``voro3d.pointcloud.preprocess.outlier_mask``, as ``reconstruct`` does), joins points closer than
``REACH`` median spacings (a random subset of at most ``SUBSET`` points, so the radius graph stays
small) and counts the islands of at least ``MIN_ISLAND`` points. Each row gets the pieces that
VoroMesh, Poisson and alpha wrap made in the results file.

    python benchmarks/bench_islands.py    # reads results/pointcloud.json and pointcloud_range.json

Writes ``benchmarks/results/pointcloud_islands.{md,json}``.
"""
from __future__ import annotations

import json
import time
import numpy as np

from bench_pointcloud import RESULTS, SHARED, make_cloud

SOURCES = ("pointcloud.json", "pointcloud_range.json")
# The islands read the same at 3, 5 and 8 median spacings on the two clouds that come out in
# several pieces (elephant with a third missing, spot's 1-view scan): the gaps are wide.
REACH = 3.0
SUBSET = 30_000
MIN_ISLAND = 10


def islands(points: np.ndarray, seed: int = 0) -> list[int]:
    """Sizes (largest first) of the islands of ``points`` (n, 3) that our outlier test keeps."""
    from scipy.spatial import cKDTree

    from voro3d.geometry import components
    from voro3d.pointcloud.preprocess import outlier_mask

    points = points[~outlier_mask(points)]
    if len(points) > SUBSET:
        points = points[np.random.default_rng(seed).choice(len(points), SUBSET, replace=False)]
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, 9)[0][:, -1]))
    _, label = components(len(points), tree.query_pairs(REACH * spacing, output_type="ndarray"))
    sizes = np.sort(np.bincount(label))[::-1]
    return [int(size) for size in sizes if size >= MIN_ISLAND]


def main():
    from voro3d.io import load_mesh

    rows, meshes = [], {}
    for source in SOURCES:
        for row in json.loads((RESULTS / source).read_text())["rows"]:
            if row["shape"] not in meshes:
                meshes[row["shape"]] = load_mesh(SHARED / "dev" / row["shape"])
            sizes = islands(make_cloud(meshes[row["shape"]], row["condition"]))
            pieces = {method: (row.get(method) or {}).get("pieces") for method in ("voromesh", "poisson", "alpha_wrap")}
            rows.append(dict(shape=row["shape"], condition=row["condition"], islands=len(sizes), sizes=sizes[:6], **pieces))
    several = [row for row in rows if row["voromesh"] != 1 or row["islands"] != 1]
    over = [row for row in rows if row["voromesh"] > row["islands"]]
    (RESULTS / "pointcloud_islands.json").write_text(json.dumps(dict(
        date=time.strftime("%Y-%m-%d %H:%M"), reach=REACH, subset=SUBSET, min_island=MIN_ISLAND, rows=rows), indent=1))
    lines = [f"# Islands of the benchmark clouds against the pieces made of them ({time.strftime('%Y-%m-%d')})", "",
             f"Every cloud of `{'`, `'.join(SOURCES)}` rebuilt, less what our outlier test drops; points within "
             f"{REACH:g} median spacings (8th neighbour) joined, on a random subset of at most {SUBSET:,}; islands of "
             f"at least {MIN_ISLAND} points. `python benchmarks/bench_islands.py`.", "",
             f"{len(rows)} clouds: {sum(row['islands'] == 1 for row in rows)} are one island; VoroMesh made one piece of "
             f"{sum(row['voromesh'] == 1 for row in rows)}, and more pieces than islands of {len(over)}.", "",
             "## Clouds of several islands, or outputs of several pieces", "",
             "| shape | condition | islands (largest) | VoroMesh pieces | Poisson pieces | alpha wrap pieces |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {row['shape']} | {row['condition']} | {row['islands']} ({', '.join(map(str, row['sizes']))}) | "
              f"{row['voromesh']} | {row['poisson'] if row['poisson'] is not None else '-'} | "
              f"{row['alpha_wrap'] if row['alpha_wrap'] is not None else '-'} |" for row in several]
    (RESULTS / "pointcloud_islands.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
