"""Reading and writing meshes, point clouds and polygon meshes, atomically; Open3D <-> arrays.

VoroMesh files are :meth:`voro3d.VoroMesh.save`'s, SDF grids plain ``.npy``/``.npz``
(``voro3d predict``); normalisation frames live in :mod:`voro3d.frames`.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np

from ._validate import as_points, finite_rows, is_trusted
from .geometry import vertex_normals

__all__ = ["MESH_SUFFIXES", "POINT_SUFFIXES", "POINT_WRITE_SUFFIXES", "POLYGON_SUFFIXES", "atomic_path", "load_mesh", "load_points",
           "mesh_arrays", "save_mesh", "save_points", "save_polygons", "to_triangle_mesh"]

# Vertices closer than this fraction of the bounding-box diagonal are one vertex. Files repeat a
# position bit-for-bit at OBJ UV seams and in STL triangle soups, so a tiny tolerance suffices and
# never merges genuinely distinct vertices.
MERGE_TOLERANCE = 1e-9

MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
POINT_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pwn", ".pts", ".npy")
# Plain text, one point a line: x y z, or x y z nx ny nz (CGAL's and Poisson's .pwn; .xyz either way).
TEXT_POINT_SUFFIXES = (".xyz", ".pwn")
POLYGON_SUFFIXES = (".ply", ".obj", ".off")
# Point-cloud formats save_points writes, normals included (Open3D's .pts and .xyzrgb carry none).
POINT_WRITE_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".pwn", ".npy")


@contextlib.contextmanager
def atomic_path(path, *, suffix: str | None = None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    A crash, an exception or Ctrl-C leaves no half-written file at ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix or path.suffix, dir=path.parent)
    os.close(handle)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def _quiet():
    """Silence Open3D's own warnings; every failure is turned into one exception here instead."""
    import open3d as o3d

    return o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error)


def _existing_file(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    if not path.is_file():
        raise ValueError(f"{path} is not a file")
    return path


def mesh_arrays(mesh, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a mesh, validated.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh, open3d.t.geometry.TriangleMesh or (vertices, triangles)
        ``vertices`` ``(v, 3)`` float, ``triangles`` ``(t, 3)`` integer indices into ``vertices``.
    name : str
        Argument name used in error messages.

    Returns
    -------
    vertices : (v, 3) float64
    triangles : (t, 3) int64, ``t >= 1``

    Raises
    ------
    ValueError
        No triangles, indices out of range, or NaN/inf vertices.
    TypeError
        ``mesh`` is none of the accepted kinds.
    """
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        vertices, triangles = mesh
    elif hasattr(mesh, "vertex") and hasattr(mesh, "triangle"):  # open3d.t.geometry.TriangleMesh
        if "positions" not in mesh.vertex or "indices" not in mesh.triangle:
            raise ValueError(f"{name} has no triangles")
        vertices, triangles = mesh.vertex.positions.numpy(), mesh.triangle.indices.numpy()
    elif hasattr(mesh, "vertices") and hasattr(mesh, "triangles"):
        vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    else:
        raise TypeError(f"{name} must be an open3d TriangleMesh or (vertices, triangles), got {type(mesh).__name__}")
    if is_trusted():
        return np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(triangles, dtype=np.int64)
    triangles = np.asarray(triangles)
    if triangles.size == 0:
        raise ValueError(f"{name} has no triangles")
    vertices = as_points(vertices, f"{name} vertices", min_count=3)
    if not np.issubdtype(triangles.dtype, np.integer) or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise ValueError(f"{name} triangles must be an integer array of shape (t, 3), "
                         f"got {triangles.dtype} {triangles.shape}")
    if triangles.min() < 0 or triangles.max() >= vertices.shape[0]:
        raise ValueError(f"{name} triangles index vertices outside [0, {vertices.shape[0]})")
    return vertices, np.ascontiguousarray(triangles, dtype=np.int64)


def to_triangle_mesh(vertices: np.ndarray, triangles: np.ndarray, *, normals: bool = False):
    """``open3d.geometry.TriangleMesh`` from ``(v, 3)`` float vertices and ``(t, 3)`` int triangles.

    Parameters
    ----------
    vertices : (v, 3) float
    triangles : (t, 3) int
    normals : bool, keyword-only
        Also set area-weighted vertex normals (:func:`voro3d.geometry.vertex_normals`); default none.
    """
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(vertices, np.float64)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(triangles, np.int32)),
    )
    if normals:
        # Area-weighted, as Open3D's compute_vertex_normals, which takes 0.7 s at 2e5 triangles here.
        mesh.vertex_normals = o3d.utility.Vector3dVector(vertex_normals(vertices, triangles))
    return mesh


def load_mesh(path, *, weld: bool = True):
    """Read a triangle mesh and weld it so that watertightness reflects topology.

    Any format Open3D reads works (``.ply .obj .off .stl .glb .gltf``). Vertices that coincide
    within ``MERGE_TOLERANCE`` times the bounding-box diagonal are merged (OBJ files split vertices
    at UV seams, STL files store triangle soups); triangles that repeat a vertex, repeated triangles
    (same vertices, same cyclic order) and unreferenced vertices are removed. Zero-area triangles
    with three distinct vertices are kept, since dropping them could open the surface. Texture
    coordinates, colours and file normals are dropped: they would no longer match the vertices.

    Parameters
    ----------
    path : str or os.PathLike
    weld : bool, keyword-only
        Merge coincident vertices (default). Pass False to read a mesh as written, e.g. a
        VoroMesh whose sheets touch at deliberately duplicated vertices.

    Returns
    -------
    open3d.geometry.TriangleMesh
        Float64 vertices in the file's units, without normals.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        The file could not be read, holds no triangles, or has NaN/inf vertices.
    """
    import open3d as o3d

    path = _existing_file(path)
    with _quiet():
        raw = o3d.io.read_triangle_mesh(str(path))
    n_vertices, n_triangles = len(raw.vertices), len(raw.triangles)
    if n_vertices == 0:
        raise ValueError(f"{path} could not be read as a triangle mesh (unsupported or corrupt file, or empty)")
    if n_triangles == 0:
        raise ValueError(f"{path} has no triangles ({n_vertices} vertices only)")
    vertices, triangles = mesh_arrays(raw, name=str(path))
    mesh = to_triangle_mesh(vertices, triangles)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    with _quiet():
        if weld:
            mesh.merge_close_vertices(MERGE_TOLERANCE * diagonal)
        mesh.remove_degenerate_triangles()
        mesh.remove_duplicated_triangles()
        mesh.remove_unreferenced_vertices()
    if len(mesh.triangles) == 0:
        raise ValueError(f"{path} has no triangles (all {n_triangles} are degenerate)")
    return mesh


def _text_points(path) -> np.ndarray:
    """(n, c) float64 from whitespace-separated text; a first line of one number (a count) is skipped."""
    with open(path) as stream:
        skip = int(len(stream.readline().split()) == 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data": refused by the caller
        return np.loadtxt(path, dtype=np.float64, ndmin=2, skiprows=skip, comments="#")


def load_points(path):
    """Read a point cloud, with normals when the file has them.

    Parameters
    ----------
    path : str or os.PathLike
        ``.ply .pcd .xyzn .xyzrgb .pts`` (via Open3D); ``.xyz`` or ``.pwn`` text, one point a line,
        ``x y z`` or ``x y z nx ny nz`` (the first line may hold the point count); or ``.npy``
        holding an ``(n, 3)`` array of positions or an ``(n, 6)`` array of positions then normals.

    Returns
    -------
    open3d.geometry.PointCloud
        Float64 points in the file's units; ``normals`` set if the file holds them.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        The file could not be read, holds no points, has the wrong shape, or NaN/inf positions
        only; some are left out with a warning (an organized scan's empty pixels), normals are
        passed as they are.
    """
    import open3d as o3d

    path = _existing_file(path)
    suffix = path.suffix.lower()
    if suffix not in POINT_SUFFIXES:
        raise ValueError(f"{path} is not a point cloud file: readable formats are {', '.join(POINT_SUFFIXES)}")
    if suffix == ".npy" or suffix in TEXT_POINT_SUFFIXES:
        try:
            array = np.load(path, allow_pickle=False) if suffix == ".npy" else _text_points(path)
        except (ValueError, OSError, EOFError) as error:
            raise ValueError(f"{path} could not be read as {'a .npy array' if suffix == '.npy' else 'x y z lines'}: {error}") from None
        if array.size == 0:
            raise ValueError(f"{path} holds no points")
        if array.ndim != 2 or array.shape[1] not in (3, 6):
            raise ValueError(f"{path} could not be read: it must hold an array of shape (n, 3) or (n, 6), got {array.shape}")
        keep = finite_rows(array[:, :3], str(path))
        array = array if keep is None else array[keep]
        # Normals pass as they are: zero or NaN ones (scanners write them) are repaired
        # from their neighbours by the reconstruction, which names the problem when there are many.
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(as_points(array[:, :3], str(path))))
        if array.shape[1] == 6:
            cloud.normals = o3d.utility.Vector3dVector(array[:, 3:])
        return cloud
    with _quiet():
        cloud = o3d.io.read_point_cloud(str(path))
    if len(cloud.points) == 0:
        raise ValueError(f"{path} could not be read as a point cloud (corrupt or empty; formats: {', '.join(POINT_SUFFIXES)})")
    if finite_rows(np.asarray(cloud.points), str(path)) is not None:
        cloud.remove_non_finite_points()  # its normals and colours alike, whatever their own values
    as_points(np.asarray(cloud.points), str(path))
    return cloud


def save_mesh(mesh, path) -> Path:
    """Write a mesh atomically (temporary file beside ``path``, then rename).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or (vertices, triangles)
    path : str or os.PathLike
        The suffix picks the format: ``.ply .obj .off .stl .glb .gltf``. The temporary file keeps
        the suffix because Open3D chooses its writer by extension.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        Unsupported suffix, a mesh without triangles, or the writer failed.
    """
    import open3d as o3d

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"path must end in one of {', '.join(MESH_SUFFIXES)}, got {path.name!r}")
    vertices, triangles = mesh_arrays(mesh)
    with atomic_path(path, suffix=suffix) as tmp:
        if suffix == ".glb":
            # Open3D 0.20 writes .glb files that neither it nor trimesh can read back.
            import trimesh

            trimesh.Trimesh(vertices, triangles, process=False).export(tmp)
            ok = True
        else:
            if isinstance(mesh, o3d.geometry.TriangleMesh):
                out = o3d.geometry.TriangleMesh(mesh)
            else:
                out = to_triangle_mesh(vertices, triangles)
            if suffix == ".stl":
                out.compute_triangle_normals()  # the STL writer refuses meshes without them
            with _quiet():
                ok = o3d.io.write_triangle_mesh(tmp, out)
        if not ok:
            raise ValueError(f"writing {path} failed")
    return path


def save_points(points, path, *, normals=None) -> Path:
    """Write a point cloud atomically; the suffix picks the format (:data:`POINT_WRITE_SUFFIXES`).

    Parameters
    ----------
    points : (n, 3) float
    path : str or os.PathLike
        ``.npy`` holds (n, 3), or (n, 6) with normals; ``.xyz``/``.pwn`` are text, with normals
        when given; the others are written by Open3D.
    normals : (n, 3) float, optional

    Returns
    -------
    pathlib.Path
    """
    import open3d as o3d

    points = as_points(points, "points")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in POINT_WRITE_SUFFIXES:
        raise ValueError(f"path must end in one of {', '.join(POINT_WRITE_SUFFIXES)}, got {path.name!r}")
    columns = points if normals is None else np.hstack([points, as_points(normals, "normals")])
    with atomic_path(path, suffix=suffix) as tmp:
        if suffix == ".npy":
            np.save(tmp, columns)
        elif suffix in TEXT_POINT_SUFFIXES:
            np.savetxt(tmp, columns, fmt="%.9g")
        else:
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            if normals is not None:
                cloud.normals = o3d.utility.Vector3dVector(columns[:, 3:])
            if not o3d.io.write_point_cloud(str(tmp), cloud):
                raise ValueError(f"Open3D could not write {path.name!r}")
    return path


def save_polygons(polygons, path) -> Path:
    """Write a polygon mesh (e.g. :func:`voro3d.extract.voronoi_polygons`) atomically.

    Parameters
    ----------
    polygons : (vertices, faces)
        ``vertices`` ``(v, 3)`` float, ``faces`` a sequence of integer index arrays of at least 3
        corners each, in order.
    path : str or os.PathLike
        ``.ply`` (binary little-endian, a ``vertex_indices`` list per face, at most 255 corners),
        ``.obj`` or ``.off``.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        Unsupported suffix, no faces, a face of fewer than 3 corners, or an index outside ``vertices``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in POLYGON_SUFFIXES:
        raise ValueError(f"path must end in one of {', '.join(POLYGON_SUFFIXES)}, got {path.name!r}")
    vertices, faces = polygons
    vertices = as_points(vertices, "polygons vertices")
    faces = [np.asarray(face) for face in faces]
    if not faces:
        raise ValueError("polygons has no faces")
    if any(face.ndim != 1 or face.size < 3 for face in faces):
        raise ValueError("polygons faces must be 1-D index arrays of at least 3 corners each")
    sizes = np.array([face.size for face in faces])
    corners = np.concatenate(faces)
    if not np.issubdtype(corners.dtype, np.integer) or corners.min() < 0 or corners.max() >= vertices.shape[0]:
        raise ValueError(f"polygons faces must index vertices in [0, {vertices.shape[0]})")
    with atomic_path(path, suffix=suffix) as tmp, open(tmp, "wb") as handle:
        if suffix == ".ply":
            if sizes.max() > 255:
                raise ValueError(f"polygons faces must have at most 255 corners for .ply, got {sizes.max()}")
            header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {vertices.shape[0]}\n"
                      "property double x\nproperty double y\nproperty double z\n"
                      f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
            handle.write(header.encode("ascii"))
            handle.write(vertices.astype("<f8").tobytes())
            # Each face: its corner count as one byte, then its corners as little-endian int32.
            rows = np.empty(len(faces) + 4 * corners.size, np.uint8)
            starts = np.cumsum(np.r_[0, 1 + 4 * sizes[:-1]])
            rows[starts] = sizes
            corner_bytes = np.ones(rows.size, bool)
            corner_bytes[starts] = False
            rows[corner_bytes] = corners.astype("<i4").view(np.uint8)
            handle.write(rows.tobytes())
        elif suffix == ".obj":  # 1-based indices
            lines = ["v " + " ".join(map(repr, row)) for row in vertices.tolist()]
            lines += ["f " + " ".join(map(str, (face + 1).tolist())) for face in faces]
            handle.write(("\n".join(lines) + "\n").encode("ascii"))
        else:
            lines = ["OFF", f"{vertices.shape[0]} {len(faces)} 0"] + [" ".join(map(repr, row)) for row in vertices.tolist()]
            lines += [f"{face.size} " + " ".join(map(str, face.tolist())) for face in faces]
            handle.write(("\n".join(lines) + "\n").encode("ascii"))
    return path
