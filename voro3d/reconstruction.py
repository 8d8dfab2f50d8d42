"""Geometry in, watertight mesh out: the Open3D-style entry point and a pipeline stage.

``reconstruct`` takes what an Open3D pipeline holds (a point cloud, a mesh, their tensor
versions, a numpy array or a path) and returns an ``open3d.geometry.TriangleMesh``, like
``TriangleMesh.create_from_point_cloud_poisson``, but closed and free of self-intersections.
Meshes go to the direct fit (or the learned model); point clouds to :mod:`voro3d.pointcloud`.

The grid of reconstruct
-----------------------
``grid`` is an int of at least 4, or ``"auto"`` (the default):

- **a mesh:** ``"auto"`` is 32 (``reconstruction.MESH_AUTO_GRID``): a mesh has no point spacing to
  go by. Any larger grid works; there is no upper limit, only cost.
- **a point cloud:** ``"auto"`` makes voxels about 2.5 median point spacings ``s`` wide (in the fit
  frame, diagonal 2): ``round(2 / (2.5 s)) + 1``, clipped to 32-128 (``pointcloud.auto_grid``), as
  the finest level of an adaptive band whose voxels coarsen up to 32^3 wherever the surface is flat
  (``generators.AdaptiveBand``; the learned model takes a uniform grid of at most 64); it never warns. An explicit grid above ``pointcloud.max_supported_grid(s) = int(2 / s) + 1`` (voxels
  narrower than one spacing) still runs, with a ``UserWarning``: between the points the surface then
  comes from the smooth target alone, and no finer grid adds detail the points do not hold.
- **cost:** the fit samples ``150 g²`` surface points and optimises the corners of the voxels they
  fall in (also about ``g²``), so time and memory grow about as ``g²``: 128 is practical, 256 slow.
  The learned model (``method="learned"``) was trained at 32 and 64.
- **a cloud of more than 2 million points** is reconstructed from a uniform subset of a million
  (at the target's resolution the rest add nothing), its fit in tiles run by a local process pool
  or by Ray (``engine=``, ``workers=``; :mod:`voro3d.pointcloud.tiles`): one closed mesh either way.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._validate import MESH_AUTO_GRID, as_points, finite_rows, grid_option, mesh_grid, method_options, positive_int, trusted
from .pointcloud.plan import as_plan
from .pointcloud.reconstruct import METHODS, MIN_POINTS
from .pointcloud.preprocess import check_stride
from .pointcloud.tiles import ENGINES, analysis_subset
from .pointcloud.tuning import MAX_HULL_VOLUME, MAX_MEDIAN_DISTANCE, SEPARATE_POINTS

__all__ = ["reconstruct", "VoroMeshStage"]

def reconstruct(geometry, grid="auto", *, method: str = "fit", steps: int | None = None, seed: int | None = None,
                device: str | None = None, model=None, threads: int | None = None, plan=None,
                allow_open: bool = False, clean: bool = True, engine: str = "local", workers: int | None = None,
                progress: bool = False):
    """Watertight VoroMesh surface of a point cloud or mesh.

    Parameters
    ----------
    geometry : open3d.geometry.PointCloud, open3d.geometry.TriangleMesh, their ``open3d.t``
        versions, a ``(vertices, triangles)`` pair, (n, 3) or (n, 6) float array (points, or
        points then normals), or a path to a mesh or point-cloud file.
        Point clouds use their normals when they have them, checked (zero or NaN ones repaired
        from their neighbours, or past half ours estimated instead; signs that disagree between
        neighbours re-oriented; normals that all point inward flipped); otherwise normals are
        estimated and oriented.
        Repeated points are merged; objects far apart are reconstructed one by one
        (:func:`voro3d.pointcloud.separate_objects`).
    grid : int or "auto"
        Grid resolution ``g`` (``g^3`` nodes over the shape's bounding box), at least 4, no
        upper limit. ``"auto"``: for a mesh, 32 (:data:`MESH_AUTO_GRID`: a mesh has no point
        spacing to go by); for a cloud, the finest voxels about 2.5 median point spacings wide,
        clipped to 32-128 (:func:`voro3d.pointcloud.auto_grid`), coarser where the surface is flat
        (an adaptive band, :class:`voro3d.generators.AdaptiveBand`); an int is a uniform grid. A cloud's grid finer than
        :func:`voro3d.pointcloud.max_supported_grid` (voxels narrower than one spacing) works
        and warns: the surface between the points then comes from the smooth target alone.
        Time and memory grow about as ``g^2`` (``150 g^2`` surface samples for a mesh, ``75 g^2``
        for a cloud): 128 is practical, 256 slow. The learned model was trained at 32 and 64.
    method : {"fit", "learned"}
        Direct optimisation (seconds) or the shipped ONNX network (fast, needs no torch).
    steps, seed, device : int, int, str, optional
        The fit's Adam steps, seed and torch device (defaults 400 steps for a mesh, 120 for a
        cloud, whose mesh is fitted to its target afterwards (``pointcloud.tuning.CLOUD_STEPS``),
        seed 0, ``"cpu"``). ``method="learned"`` uses none of them and refuses them.
    model : str or os.PathLike, optional
        ``method="learned"``: an ONNX model of ``voro3d export-onnx``; default the shipped one.
    threads : int, optional
        Threads of the fit's CPU kernel or of onnxruntime; default every CPU the process may use.
        With 1, a large cloud's Poisson target is not solved in a second process either (the same
        mesh, solved in turn).
    plan : voro3d.pointcloud.CloudPlan, dict or None
        Point clouds: what to do with them (:class:`voro3d.pointcloud.CloudPlan`): ``normals``
        (``"check"`` the given ones, ``"trust"`` them, or ``"estimate"``), ``denoise`` (the pass
        that moves noisy points onto their smooth surface), ``filter`` (of a Poisson target),
        ``target`` (``"poisson"``, ``"imls"`` or ``"sheet"``) and ``hull`` (``"on"``: the target
        cut back to the points' convex hull, which ``"auto"`` does for one-sided scans); a dict may set some, e.g.
        ``plan={"denoise": "off"}``. Fields left ``"auto"`` (all, by default) are decided from the
        cloud; ``progress`` prints the plan chosen. Meshes: must stay None.
    allow_open : bool
        Meshes: accept one with boundary edges, its inside decided by generalized winding number
        (:class:`voro3d.queries.InsideOutside`). Point clouds need no such flag (open scans are
        what they are) and refuse it.
    clean : bool
        Remove slivers, tiny faces and nearly coincident vertices (:func:`voro3d.cleaning.clean`),
        then fit the vertices, at most a quarter voxel each, to the input mesh or the cloud's
        smooth target surface (:func:`voro3d.snapping.snap_to_surface`), every guarantee kept;
        ``False`` keeps the Voronoi faces as they are.
    engine : {"local", "ray"}
        Point clouds of more than 2 million points (``pointcloud.tuning.TILE_POINTS``) are
        reconstructed from a uniform subset of a million, their fit in tiles
        (:mod:`voro3d.pointcloud.tiles`): in a local process pool, or as Ray tasks
        (``pip install 'voro3d[ray]'``; a local Ray is started unless one is running). The mesh is
        the same either way.
    workers : int, optional
        Tiles fitted at once; default one per CPU.
    progress : bool
        Show a progress bar over the fit's steps (the learned method has no loop to show) and,
        for a point cloud, one line on stderr per phase with what it chose and its time.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Closed, manifold, outward-oriented, in the input's coordinates. A cloud with colours
        gives vertex colours (inverse-distance mean of the nearest points' colours), on the mesh
        split flat until it has about one vertex per point (:func:`voro3d.pointcloud.colored_mesh`:
        the same surface, up to 64x the faces).

    Raises
    ------
    ValueError
        Empty or too small cloud (< 100 points; points with NaN or inf coordinates are left out,
        with a warning), all points coplanar, coordinates rounded coarser than the points' spacing
        (float32 far from the origin), more than 1% of the given normals unusable, a cloud
        of outliers only (it fills a volume), normals not estimable, an unknown method, an option
        the method does not use (``steps``, ``seed`` or ``device`` with ``method="learned"``), a
        ``plan`` given for a mesh or not a plan, or a non-watertight input mesh.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    options = method_options(method, "fit", steps=steps, seed=seed, device=device)
    options.update(method_options(method, "learned", model=model), threads=threads)
    grid = grid_option(grid)
    cloud_plan = as_plan(plan)
    kind, data = _read(geometry)
    if kind == "mesh":
        if plan is not None:
            raise ValueError("plan applies to point clouds only; a mesh input takes plan=None")
    elif allow_open:
        raise ValueError("allow_open applies to meshes only; a point cloud may be open as it is")
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    tiling = dict(engine=engine, workers=None if workers is None else positive_int(workers, "workers"))
    # The input was checked by _read: the stages below trust it.
    with trusted():
        if kind == "mesh":
            return _mesh_to_mesh(data, mesh_grid(grid), method, options,
                                 allow_open=allow_open, clean=clean, progress=progress)
        return _cloud_to_mesh(*data, grid, method, options | tiling, plan=cloud_plan, clean=clean, progress=progress)


def _mesh_to_mesh(mesh, grid: int, method: str, options: dict, *, allow_open: bool, clean: bool, progress: bool):
    """A mesh's VoroMesh by the fit or the learned model, cleaned and fitted to the mesh."""
    if method == "fit":
        from .fitting import fit

        shape = fit(mesh, grid, allow_open=allow_open, progress=progress, **options)[0]
    else:
        from .infer import predict_from_mesh

        shape = predict_from_mesh(mesh, grid, allow_open=allow_open, **options)
    return shape.to_open3d(clean=clean, surface=mesh if clean else None)


def _cloud_to_mesh(points, normals, colors, grid, method: str, options: dict, *, plan, clean: bool,
                   progress: bool):
    """A cloud's mesh, object by object (:func:`voro3d.pointcloud.separate_objects`), checked against its points."""
    import open3d as o3d

    from .pointcloud import cloud_mesh, colored_mesh, reconstruct_points
    from .pointcloud.reconstruct import report_phase

    mesh = o3d.geometry.TriangleMesh()
    # Objects far apart are reconstructed one by one, each at its own grid; their meshes lie in
    # disjoint boxes, so together they are still closed and free of crossings.
    groups = _objects(points)
    for number, group in enumerate(groups):
        if len(groups) > 1:
            report_phase(progress, "object", f"{number + 1} of {len(groups)} far apart: {len(group):,} points")
        shape, target, info = reconstruct_points(points[group], None if normals is None else normals[group],
                                                 grid=grid, method=method, plan=plan, progress=progress,
                                                 **options)
        piece = cloud_mesh(shape, target, clean=clean, progress=progress)
        subset = analysis_subset(len(group), 0)
        _check_fit(piece, points[group if subset is None else group[subset]], info.voxel, info.offset)
        if colors is not None:
            piece = colored_mesh(piece, points[group], colors[group])
        mesh += piece
    return mesh


def _objects(points) -> list:
    """:func:`~voro3d.pointcloud.separate_objects`; on more than ``SEPARATE_POINTS`` points, of every
    k-th (at most that many), each point then in its nearest subset point's object (the pieces of a
    neighbour graph, far apart, are the same)."""
    from scipy.spatial import cKDTree

    from .pointcloud import separate_objects

    if len(points) <= SEPARATE_POINTS:
        return separate_objects(points, min_points=MIN_POINTS)
    subset = points[:: -(-len(points) // SEPARATE_POINTS)]
    groups = separate_objects(subset, min_points=max(1, MIN_POINTS * len(subset) // len(points)))
    if len(groups) == 1:
        return [np.arange(len(points))]
    label = np.empty(len(subset), np.int64)
    for number, group in enumerate(groups):
        label[group] = number
    nearest = label[cKDTree(subset).query(points, workers=-1)[1]]
    groups = [np.flatnonzero(nearest == number) for number in range(len(groups))]
    return groups if min(map(len, groups)) >= MIN_POINTS else [np.arange(len(points))]


class VoroMeshStage:
    """A pipeline stage: ``stage(geometry) -> TriangleMesh``, set up once, called many times.

    Parameters are those of :func:`reconstruct`, checked here, once. With ``method="learned"``
    the ONNX session is loaded on the first call and kept.

    Examples
    --------
    >>> steps = [lambda p: p.voxel_down_sample(0.01), VoroMeshStage(grid=64)]  # doctest: +SKIP
    """

    def __init__(self, grid="auto", *, method: str = "fit", steps: int | None = None, seed: int | None = None,
                 device: str | None = None, model=None, threads: int | None = None, plan=None,
                 allow_open: bool = False, clean: bool = True, engine: str = "local", workers: int | None = None,
                 progress: bool = False):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        if engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
        options = method_options(method, "fit", steps=steps, seed=seed, device=device)
        options.update(method_options(method, "learned", model=model))
        if threads is not None:
            options["threads"] = positive_int(threads, "threads")
        if workers is not None:
            options["workers"] = positive_int(workers, "workers")
        grid = grid_option(grid)
        self.options = dict(grid=grid, method=method, plan=None if plan is None else as_plan(plan),
                            allow_open=bool(allow_open), clean=bool(clean), engine=engine, progress=progress,
                            **options)

    def __call__(self, geometry):
        return reconstruct(geometry, **self.options)

    def __repr__(self) -> str:
        return "VoroMeshStage(" + ", ".join(f"{k}={v!r}" for k, v in self.options.items()) + ")"


def _check_fit(mesh, points, voxel: float, offset: float = 0.0) -> None:
    """Refuse a cloud's mesh that is far off its points (``MAX_HULL_VOLUME``, ``MAX_MEDIAN_DISTANCE``
    voxels beyond the ``offset`` its target keeps from them by design, ``PointCloudInfo.offset``),
    read from at most ``CHECK_POINTS`` of them, evenly."""
    import open3d as o3d
    from scipy.spatial import ConvexHull

    from .geometry import centred_scene
    from .watertight import signed_volume

    points = points[::check_stride(len(points))]
    ratio = signed_volume(np.asarray(mesh.vertices), np.asarray(mesh.triangles)) / ConvexHull(points).volume
    if ratio > MAX_HULL_VOLUME:
        raise ValueError(f"the reconstructed surface encloses {ratio:.1f} times the volume of the points' convex hull: "
                         "it balloons around the points instead of following them (normals that point every which way?)")
    # A distance needs no inside (nor the edge counts InsideOutside would make); about the mesh's
    # centre, as Open3D's float32 would be 0.5 off at 5e6 (georeferenced scans).
    scene, origin = centred_scene(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    distance = scene.compute_distance(o3d.core.Tensor((points - origin).astype(np.float32))).numpy()
    distance = (float(np.median(distance)) - offset) / voxel
    if distance > MAX_MEDIAN_DISTANCE:
        raise ValueError(f"the reconstructed surface lies {distance:.1f} voxels from the median point: it does not follow "
                         "the points")


def _read(geometry):
    """('mesh', (vertices, triangles)) or ('points', (points, normals or None, colours or None)), checked."""
    import open3d as o3d

    if isinstance(geometry, (str, Path)):
        path = Path(geometry)
        from .io import MESH_SUFFIXES, load_mesh, load_points, mesh_arrays

        if not path.exists():
            raise FileNotFoundError(f"no such file: {path}")
        if path.suffix.lower() in MESH_SUFFIXES:
            try:
                return "mesh", mesh_arrays(load_mesh(path))
            except ValueError as error:
                if "no triangles" not in str(error) or path.suffix.lower() != ".ply":
                    raise
        geometry = load_points(path)
    if isinstance(geometry, o3d.t.geometry.TriangleMesh):
        geometry = geometry.to_legacy()
    if isinstance(geometry, o3d.t.geometry.PointCloud):
        geometry = geometry.to_legacy()
    if isinstance(geometry, o3d.geometry.TriangleMesh) or (isinstance(geometry, tuple) and len(geometry) == 2):
        from .io import mesh_arrays

        return "mesh", mesh_arrays(geometry)
    colors = None
    if isinstance(geometry, o3d.geometry.PointCloud):
        points = np.asarray(geometry.points)
        normals = np.asarray(geometry.normals) if geometry.has_normals() else None
        colors = np.asarray(geometry.colors) if geometry.has_colors() else None
    else:
        try:
            array = np.asarray(geometry, np.float64)
        except (TypeError, ValueError):
            raise ValueError("geometry must be an Open3D point cloud or triangle mesh, a (vertices, triangles) pair, "
                             f"an (n, 3) or (n, 6) array or a file path, got {type(geometry).__name__}") from None
        if array.ndim == 2 and array.shape[1] == 6:
            points, normals = array[:, :3], array[:, 3:]
        else:
            points, normals = array, None
    array = np.asarray(points)
    if array.ndim == 2 and array.shape[1] == 3 and np.issubdtype(array.dtype, np.number):
        keep = finite_rows(array, "points", stacklevel=4)
        if keep is not None:
            points = array[keep]
            # An Open3D cloud's normals and colours count as present only at the points' length, as an (n, 6) array's.
            normals, colors = (None if a is None else a[keep] for a in (normals, colors))
    points = as_points(points, "points", min_count=0)
    if colors is not None:
        colors = np.asarray(colors, np.float64)
        if colors.shape != points.shape or not np.isfinite(colors).all():
            raise ValueError(f"colors must be finite with shape {points.shape}, got {colors.shape}")
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != points.shape or not np.issubdtype(normals.dtype, np.number):
            raise ValueError(f"normals must be a numeric array of shape {points.shape}, got {normals.dtype} "
                             f"{normals.shape}")
    from .pointcloud import merge_duplicates

    given = points.shape[0]
    points, normals, colors = merge_duplicates(points, None if normals is None else normals.astype(np.float64), colors)
    if points.shape[0] < MIN_POINTS:
        repeats = f" ({given - points.shape[0]} duplicated points merged)" if given > points.shape[0] else ""
        raise ValueError(f"point cloud has {points.shape[0]} distinct points{repeats}; at least {MIN_POINTS} are needed")
    _check_not_flat(points)
    _check_resolved(points)
    return "points", (points, normals, colors)


def _check_not_flat(points) -> None:
    """Refuse points that all lie in one plane (or on one line): they enclose no volume."""
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred[:: max(1, points.shape[0] // 20000)], compute_uv=False)
    if singular[2] <= 1e-9 * singular[0]:
        raise ValueError("all points are coplanar (or collinear): a flat cloud encloses no volume")


# Coarsest step between a coordinate's distinct values, over the spacing the points would have on a surface as wide as
# their box (its largest side / sqrt(n)), that still holds a surface. A surface sampled on a voxel lattice reads up to
# 2.4 (its step is its spacing); clouds sampled from the 38 dev meshes (300-10^5 points) 0.08 at most, the four real
# scans 0.02. The bunny (20k points) at UTM coordinates stored as float32, whose steps are 1/32 in x and 1/4 in y,
# reads 3.3 at 11 m wide (CD 1.36 against 0.64 unrounded, NC 0.945), 4.6 at 7.8 m (CD 7.1, NC 0.74: layers, not a
# surface), 23.6 at 1.6 m (CD 130) and 141 at 0.16 m (a marching-cubes error, before this check).
MAX_COORDINATE_STEP = 4.0


def _check_resolved(points) -> None:
    """Refuse points whose coordinates were rounded coarser than the surface they sample (float32 coordinates far
    from the origin keep about 7 digits): they lie in layers, not on a surface."""
    sample = points[:: max(1, points.shape[0] // 200_000)]
    spacing = np.ptp(sample, axis=0).max() / np.sqrt(len(sample))
    for axis, values in enumerate(sample.T):
        distinct = np.unique(values)
        step = float(np.median(np.diff(distinct)))
        if step > MAX_COORDINATE_STEP * spacing:
            raise ValueError(f"the points' {'xyz'[axis]} coordinates take only {len(distinct):,} distinct values, "
                             f"{step:.3g} apart, coarser than the points' spacing (about {spacing:.2g}): their precision "
                             "was lost (float32 coordinates far from the origin keep about 7 digits; subtract an offset "
                             "before storing them)")
