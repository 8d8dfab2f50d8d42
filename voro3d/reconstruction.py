"""Geometry in, watertight mesh out: the Open3D-style entry point and a pipeline stage.

``reconstruct`` takes what an Open3D pipeline holds (a point cloud, a mesh, their tensor
versions, a numpy array or a path) and returns an ``open3d.geometry.TriangleMesh``, like
``TriangleMesh.create_from_point_cloud_poisson``, but closed and free of self-intersections.
A point cloud needs no mesh: VoroLoss fits the generators to the points, and the generalized
winding number of the oriented points (Barill et al. 2018) labels the cells.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._validate import as_points, positive_int

MIN_POINTS = 100
METHODS = ("fit", "learned")
# Neighbours for normal estimation, orientation and point areas.
NEIGHBOURS = 16


def reconstruct(geometry, grid: int = 32, *, method: str = "fit", steps: int = 400, seed: int = 0,
                device: str = "cpu", progress: bool = False):
    """Watertight VoroMesh surface of a point cloud or mesh.

    Parameters
    ----------
    geometry : open3d.geometry.PointCloud, open3d.geometry.TriangleMesh, their ``open3d.t``
        versions, (n, 3) or (n, 6) float array (points, or points then normals), or a path
        to a mesh or point-cloud file.
        Point clouds use their normals when they have them; otherwise normals are estimated
        and oriented with Open3D.
    grid : int
        Grid resolution ``g`` (``g^3`` nodes over the shape's bounding box).
    method : {"fit", "learned"}
        Direct optimisation (seconds) or the shipped ONNX network (fast, needs no torch).
    steps, seed, device, progress
        Passed to the fit (``method="fit"``).

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, manifold, outward-oriented, in the input's coordinates.

    Raises
    ------
    ValueError
        Empty or too small cloud (< 100 points), NaN/inf points, all points coplanar, normals
        missing and not estimable, an unknown method, or a non-watertight input mesh.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    grid = positive_int(grid, "grid", minimum=4)
    kind, data = _read(geometry)
    if kind == "mesh":
        if method == "fit":
            from .fitting import fit

            return fit(data, grid, steps=steps, seed=seed, device=device, progress=progress).to_open3d()
        from .infer import predict_mesh

        return predict_mesh(data, grid).to_open3d()
    points, normals = data
    return _reconstruct_points(points, normals, grid, method=method, steps=steps, seed=seed, device=device,
                               progress=progress).to_open3d()


class VoroMeshStage:
    """A pipeline stage: ``stage(geometry) -> TriangleMesh``, set up once, called many times.

    Parameters are those of :func:`reconstruct`. With ``method="learned"`` the ONNX session is
    loaded on the first call and kept.

    Examples
    --------
    >>> steps = [lambda p: p.voxel_down_sample(0.01), VoroMeshStage(grid=64)]  # doctest: +SKIP
    """

    def __init__(self, grid: int = 32, *, method: str = "fit", steps: int = 400, seed: int = 0,
                 device: str = "cpu", progress: bool = False):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.options = dict(grid=positive_int(grid, "grid", minimum=4), method=method, steps=steps, seed=seed,
                            device=device, progress=progress)

    def __call__(self, geometry):
        return reconstruct(geometry, **self.options)

    def __repr__(self) -> str:
        return "VoroMeshStage(" + ", ".join(f"{k}={v!r}" for k, v in self.options.items()) + ")"


def _reconstruct_points(points, normals, grid, *, method, steps, seed, device, progress):
    from .io import fit_frame
    from .sampling import point_areas, point_winding_number

    frame = fit_frame(points)
    framed = frame.apply(points)
    areas = point_areas(framed, k=NEIGHBOURS)

    def inside(queries):
        return point_winding_number(framed, normals, queries, areas=areas) > 0.5

    if method == "learned":
        from .extract import VoroMesh
        from .infer import predict

        shape = predict(_cloud_sdf(framed, inside, grid))
        return VoroMesh(frame.invert(shape.generators), shape.occupancy)
    from .fitting import SAMPLES_PER_FACE, fit_samples

    budget = SAMPLES_PER_FACE * grid**2
    samples = framed
    if samples.shape[0] > budget:  # the paper's sample count is enough; more only costs time
        samples = samples[np.random.default_rng(seed).choice(samples.shape[0], budget, replace=False)]
    shape, _ = fit_samples(samples, inside, grid, frame=frame, steps=steps, seed=seed, device=device,
                           progress=progress)
    return shape


def _cloud_sdf(points, inside, grid):
    """Signed distance to the cloud at the grid nodes: distance to the nearest point, signed
    by the winding number (negative inside)."""
    from scipy.spatial import cKDTree

    from .sampling import grid_nodes

    nodes = grid_nodes(grid)
    distance, _ = cKDTree(points).query(nodes, workers=-1)
    return np.where(inside(nodes), -distance, distance).reshape(grid, grid, grid).astype(np.float32)


def _read(geometry):
    """('mesh', TriangleMesh) or ('points', (points, normals))."""
    import open3d as o3d

    if isinstance(geometry, (str, Path)):
        path = Path(geometry)
        from .io import MESH_SUFFIXES, load_mesh, load_points

        if not path.exists():
            raise FileNotFoundError(f"no such file: {path}")
        if path.suffix.lower() in MESH_SUFFIXES:
            try:
                return "mesh", load_mesh(path)
            except ValueError as error:
                if "no triangles" not in str(error) or path.suffix.lower() != ".ply":
                    raise
        geometry = load_points(path)
    if isinstance(geometry, o3d.t.geometry.TriangleMesh):
        geometry = geometry.to_legacy()
    if isinstance(geometry, o3d.t.geometry.PointCloud):
        geometry = geometry.to_legacy()
    if isinstance(geometry, o3d.geometry.TriangleMesh):
        if len(geometry.triangles) == 0:
            raise ValueError("mesh has no triangles")
        return "mesh", geometry
    if isinstance(geometry, o3d.geometry.PointCloud):
        points = np.asarray(geometry.points)
        normals = np.asarray(geometry.normals) if geometry.has_normals() else None
    else:
        array = np.asarray(geometry)
        if array.ndim == 2 and array.shape[1] == 6:
            points, normals = array[:, :3], array[:, 3:]
        else:
            points, normals = array, None
    return "points", _oriented(points, normals)


def _oriented(points, normals):
    points = as_points(points, "points", min_count=0)
    if points.shape[0] < MIN_POINTS:
        raise ValueError(f"point cloud has {points.shape[0]} points; at least {MIN_POINTS} are needed")
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred[:: max(1, points.shape[0] // 20000)], compute_uv=False)
    if singular[2] <= 1e-9 * singular[0]:
        raise ValueError("all points are coplanar (or collinear): a flat cloud encloses no volume")
    if normals is None:
        normals = estimate_normals(points)
    normals = as_points(normals, "normals")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have shape {points.shape}, got {normals.shape}")
    length = np.linalg.norm(normals, axis=1)
    if (length < 1e-12).mean() > 0.01:
        raise ValueError(f"{int((length < 1e-12).sum())} normals are zero: the cloud's normals are not usable")
    return points, normals / np.maximum(length, 1e-12)[:, None]


def estimate_normals(points: np.ndarray, *, k: int = NEIGHBOURS) -> np.ndarray:
    """Unit normals from local PCA, oriented consistently and outward (Open3D).

    Orientation propagates over a k-nearest-neighbour tangent-plane graph; the whole set is
    then flipped if most normals point towards the centroid, since a closed surface's
    outward normals mostly point away from it.

    Parameters
    ----------
    points : (n, 3) float64

    Returns
    -------
    (n, 3) float64
    """
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k))
    try:
        cloud.orient_normals_consistent_tangent_plane(k)
    except RuntimeError as error:
        raise ValueError(f"normals could not be oriented: {error}") from error
    normals = np.asarray(cloud.normals).copy()
    if not np.isfinite(normals).all():
        raise ValueError("normals could not be estimated (degenerate neighbourhoods)")
    if np.einsum("ij,ij->i", normals, points - points.mean(axis=0)).mean() < 0:
        normals = -normals
    return normals
