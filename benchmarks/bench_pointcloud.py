"""Point clouds as they come -> watertight meshes: VoroMesh vs Open3D's Poisson pipeline.

Each dev mesh (default ``../shared/data/dev``, else the bundled examples) is sampled into
clouds *without normals* under the conditions of ``CONDITIONS``: sparse to dense clean clouds,
Gaussian noise, a 20x density ramp, uniform outliers in the bounding box, a third of the surface
missing, range scans from 1, 3 and 6 viewpoints (``range_scan``), and, only when named, one view of a
depth camera's frame, ~300k points (``dense range scan 1 view``) and range scans from 1 and 3
viewpoints with a consumer depth sensor's noise (``noisy range scan ...``), from 3 and 6 whose views
registration left a little apart (``misaligned range scan ...``), and from 1 and 3 with a time-of-flight
camera's flying pixels at depth edges (``flying pixels range scan ...``), a spinning LiDAR's scan lines
from 1 and 3 positions (``lidar ...``, ``lidar_scan``; ``dense lidar ...`` only when named), and clouds of 300 to 5k points (``sparse ...``).
On each cloud:

* VoroMesh: ``voro3d.pointcloud.reconstruct_points`` at ``--grid`` (outlier removal, normals,
  target surface, fit), timed with its split, and ``cloud_mesh`` (extraction, clean, fit to the
  target), as ``voro3d.reconstruct`` returns it.
* Poisson, as a user of Open3D would run it: statistical outlier removal (20 neighbours, 2
  deviations), normals (30 neighbours), ``orient_normals_consistent_tangent_plane(30)`` (``--orient-neighbours``),
  screened Poisson at depth 7 and 8, the one with the lower CD per shape (its own pipeline time).

CD x1e5, F1 at 0.003 and NC against the mesh (NDC frame, 100k points); VoroMesh meshes are also
checked closed, manifold, oriented with no crossing triangles (``check_watertight``), and their
connected pieces counted. The clean 20k condition carries colours (RGB from the position) into
both methods and scores the colour error at the ground-truth samples. ``--scans`` reconstructs
the real scans of ``../shared/data/scans`` with both methods (distance from the scan points,
agreement with the scan's normals, a side-by-side PNG per scan).

Writes ``benchmarks/results/pointcloud.{md,json}`` (``--out``), ``pointcloud.png`` and
``pointcloud_scans.png``. Parts of the work can run in separate processes and be merged:

    python benchmarks/bench_pointcloud.py --shapes A B --conditions all --out /tmp/a
    python benchmarks/bench_pointcloud.py --merge /tmp/a.json /tmp/b.json
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "benchmarks" / "results"
# name: (kind, points, parameter)
CONDITIONS = {
    "clean 5k": ("clean", 5_000, 0.0),
    "clean 20k": ("clean", 20_000, 0.0),
    "clean 100k": ("clean", 100_000, 0.0),
    "noise 0.25%": ("noise", 20_000, 0.0025),
    "noise 0.5%": ("noise", 20_000, 0.005),
    "noise 1%": ("noise", 20_000, 0.01),
    "density ramp 20x": ("ramp", 100_000, 20.0),
    "outliers 2%": ("outliers", 50_000, 0.02),
    "third missing": ("hole", 50_000, 1 / 3),
    "range scan 1 view": ("range", 30_000, 1),
    "range scan 3 views": ("range", 30_000, 3),
    "range scan 6 views": ("range", 30_000, 6),
    "dense range scan 1 view": ("dense range", 300_000, 1),
    "noisy range scan 1 view": ("noisy range", 30_000, 1),
    "noisy range scan 3 views": ("noisy range", 30_000, 3),
    "misaligned range scan 3 views": ("misaligned range", 30_000, 3),
    "misaligned range scan 6 views": ("misaligned range", 30_000, 6),
    "flying pixels range scan 1 view": ("flying range", 30_000, 1),
    "flying pixels range scan 3 views": ("flying range", 30_000, 3),
    "lidar 1 position": ("lidar", 0, 1),
    "lidar 3 positions": ("lidar", 0, 3),
    "dense lidar 3 positions": ("dense lidar", 0, 3),
    "sparse 300": ("clean", 300, 0.0),
    "sparse 600": ("clean", 600, 0.0),
    "sparse 1k": ("clean", 1_000, 0.0),
    "sparse 2k, noise 0.25%": ("noise", 2_000, 0.0025),
    "sparse 5k, noise 0.25%": ("noise", 5_000, 0.0025),
}
# The virtual range scanner (make_cloud's "range" kind): a pinhole camera of this field of view and
# pixel count looking at the shape's centre from RANGE_DISTANCE diagonals away; hits whose surface
# turns more than RANGE_GRAZING degrees from the ray are dropped (a scanner gets no return there),
# and depth noise of RANGE_NOISE of the diagonal is added along the ray.
RANGE_FOV = 40.0
RANGE_PIXELS = (256, 256)
DENSE_RANGE_PIXELS = (1600, 1200)  # a depth camera's frame: ~300k points of one view of a dev mesh
RANGE_DISTANCE = 1.6
RANGE_GRAZING = 75.0
RANGE_NOISE = 0.0005
# The "noisy range" kind's depth noise, of the diagonal: a structured-light or time-of-flight sensor's
# few millimetres on an object of about a metre.
NOISY_RANGE_NOISE = 0.003
# The "misaligned range" kind: each view moved by its own rigid motion, as registration (ICP) leaves
# merged scans: a turn about a random axis through the centre of N(0, MISALIGN_DEGREES) degrees and a
# shift of N(0, MISALIGN_SHIFT) diagonals per axis (0.1-0.4% of the diagonal where the views overlap).
MISALIGN_DEGREES = 0.3
MISALIGN_SHIFT = 0.002
# The "flying range" kind: a time-of-flight camera's mixed pixels. A pixel beside a depth edge (a 4-neighbour
# missed or over FLYING_EDGE diagonals away) returns, with probability FLYING_SHARE, a depth up to
# FLYING_DEPTH diagonals behind its surface (mixed with the background) instead of the surface's.
FLYING_SHARE = 0.5
FLYING_EDGE = 0.02
FLYING_DEPTH = 0.1
# The "lidar" kind: a spinning LiDAR's LIDAR_BEAMS scan lines, each swept in LIDAR_STEPS azimuth steps across
# the shape (lines 10x as far apart as the steps along them, as a 16-beam sensor's 2 degrees against
# its 0.2), from 1 or 3 positions around it, LIDAR_DISTANCE diagonals away and LIDAR_ELEVATION
# radians above its centre; grazing hits dropped and depth noise as the range scanner's.
LIDAR_BEAMS = 48
LIDAR_STEPS = 480
# The "dense lidar" kind: a 128-beam sensor's lines, 20x as far apart as its steps, its depth noise as wide as a step.
DENSE_LIDAR_BEAMS = 128
DENSE_LIDAR_STEPS = 2560
LIDAR_DISTANCE = 2.5
LIDAR_ELEVATION = 0.25
COLOURED = "clean 20k"
PICTURED = ("organic_bunny.off", "cad_fandisk.obj")
# Seconds given to Open3D's normal orientation before the baseline falls back to ours.
ORIENT_TIMEOUT = 120
# Neighbours of Open3D's tangent-plane orientation (--orient-neighbours): the stored tables' 30; issue
# 24's pipeline used 16, on organic clouds 0.8x the time (bunny at 10^5 points 7.9 -> 6.6 s), on CAD
# parts as slow (fandisk at 10^5 points: 437 s).
ORIENT_NEIGHBOURS = 30
PICTURED_CONDITIONS = ("clean 5k", "noise 1%", "outliers 2%", "third missing", "range scan 1 view", "range scan 3 views",
                       "dense range scan 1 view", "noisy range scan 1 view", "noisy range scan 3 views",
                       "misaligned range scan 3 views", "flying pixels range scan 3 views", "lidar 3 positions", "sparse 600",
                       "sparse 2k, noise 0.25%")


def make_cloud(mesh, condition: str, *, seed: int = 0) -> np.ndarray:
    """The cloud of one condition: area-uniform samples, then noise (sigma = share of the bounding-box
    diagonal, per coordinate), a density falling linearly along x to 1/ratio, uniform outliers in the
    bounding box (share of the points), or the samples beyond a random plane removed (share)."""
    from voro3d.io import mesh_arrays
    from voro3d.sampling import sample_surface

    kind, n, parameter = CONDITIONS[condition]
    vertices, triangles = mesh_arrays(mesh)
    rng = np.random.default_rng(seed + 1)
    if kind.endswith("range"):
        return range_scan(vertices, triangles, parameter, n, rng, DENSE_RANGE_PIXELS if kind == "dense range" else RANGE_PIXELS,
                          noise=NOISY_RANGE_NOISE if kind == "noisy range" else RANGE_NOISE,
                          misalign=(MISALIGN_DEGREES, MISALIGN_SHIFT) if kind == "misaligned range" else None,
                          flying=FLYING_SHARE if kind == "flying range" else 0.0)
    if kind.endswith("lidar"):
        lines = (DENSE_LIDAR_BEAMS, DENSE_LIDAR_STEPS) if kind == "dense lidar" else (LIDAR_BEAMS, LIDAR_STEPS)
        return lidar_scan(vertices, triangles, parameter, rng, *lines)
    if kind == "ramp":
        points, _ = sample_surface((vertices, triangles), 4 * n, seed=seed)
        along = (points[:, 0] - points[:, 0].min()) / np.ptp(points[:, 0])
        points = points[rng.random(len(points)) < 1.0 - along * (1.0 - 1.0 / parameter)][:n]
    elif kind == "hole":
        points, _ = sample_surface((vertices, triangles), int(n / (1 - parameter)) + 1, seed=seed)
        direction = rng.normal(size=3)
        height = points @ (direction / np.linalg.norm(direction))
        points = points[height < np.quantile(height, 1 - parameter)][:n]
    else:
        points, _ = sample_surface((vertices, triangles), n, seed=seed)
    if kind == "noise":
        diagonal = np.linalg.norm(vertices.max(0) - vertices.min(0))
        points = points + rng.normal(scale=parameter * diagonal, size=points.shape)
    if kind == "outliers":
        points = np.vstack([points, rng.uniform(vertices.min(0), vertices.max(0), (int(parameter * n), 3))])
    return points


def range_scan(vertices, triangles, views: int, n: int, rng, pixels=RANGE_PIXELS, *, noise: float = RANGE_NOISE,
               misalign: tuple[float, float] | None = None, flying: float = 0.0) -> np.ndarray:
    """Points a range scanner of ``pixels`` (width, height) sees from ``views`` viewpoints (at most ``n``
    in all, drawn evenly), with depth noise along the ray of ``noise`` times the diagonal.

    Viewpoints: one for 1; otherwise spread in longitude around the vertical at 30 degrees of
    elevation (3 views), or the six directions of a cube, turned at random. Each camera casts
    Open3D's pinhole rays (``RaycastingScene.create_rays_pinhole``) at the shape's centre.
    ``misalign`` (degrees, diagonals): each view's points then turned and shifted by their own
    random rigid motion (``MISALIGN_DEGREES``). ``flying``: the share of pixels beside a depth edge
    that return a mixed depth behind it (``FLYING_SHARE``).
    """
    import open3d as o3d

    from voro3d.geometry import raycasting_scene

    scene = raycasting_scene(vertices, triangles)
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    diagonal = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if views == 6:
        rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        directions = np.vstack([np.eye(3), -np.eye(3)]) @ rotation.T
    else:
        longitude = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(views) / views
        elevation = np.radians(30.0)
        directions = np.c_[np.cos(elevation) * np.cos(longitude), np.cos(elevation) * np.sin(longitude),
                           np.full(views, np.sin(elevation))]
    found = []
    for direction in directions:
        eye = centre + RANGE_DISTANCE * diagonal * direction
        up = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        rays = scene.create_rays_pinhole(RANGE_FOV, centre.tolist(), eye.tolist(), up.tolist(), *pixels).numpy()
        rays = rays.reshape(-1, 6)
        unit = rays[:, 3:] / np.linalg.norm(rays[:, 3:], axis=1, keepdims=True)
        depth, seen = _seen_hits(scene, rays, unit)
        distance = (depth * np.linalg.norm(rays[:, 3:], axis=1)).astype(np.float64)
        distance[seen] += rng.normal(scale=noise * diagonal, size=int(seen.sum()))
        if flying:
            mixed = _depth_edges(distance, pixels, FLYING_EDGE * diagonal) & (rng.random(distance.shape) < flying)
            distance[mixed] += rng.uniform(0.0, FLYING_DEPTH * diagonal, int(mixed.sum()))
            seen |= mixed
        points = rays[seen, :3] + distance[seen, None] * unit[seen]
        if misalign is not None:
            axis = rng.normal(size=3)
            turn = o3d.geometry.get_rotation_matrix_from_axis_angle(
                axis / np.linalg.norm(axis) * np.radians(misalign[0]) * rng.normal())
            points = (points - centre) @ turn.T + centre + rng.normal(scale=misalign[1] * diagonal, size=3)
        found.append(points)
    points = np.vstack(found)
    return points[rng.permutation(len(points))[:n]]


def lidar_scan(vertices, triangles, positions: int, rng, beams: int = LIDAR_BEAMS, steps: int = LIDAR_STEPS) -> np.ndarray:
    """Points a spinning LiDAR sees from ``positions`` places spread in longitude around the shape:
    ``beams`` lines of elevation, each swept in ``steps`` steps of azimuth, both spans covering the
    shape's bounding sphere; every hit kept (all of them: the lines are the point)."""
    from voro3d.geometry import raycasting_scene

    scene = raycasting_scene(vertices, triangles)
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    diagonal = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    found = []
    for longitude in rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(positions) / positions:
        eye = centre + LIDAR_DISTANCE * diagonal * np.array([np.cos(longitude), np.sin(longitude), LIDAR_ELEVATION])
        forward = (centre - eye) / np.linalg.norm(centre - eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        half = np.arcsin(0.5 * diagonal / np.linalg.norm(centre - eye))
        elevation, azimuth = np.meshgrid(np.linspace(-half, half, beams), np.linspace(-half, half, steps), indexing="ij")
        directions = ((np.cos(elevation) * np.cos(azimuth))[..., None] * forward
                      + (np.cos(elevation) * np.sin(azimuth))[..., None] * right
                      + np.sin(elevation)[..., None] * up).reshape(-1, 3)
        rays = np.hstack([np.repeat(eye[None], len(directions), axis=0), directions])
        depth, seen = _seen_hits(scene, rays, directions)
        depth = depth.astype(np.float64)
        depth[seen] += rng.normal(scale=RANGE_NOISE * diagonal, size=int(seen.sum()))
        found.append(eye + depth[seen, None] * directions[seen])
    return np.vstack(found)


def _seen_hits(scene, rays, unit) -> tuple[np.ndarray, np.ndarray]:
    """``rays`` (r, 6) cast into ``scene`` (as float32, as Open3D does): each one's hit parameter
    (float32, inf where missed) and whether it is seen, a hit within ``RANGE_GRAZING`` of facing
    its direction ``unit`` (r, 3), as a scanner drops grazing returns."""
    import open3d as o3d

    hit = scene.cast_rays(o3d.core.Tensor(np.asarray(rays, np.float32)))
    depth = hit["t_hit"].numpy()
    facing = np.abs(np.einsum("ij,ij->i", hit["primitive_normals"].numpy(), unit))
    return depth, np.isfinite(depth) & (facing > np.cos(np.radians(RANGE_GRAZING)))


def _depth_edges(distance, pixels, gap: float) -> np.ndarray:
    """(w h,) bool: the hit pixels of a row-major depth image (``distance``, inf where missed) with a
    4-neighbour that missed or lies over ``gap`` away."""
    width, height = pixels
    image = distance.reshape(height, width)
    padded = np.pad(image, 1, constant_values=np.inf)
    edge = np.zeros((height, width), bool)
    for rows, columns in ((slice(1, -1), slice(2, None)), (slice(1, -1), slice(None, -2)),
                          (slice(2, None), slice(1, -1)), (slice(None, -2), slice(1, -1))):
        with np.errstate(invalid="ignore"):
            edge |= ~(np.abs(padded[rows, columns] - image) <= gap)
    return (edge & np.isfinite(image)).reshape(-1)


def dev_parser(doc: str, shapes, out: Path):
    """An argument parser with ``--shapes`` (default ``shapes``) and ``--out`` (default ``out``), described by ``doc``'s first line."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=list(shapes))
    parser.add_argument("--out", type=Path, default=out)
    return parser


def dev_shapes(names, folder: Path = SHARED / "dev") -> list:
    """The dev meshes of ``names`` that ``folder`` holds; none of them is an error (the data is not bundled)."""
    found = [name for name in names if (folder / name).exists()]
    if not found:
        raise SystemExit(f"none of {list(names)} in {folder}")
    return found


def position_colours(points, low, high):
    """RGB in [0, 1] from the position in the box ``low``-``high``: a smooth colouring to carry over."""
    return np.clip((points - low) / (high - low), 0.0, 1.0)


def _tangent_plane_normals(points, normals, queue):
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    cloud.orient_normals_consistent_tangent_plane(ORIENT_NEIGHBOURS)
    queue.put(np.asarray(cloud.normals))


def _orient(points, normals):
    """Open3D's tangent-plane orientation in a child process, given ORIENT_TIMEOUT seconds (it took
    13-20 minutes on some 100k-point dev clouds). Past that, the normals take the signs of
    :func:`voro3d.pointcloud.estimate_normals` instead: the baseline then gets our orientation."""
    import multiprocessing

    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_tangent_plane_normals, args=(points, normals, queue))
    child.start()
    try:
        return queue.get(timeout=ORIENT_TIMEOUT), "tangent plane"
    except Exception:  # queue.Empty: timed out (or the child died)
        from voro3d.frames import fit_frame
        from voro3d.pointcloud import estimate_normals

        ours = estimate_normals(fit_frame(points).apply(points))
        return normals * np.sign(np.einsum("ij,ij->i", normals, ours) + 1e-300)[:, None], "voro3d (timeout)"
    finally:
        child.kill()
        child.join()


def poisson(points, colours=None):
    """Open3D's pipeline; returns ({depth: (mesh, seconds)}, how the normals were oriented)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if colours is not None:
        cloud.colors = o3d.utility.Vector3dVector(colours)
    start = time.perf_counter()
    cloud, _ = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
    oriented, orientation = _orient(np.asarray(cloud.points), np.asarray(cloud.normals))
    cloud.normals = o3d.utility.Vector3dVector(oriented)
    prepared = time.perf_counter() - start
    meshes = {}
    for depth in (7, 8):
        start = time.perf_counter()
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
        meshes[depth] = (mesh, prepared + time.perf_counter() - start)
    return meshes, orientation


def best_poisson(points, source, colours=None):
    """:func:`poisson` at depths 7 and 8, the one with the lower CD against ``source``.

    Returns
    -------
    depth, mesh, scores (:func:`voro3d.metrics.evaluate`), seconds, orientation
    """
    from voro3d.metrics import evaluate

    meshes_by_depth, orientation = poisson(points, colours)
    tried = {depth: (evaluate(mesh, source), mesh, seconds) for depth, (mesh, seconds) in meshes_by_depth.items()}
    depth = min(tried, key=lambda d: tried[d][0]["chamfer_x1e5"])
    scores, mesh, seconds = tried[depth]
    return depth, mesh, scores, seconds, orientation


def alpha_wrap_binary() -> Path:
    """``out/alpha_wrap``, compiled from ``benchmarks/alpha_wrap.cpp`` with the system's CGAL when missing or older."""
    import subprocess

    source, binary = Path(__file__).with_name("alpha_wrap.cpp"), ROOT / "out" / "alpha_wrap"
    if not binary.exists() or binary.stat().st_mtime < source.stat().st_mtime:
        binary.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["g++", "-O2", "-std=c++17", "-DNDEBUG", str(source), "-o", str(binary), "-lgmp", "-lmpfr"],
                       check=True)
    return binary


def alpha_wrap(points):
    """CGAL's ``alpha_wrap_3`` of the points, alpha = diagonal / 60, offset = diagonal / 600 (closed,
    intersection-free, as ours); returns (mesh, seconds)."""
    import subprocess
    import tempfile

    import open3d as o3d

    diagonal, binary = float(np.linalg.norm(np.ptp(points, axis=0))), alpha_wrap_binary()
    with tempfile.TemporaryDirectory() as folder:
        cloud, wrap = Path(folder) / "points.xyz", Path(folder) / "wrap.off"
        np.savetxt(cloud, points, fmt="%.9g")
        start = time.perf_counter()
        subprocess.run([str(binary), str(cloud), str(wrap), repr(diagonal / 60), repr(diagonal / 600)],
                       check=True)
        seconds = time.perf_counter() - start
        mesh = o3d.io.read_triangle_mesh(str(wrap))
    return mesh, seconds


def _pieces(mesh) -> int:
    return int(len(np.unique(np.asarray(mesh.cluster_connected_triangles()[0]))))


def _colour_error(mesh, source, low, high):
    """Mean |RGB error| (0-1 per channel, averaged) at 20k ground-truth samples: the colour of the
    nearest mesh vertex against the position colouring."""
    from scipy.spatial import cKDTree

    from voro3d.sampling import sample_surface

    truth, _ = sample_surface(source, 20_000, seed=5)
    _, nearest = cKDTree(np.asarray(mesh.vertices)).query(truth, workers=-1)
    return float(np.abs(np.asarray(mesh.vertex_colors)[nearest] - position_colours(truth, low, high)).mean())


def run_condition(source, name, condition, grid, picture_dir, *, with_poisson=True, with_alpha_wrap=False,
                  pictured=PICTURED, prefilter=False):
    from voro3d.io import mesh_arrays, save_mesh
    from voro3d.metrics import evaluate
    from voro3d.pointcloud import cloud_mesh, colored_mesh, reconstruct_points
    from voro3d.reconstruction import _check_fit
    from voro3d.watertight import check_watertight

    points = make_cloud(source, condition)
    vertices, _ = mesh_arrays(source)
    low, high = vertices.min(0), vertices.max(0)
    colours = position_colours(points, low, high) if condition == COLOURED else None
    row = dict(shape=name, condition=condition, points=len(points))
    start = time.perf_counter()
    try:
        kept = slice(None)
        if prefilter:  # what a user runs first on scans with flying pixels (README); the baselines get the cloud as it is
            import open3d as o3d

            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            kept = np.asarray(cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)[1], np.int64)
        shape, target, info = reconstruct_points(points[kept], grid=grid, progress=False)
        mesh = cloud_mesh(shape, target)
        _check_fit(mesh, points[kept], info.voxel, info.offset)  # what reconstruct refuses is an error here too
        if colours is not None:
            mesh = colored_mesh(mesh, points[kept], colours[kept])
        seconds = time.perf_counter() - start
        report = check_watertight(mesh)
        row["voromesh"] = dict(evaluate(mesh, source), seconds=seconds, split=info.seconds, grid=info.grid,
                               noise=info.noise, outliers=info.n_outliers, smoothed=info.smoothed, target=info.target,
                               level=info.level, watertight=bool(report.watertight),
                               crossing_pairs=int(report.self_intersecting_pairs), pieces=_pieces(mesh))
        if colours is not None:
            row["voromesh"]["colour_error"] = _colour_error(mesh, source, low, high)
        meshes = {"voromesh": mesh}
    except (ValueError, RuntimeError) as error:
        row["voromesh"] = dict(error=f"{type(error).__name__}: {error}", watertight=False,
                               seconds=time.perf_counter() - start)
        meshes = {}
    if with_poisson:
        depth, mesh, scores, seconds, orientation = best_poisson(points, source, colours)
        row["poisson"] = dict(scores, seconds=seconds, depth=depth, pieces=_pieces(mesh), orientation=orientation,
                              closed=bool(mesh.is_edge_manifold() and mesh.is_watertight()))
        if colours is not None:
            row["poisson"]["colour_error"] = _colour_error(mesh, source, low, high)
        meshes["poisson"] = mesh
    if with_alpha_wrap:
        mesh, seconds = alpha_wrap(points)
        row["alpha_wrap"] = dict(evaluate(mesh, source), seconds=seconds, pieces=_pieces(mesh))
    if name in pictured and (condition in PICTURED_CONDITIONS or condition == COLOURED):
        for method, mesh in meshes.items():
            save_mesh(mesh, picture_dir / f"{Path(name).stem}_{condition.replace(' ', '_')}_{method}.ply")
    return row if with_poisson else dict(row, poisson={})


def run_scans(folder: Path, grid, picture_dir):
    """Both methods on each real scan: mean distance from the scan points to the mesh (in the scan's
    bounding-box diagonals) and mean |n_scan . n_mesh| where the scan has normals."""
    import open3d as o3d

    from voro3d.frames import fit_frame
    from voro3d.io import save_mesh
    from voro3d.pointcloud import cloud_mesh, reconstruct_points
    from voro3d.pointcloud.preprocess import outlier_mask
    from voro3d.watertight import check_watertight

    rows = []
    for path in sorted(p for p in folder.iterdir() if p.suffix in (".ply", ".xyz")):
        fmt = {"point_set_3.xyz": "xyzn"}.get(path.name, "xyz" if path.suffix == ".xyz" else "auto")
        cloud = o3d.io.read_point_cloud(str(path), format=fmt)
        points = np.asarray(cloud.points)
        normals = np.asarray(cloud.normals) if cloud.has_normals() else None
        usable = None if normals is None else np.linalg.norm(normals, axis=1) > 1e-9
        row = dict(scan=path.name, points=len(points), normals=normals is not None)
        diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
        # Both methods are also scored at the points our outlier test keeps (a scan's far specks
        # weigh heavily in a mean distance: Poisson wraps them in blobs, we drop them).
        kept = ~outlier_mask(fit_frame(points).apply(points))
        row["kept_points"] = int(kept.sum())
        start = time.perf_counter()
        try:
            shape, target, info = reconstruct_points(points, normals, grid=grid)
            mesh = cloud_mesh(shape, target)
            report = check_watertight(mesh)
            row["voromesh"] = dict(_scan_scores(mesh, points, normals, usable, diagonal, kept),
                                   seconds=time.perf_counter() - start, grid=info.grid, pieces=_pieces(mesh),
                                   watertight=bool(report.watertight), outliers=info.n_outliers)
            save_mesh(mesh, picture_dir / f"scan_{path.stem}_voromesh.ply")
        except ValueError as error:
            row["voromesh"] = dict(error=str(error))
        tried, _ = poisson(points)
        scored = {d: _scan_scores(m, points, normals, usable, diagonal, kept) for d, (m, _) in tried.items()}
        depth = min(scored, key=lambda d: scored[d]["distance"])
        row["poisson"] = dict(scored[depth], depth=depth, seconds=tried[depth][1], pieces=_pieces(tried[depth][0]))
        save_mesh(tried[depth][0], picture_dir / f"scan_{path.stem}_poisson.ply")
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _scan_scores(mesh, points, normals, usable, diagonal, kept):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    found = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    distance = np.linalg.norm(found["points"].numpy() - points, axis=1)
    scores = dict(distance=float(distance.mean() / diagonal), kept_distance=float(distance[kept].mean() / diagonal))
    if normals is not None:
        agreement = np.abs(np.einsum("ij,ij->i", found["primitive_normals"].numpy(), normals))
        scores["normal_agreement"] = float(agreement[usable].mean())
    return scores


def _mean(rows, method, key):
    values = [r[method][key] for r in rows if key in r[method]]
    return float(np.mean(values)) if values else float("nan")


def write(out: Path, meta, rows, scans):
    out.with_suffix(".json").write_text(json.dumps(dict(meta=meta, rows=rows, scans=scans), indent=2))
    # A merged file lists each run with its own loads (one run's before and another's after would mislead).
    runs = _runs(meta)
    loads = "; ".join(f"{run['date']}: load average {run['load_before']} before, {run['load_after']} after" for run in runs)
    lines = [f"# Point clouds as they come -> watertight meshes ({meta['machine']}; "
             f"{'merged runs, ' if len(runs) > 1 else ''}{loads})", "",
             f"Clouds without normals sampled from {len({r['shape'] for r in rows})} {meta.get('meshes', 'dev meshes')}. VoroMesh: "
             f"`voro3d.pointcloud.reconstruct_points(points, grid={meta['grid']})`, then `cloud_mesh`. Poisson: Open3D statistical "
             f"outlier removal (20, 2.0), normals (30 neighbours), tangent-plane orientation "
             f"({meta.get('orient_neighbours', 30)} neighbours; after "
             f"{ORIENT_TIMEOUT} s the signs of voro3d's normals instead, marked * per shape), screened Poisson "
             "depth 7 or 8, the lower CD per shape. CD x1e5, F1 at 0.003, NC against the mesh (NDC frame, 100k "
             "points). *closed*: VoroMesh meshes checked closed, manifold, oriented, no crossing triangles (exact); "
             "*one piece*: share of the outputs in one connected piece (every input is one object).", "",
             "| condition | shapes | VoroMesh CD | Poisson CD | CD ratio | VoroMesh NC | Poisson NC | NC diff | "
             "VoroMesh F1 | Poisson F1 | closed % | one piece % (Poisson) | VoroMesh s | Poisson s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    totals = dict(voromesh=0.0, poisson=0.0)
    for condition in CONDITIONS:
        everything = [r for r in rows if r["condition"] == condition]
        group = [r for r in everything if r["poisson"]]
        for label, subset, paired in ((condition, group, True),
                                      (f"{condition}, all {len(everything)} (VoroMesh only)", everything, False)):
            if not subset or (not paired and len(everything) == len(group)):
                continue
            ok = [r for r in subset if "chamfer_x1e5" in r["voromesh"]]
            cd_v, nc_v = _mean(ok, "voromesh", "chamfer_x1e5"), _mean(ok, "voromesh", "nc")
            closed = 100.0 * np.mean([r["voromesh"].get("watertight", False) for r in subset])
            one = 100.0 * np.mean([r["voromesh"].get("pieces") == 1 for r in subset])
            v_seconds = float(np.sum([r["voromesh"]["seconds"] for r in subset]))
            if not paired:
                lines.append(f"| {label} | {len(subset)} ({len(ok)} meshes) | {cd_v:.3f} | - | - | {nc_v:.3f} | - | - | "
                             f"{_mean(ok, 'voromesh', 'f1'):.3f} | - | {closed:.0f} | {one:.0f} | "
                             f"{v_seconds / len(subset):.1f} | - |")
                continue
            cd_p, nc_p = _mean(ok, "poisson", "chamfer_x1e5"), _mean(ok, "poisson", "nc")
            one_p = 100.0 * np.mean([r["poisson"]["pieces"] == 1 for r in subset])
            p_seconds = float(np.sum([r["poisson"]["seconds"] for r in subset]))
            totals["voromesh"] += v_seconds
            totals["poisson"] += p_seconds
            lines.append(f"| {label} | {len(subset)} ({len(ok)} meshes) | {cd_v:.3f} | {cd_p:.3f} | {cd_v / cd_p:.2f} | "
                         f"{nc_v:.3f} | {nc_p:.3f} | {nc_v - nc_p:+.3f} | {_mean(ok, 'voromesh', 'f1'):.3f} | "
                         f"{_mean(ok, 'poisson', 'f1'):.3f} | {closed:.0f} | {one:.0f} ({one_p:.0f}) | "
                         f"{v_seconds / len(subset):.1f} | {p_seconds / len(subset):.1f} |")
    wrapped = [r for r in rows if "alpha_wrap" in r and "chamfer_x1e5" in r["voromesh"]]
    if wrapped:
        lines += ["", "CGAL's `alpha_wrap_3` (alpha = diagonal / 60, offset = diagonal / 600; `benchmarks/alpha_wrap.cpp`) "
                      "on the same clouds, where VoroMesh returned a mesh:", "",
                  "| condition | clouds | VoroMesh CD | alpha wrap CD | VoroMesh NC | alpha wrap NC | VoroMesh F1 | "
                  "alpha wrap F1 | alpha wrap one piece % | alpha wrap s |", "|---|---|---|---|---|---|---|---|---|---|"]
        for condition in CONDITIONS:
            group = [r for r in wrapped if r["condition"] == condition]
            if group:
                lines.append(f"| {condition} | {len(group)} | " + " | ".join(
                    f"{_mean(group, method, key):.3f}" for key in ("chamfer_x1e5", "nc", "f1")
                    for method in ("voromesh", "alpha_wrap")) +
                    f" | {100.0 * np.mean([r['alpha_wrap']['pieces'] == 1 for r in group]):.0f} | "
                    f"{_mean(group, 'alpha_wrap', 'seconds'):.1f} |")
    if rows:
        splits = [r["voromesh"]["split"] for r in rows if "split" in r["voromesh"]]
        split = {k: float(np.sum([s[k] for s in splits])) for k in splits[0]} if splits else {}
        ratio = totals["voromesh"] / totals["poisson"] if totals["poisson"] else float("nan")
        lines += ["", f"Time summed over the runs with both methods: VoroMesh {totals['voromesh']:.0f} s, Poisson pipeline "
                      f"{totals['poisson']:.0f} s, ratio **{ratio:.2f}**. VoroMesh split (all runs): " + ", ".join(f"{k} {v:.0f} s ({100 * v / max(sum(split.values()), 1e-9):.0f}%)"
                                            for k, v in split.items()) + "."]
        coloured = [r for r in rows if "colour_error" in r["voromesh"]]
        if coloured:
            lines += ["", f"Colours ({COLOURED}, RGB from position, {len(coloured)} shapes): mean |RGB error| at the "
                          f"ground-truth samples, VoroMesh {_mean(coloured, 'voromesh', 'colour_error'):.4f}, "
                          f"Poisson {_mean(coloured, 'poisson', 'colour_error'):.4f}."]
        failed = [r for r in rows if "error" in r["voromesh"]]
        if failed:
            lines += ["", "Failed: " + "; ".join(f"{r['shape']} / {r['condition']}: {r['voromesh']['error']}" for r in failed)]
    if scans:
        lines += ["", "## Real scans (`../shared/data/scans`)", "",
                  "Mean distance from the scan points to the mesh, in scan bounding-box diagonals, at all the points "
                  "and at those our outlier test keeps (`kept`: far specks weigh heavily in a mean; Poisson wraps "
                  "them in blobs, we drop them); mean |n_scan . n_mesh| at the scan points that have normals. "
                  "Poisson: depth 7 or 8, the lower distance.", "",
                  "| scan | points (kept) | VoroMesh distance (kept) | Poisson distance (kept) | VoroMesh normals | "
                  "Poisson normals | VoroMesh pieces | Poisson pieces | VoroMesh closed | VoroMesh s | Poisson s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for s in scans:
            v, p = s["voromesh"], s["poisson"]
            if "error" in v:
                lines.append(f"| {s['scan']} | {s['points']} | error: {v['error']} | {p['distance']:.5f} | | | | | | | |")
                continue
            fmt = lambda d: f"{d['normal_agreement']:.3f}" if "normal_agreement" in d else "-"  # noqa: E731
            kept = lambda d: f"{d['distance']:.2e} ({d['kept_distance']:.2e})"  # noqa: E731
            lines.append(f"| {s['scan']} | {s['points']} ({s['kept_points']}) | {kept(v)} | {kept(p)} | {fmt(v)} | "
                         f"{fmt(p)} | {v['pieces']} | {p['pieces']} | {v['watertight']} | {v['seconds']:.1f} | "
                         f"{p['seconds']:.1f} |")
    lines += ["", "## Per shape and condition", "",
              "| shape | condition | VoroMesh CD / NC / F1 | Poisson CD / NC / F1 (depth) | pieces | grid | target | noise est. | "
              "outliers removed | s (VoroMesh / Poisson) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        v, p = r["voromesh"], r["poisson"]
        if "error" in v:
            lines.append(f"| {r['shape']} | {r['condition']} | {v['error']} | | | | | | | |")
            continue
        timed_out = "*" if p.get("orientation", "").endswith("(timeout)") else ""
        poisson_cell = f"{p['chamfer_x1e5']:.3f} / {p['nc']:.3f} / {p['f1']:.3f} ({p['depth']}{timed_out})" if p else "-"
        lines.append(f"| {r['shape']} | {r['condition']} | {v['chamfer_x1e5']:.3f} / {v['nc']:.3f} / {v['f1']:.3f} | "
                     f"{poisson_cell} | {v['pieces']} | "
                     f"{v['grid']} | {v.get('target', '-')} | {v['noise']:.2g} | {v['outliers']} | {v['seconds']:.1f} / {p.get('seconds', float('nan')):.1f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def pictures(picture_dir: Path, rows, scans, folder: Path, out: Path, pictured=PICTURED):
    """Rows of input / VoroMesh / Poisson for the ``pictured`` shapes and conditions; one row per scan."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from figures import render_rows

    from voro3d.io import load_mesh

    def complete(path: Path, wanted: list) -> bool:
        # A merge on a machine that holds the meshes of some rows only would redraw a picture with
        # those rows alone: the picture drawn from every row stays instead.
        missing = [f.name for files in wanted for f in files if not f.exists()]
        if missing and path.exists():
            print(f"kept {path.name}: {len(missing)} of its meshes are not in {picture_dir} ({missing[0]}, ...)")
        return not missing or not path.exists()

    pictured = [(r, [picture_dir / f"{Path(r['shape']).stem}_{r['condition'].replace(' ', '_')}_{m}.ply"
                     for m in ("voromesh", "poisson")])
                for r in rows if r["shape"] in pictured and r["condition"] in PICTURED_CONDITIONS]
    if not complete(out.with_suffix(".png"), [files for _, files in pictured]):
        pictured = []
    figure = []
    for r, files in pictured:
        stem = Path(r["shape"]).stem
        if not all(f.exists() for f in files):
            continue
        v, p = r["voromesh"], r["poisson"]
        figure.append(([load_mesh(folder / r["shape"])] + [load_mesh(f, weld=False) for f in files],
                       [f"{stem}: {r['condition']} ({r['points']} pts)",
                        f"VoroMesh {v['grid']}^3: CD {v['chamfer_x1e5']:.2f} NC {v['nc']:.3f}",
                        f"Poisson d{p['depth']}: CD {p['chamfer_x1e5']:.2f} NC {p['nc']:.3f}"]))
    if figure:
        render_rows(figure, out.with_suffix(".png"))
    coloured = [(r, [picture_dir / f"{Path(r['shape']).stem}_{COLOURED.replace(' ', '_')}_{m}.ply"
                     for m in ("voromesh", "poisson")]) for r in rows if r["condition"] == COLOURED]
    if not complete(out.parent / (out.name + "_colours.png"), [files for _, files in coloured]):
        coloured = []
    coloured = [(r, files) for r, files in coloured if all(f.exists() for f in files)]
    if coloured:
        render_rows([([load_mesh(f, weld=False) for f in files],
                      [f"VoroMesh, colours carried ({Path(r['shape']).stem})", "Poisson, colours carried"])
                     for r, files in coloured], out.parent / (out.name + "_colours.png"))
    scan_files = [[picture_dir / f"scan_{Path(s['scan']).stem}_{m}.ply" for m in ("voromesh", "poisson")] for s in scans]
    if not complete(out.parent / (out.name + "_scans.png"), scan_files):
        scans = []
    scan_rows = []
    for s, files in zip(scans, scan_files):
        if all(f.exists() for f in files):
            v, p = s["voromesh"], s["poisson"]
            ours, theirs = (load_mesh(f, weld=False) for f in files)
            scan_rows.append(([ours, theirs], [f"{s['scan']}: VoroMesh {v['grid']}^3, {v['pieces']} piece(s)",
                                               f"Poisson depth {p['depth']}, {p['pieces']} piece(s)"]))
            box = ours.get_axis_aligned_bounding_box().scale(1.25, ours.get_center())
            if theirs.get_axis_aligned_bounding_box().get_max_extent() > 2.0 * box.get_max_extent():
                # Poisson's blobs around far specks shrink the shared view: the same again, cropped.
                scan_rows.append(([ours, theirs.crop(box)], [f"{s['scan']}: VoroMesh, close up",
                                                             "Poisson, cropped to the same box"]))
    if scan_rows:
        render_rows(scan_rows, out.parent / (out.name + "_scans.png"))


def _runs(meta) -> list:
    """The runs behind a result: a merged one's list, or the run itself."""
    return meta.get("runs") or [dict(date=meta["date"], load_before=meta["load_before"],
                                     load_after=meta.get("load_after", "?"))]


def _meshes(folder: Path) -> str:
    """What the results' meshes are, for their header: the dev meshes, or those of another folder."""
    dev = folder is None or folder.resolve() == (SHARED / "dev").resolve()  # None: no dev data, scans alone
    return "dev meshes" if dev else f"meshes of `{folder}`"


def merge(sources, out: Path, folder: Path):
    runs = [json.loads(Path(source).read_text()) for source in sources]
    # A --no-poisson run has no baseline of its own and merges with any.
    baselines = {run["meta"].get("orient_neighbours", 30) for run in runs if not run["meta"].get("no_poisson")}
    if len(baselines) > 1:
        raise SystemExit(f"the runs oriented Open3D's normals with {sorted(baselines)} neighbours: one baseline only")
    rows = {}
    for r in (r for run in runs for r in run["rows"]):
        key = (r["shape"], r["condition"])
        for side in ("poisson", "alpha_wrap"):  # a --no-poisson run refreshes the VoroMesh side only
            if not r.get(side) and rows.get(key, {}).get(side):
                r = dict(r, **{side: rows[key][side]})
        rows[key] = r
    scans = {s["scan"]: s for run in runs for s in run["scans"]}
    # Each run keeps its date and loads; a merged file's own runs are flattened.
    listed = {}
    for run in runs:
        for entry in _runs(run["meta"]):
            listed.setdefault(entry["date"], entry)
    pictured = sorted({shape for run in runs for shape in run["meta"].get("pictured", PICTURED)})
    meta = dict(runs[0]["meta"], runs=list(listed.values()), orient_neighbours=min(baselines, default=30), pictured=pictured,
                meshes=_meshes(folder))
    rows = [rows[k] for k in sorted(rows, key=lambda k: (list(CONDITIONS).index(k[1]), k[0]))]
    scans = [scans[k] for k in sorted(scans)]
    write(out, meta, rows, scans)
    pictures(ROOT / "out" / "bench_pointcloud", rows, scans, folder, out, pictured)
    print(f"wrote {out.with_suffix('.md')}")


def add_hull_argument(parser) -> None:
    """``--hull-margin``, ``--rim-crop`` and ``--cavity-walls``: the ablations beside ``HULL_MARGIN_NODES``, ``RIM_CROP``
    and ``sides.cavity_walls``, applied by :func:`set_hull_margin`."""
    parser.add_argument("--hull-margin", type=float, help="HULL_MARGIN_NODES for this run, the ablation beside it in "
                        "voro3d/pointcloud/tuning.py")
    parser.add_argument("--rim-crop", type=float, help="RIM_CROP for this run (inf: no open cloud read as a crop), "
                        "the ablation beside it in voro3d/pointcloud/hull.py")
    parser.add_argument("--cavity-walls", choices=("on", "off"), default="on",
                        help="off: no point's normal turned inward on a cavity's wall (sides.cavity_walls), its ablation")


def set_hull_margin(args) -> None:
    import voro3d.pointcloud.hull as hull_module

    if args.hull_margin is not None:
        hull_module.HULL_MARGIN_NODES = args.hull_margin
    if args.rim_crop is not None:
        hull_module.RIM_CROP = args.rim_crop
    if args.cavity_walls == "off":
        import voro3d.pointcloud.sides as sides_module

        sides_module.cavity_walls = lambda points, *rest, **options: np.zeros(len(points), bool)


def main():
    global ORIENT_NEIGHBOURS  # --orient-neighbours; read by the forked orientation child
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=SHARED / "dev" if (SHARED / "dev").is_dir() else None)
    parser.add_argument("--shapes", nargs="*", help="file names in --folder (default: all)")
    parser.add_argument("--conditions", nargs="*", default=[c for c in CONDITIONS if c.startswith(("clean", "noise", "density", "outliers", "third", "range"))],
                        choices=list(CONDITIONS))
    parser.add_argument("--grid", default="64", help="VoroMesh grid, or auto")
    parser.add_argument("--scans", action="store_true", help="also the real scans in ../shared/data/scans")
    parser.add_argument("--no-shapes", action="store_true", help="scans only")
    parser.add_argument("--orient-neighbours", type=int, default=ORIENT_NEIGHBOURS,
                        help=f"neighbours of Open3D's tangent-plane orientation, default {ORIENT_NEIGHBOURS}")
    parser.add_argument("--no-poisson", action="store_true", help="VoroMesh only (Open3D's tangent-plane orientation "
                        "can take minutes at 10^5 points)")
    parser.add_argument("--alpha-wrap", action="store_true", help="also CGAL's alpha_wrap_3 (alpha = diagonal / 60, "
                        "offset = diagonal / 600), compiled from benchmarks/alpha_wrap.cpp")
    parser.add_argument("--shell-depth", help="SHELL_DEPTH for this run (fit-frame units, or none: no limit), the "
                        "ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--bridge-gap", type=float, help="MAX_BRIDGE_GAP for this run (fit-frame units; 0: no "
                        "bridges), the ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--hole-level", type=float, help="HOLE_LEVEL for this run (0: each cloud's own winding "
                        "level), the ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--poisson-escape", help="MAX_POISSON_ESCAPE for this run (share of the diagonal, or none: "
                        "never refused), the ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--dense-spacings", type=float, help="DENSE_SPACINGS for this run, the ablation beside it")
    parser.add_argument("--auto-width", type=float, help="AUTO_SPACINGS_PER_VOXEL for this run (with --grid auto), the "
                        "ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--sheet-support", type=float, help="SHEET_SUPPORT for this run (inf: no such rule), the "
                        "ablation beside it in voro3d/pointcloud/tuning.py")
    parser.add_argument("--hug-spacings", help="HUG_SPACINGS for this run (none: the offset shell as its grid gives "
                        "it, not laid onto the points), the ablation beside it in voro3d/pointcloud/shell.py")
    parser.add_argument("--line-ratio", type=float, help="LINE_RATIO for this run (0: no cloud is thinned along its "
                        "scan lines), the ablation beside it")
    parser.add_argument("--sparse-spacings", type=float, help="SPARSE_SPACINGS (outlier test) for this run, the "
                        "ablation beside it in voro3d/pointcloud/tuning.py")
    add_hull_argument(parser)
    parser.add_argument("--prefilter", action="store_true", help="Open3D's statistical outlier removal (20 neighbours, "
                        "2 deviations) on each cloud before VoroMesh, as the README advises for flying pixels")
    parser.add_argument("--pictured", nargs="+", default=list(PICTURED), help="shapes whose meshes the picture shows")
    parser.add_argument("--out", type=Path, default=RESULTS / "pointcloud")
    parser.add_argument("--merge", type=Path, nargs="+", help="join the rows of these JSON results instead of running "
                        "(later files win; a row without Poisson or alpha wrap keeps the earlier file's)")
    args = parser.parse_args()
    import multiprocessing

    ORIENT_NEIGHBOURS = args.orient_neighbours
    if args.merge:
        merge(args.merge, args.out, args.folder)
        return
    import voro3d.pointcloud.plan as plan_module
    import voro3d.pointcloud.reconstruct as reconstruct_module
    import voro3d.pointcloud.resolution as resolution_module
    import voro3d.pointcloud.shell as shell_module
    import voro3d.pointcloud.surface as surface_module
    import voro3d.pointcloud.targets as targets_module

    if args.shell_depth == "none":
        targets_module._shell_depth = lambda points, normals, resolution: None
    elif args.shell_depth is not None:
        targets_module.SHELL_DEPTH = float(args.shell_depth)
    if args.bridge_gap is not None:
        surface_module.MAX_BRIDGE_GAP = shell_module.MAX_BRIDGE_GAP = args.bridge_gap
    if args.hug_spacings == "none":
        shell_module.SheetSurface.hugging = lambda sheet, points, spacing: sheet
    elif args.hug_spacings is not None:
        shell_module.HUG_SPACINGS = float(args.hug_spacings)
    if args.hole_level is not None:
        targets_module.HOLE_LEVEL = args.hole_level
    if args.poisson_escape is not None:
        targets_module.MAX_POISSON_ESCAPE = np.inf if args.poisson_escape == "none" else float(args.poisson_escape)
    if args.dense_spacings is not None:
        reconstruct_module.DENSE_SPACINGS = args.dense_spacings
    if args.sheet_support is not None:
        plan_module.SHEET_SUPPORT = args.sheet_support
    if args.auto_width is not None:
        resolution_module.AUTO_SPACINGS_PER_VOXEL = args.auto_width
    if args.line_ratio is not None:
        import voro3d.pointcloud.scanlines as scanlines_module

        scanlines_module.LINE_RATIO = args.line_ratio
    if args.sparse_spacings is not None:
        import voro3d.pointcloud.preprocess as preprocess_module

        preprocess_module.SPARSE_SPACINGS = args.sparse_spacings
    set_hull_margin(args)
    from voro3d.io import MESH_SUFFIXES, load_mesh

    grid = args.grid if args.grid == "auto" else int(args.grid)
    picture_dir = ROOT / "out" / "bench_pointcloud"
    picture_dir.mkdir(parents=True, exist_ok=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    load = lambda: " ".join(Path("/proc/loadavg").read_text().split()[:3])  # noqa: E731
    meta = dict(date=time.strftime("%Y-%m-%d %H:%M"), machine=f"{platform.machine()}, {multiprocessing.cpu_count()} cores",
                load_before=load(), grid=args.grid, shell_depth=args.shell_depth or "default",
                bridge_gap="default" if args.bridge_gap is None else args.bridge_gap,
                hole_level="default" if args.hole_level is None else args.hole_level,
                poisson_escape=args.poisson_escape or "default",
                dense_spacings="default" if args.dense_spacings is None else args.dense_spacings,
                sheet_support="default" if args.sheet_support is None else args.sheet_support,
                hug_spacings=args.hug_spacings or "default",
                auto_width="default" if args.auto_width is None else args.auto_width,
                line_ratio="default" if args.line_ratio is None else args.line_ratio,
                sparse_spacings="default" if args.sparse_spacings is None else args.sparse_spacings,
                hull_margin="default" if args.hull_margin is None else args.hull_margin,
                orient_neighbours=ORIENT_NEIGHBOURS, no_poisson=args.no_poisson, pictured=args.pictured,
                prefilter=args.prefilter, meshes=_meshes(args.folder))
    paths = [] if args.no_shapes else sorted(p for p in args.folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if args.shapes:
        paths = [p for p in paths if p.name in args.shapes]
    rows, scans = [], []
    for path in paths:
        source = load_mesh(path)
        for condition in args.conditions:
            row = run_condition(source, path.name, condition, grid, picture_dir, with_poisson=not args.no_poisson,
                                with_alpha_wrap=args.alpha_wrap, pictured=args.pictured, prefilter=args.prefilter)
            rows.append(row)
            print(json.dumps({k: row[k] for k in ("shape", "condition")} |
                             {m: {k: row[m].get(k) for k in ("chamfer_x1e5", "nc", "f1", "pieces", "watertight",
                                                             "seconds", "error")} for m in ("voromesh", "poisson", "alpha_wrap")
                                                 if m in row}),
                  flush=True)
            meta["load_after"] = load()
            write(args.out, meta, rows, scans)
    if args.scans:
        scans = run_scans(SHARED / "scans", grid, picture_dir)
        meta["load_after"] = load()
        write(args.out, meta, rows, scans)
    if not args.no_poisson:  # the pictures put both methods side by side (--merge draws them)
        pictures(picture_dir, rows, scans, args.folder, args.out, args.pictured)
    print(f"wrote {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
