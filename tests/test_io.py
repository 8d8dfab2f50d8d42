"""Tests for voro3d.io: mesh and point-cloud reading, atomic writing, normalisation frames."""
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from voro3d.frames import NormalizationFrame, fit_frame, ndc_frame
from voro3d.io import load_mesh, load_points, mesh_arrays, save_mesh, save_polygons, to_triangle_mesh
from voro3d.topology import open_edge_count



@pytest.fixture
def sphere():
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=0.7, resolution=12)
    return to_triangle_mesh(np.asarray(mesh.vertices) + [0.1, -0.2, 0.3], np.asarray(mesh.triangles))


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# -- load_mesh / save_mesh ------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".ply", ".obj", ".off", ".stl", ".glb"])
def test_save_then_load_round_trip(tmp_path, sphere, suffix):
    path = save_mesh(sphere, tmp_path / f"sphere{suffix}")
    loaded = load_mesh(path)
    vertices, triangles = mesh_arrays(loaded)
    assert len(loaded.triangles) == len(sphere.triangles)
    # STL stores a triangle soup; welding on load restores the shared vertices and closedness.
    assert len(loaded.vertices) == len(sphere.vertices)
    assert open_edge_count(vertices, triangles) == 0
    np.testing.assert_allclose(np.sort(vertices, axis=0), np.sort(np.asarray(sphere.vertices), axis=0), atol=1e-5)
    assert [p.name for p in tmp_path.iterdir()] == [f"sphere{suffix}"]  # no temporary left behind


def test_save_accepts_arrays_and_overwrites_atomically(tmp_path, sphere):
    path = tmp_path / "nested" / "out.ply"
    save_mesh((np.asarray(sphere.vertices), np.asarray(sphere.triangles)), path)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="no triangles"):
        save_mesh((np.zeros((3, 3)), np.zeros((0, 3), int)), path)
    assert path.read_bytes() == before  # a failed save leaves the old file intact
    assert sorted(p.name for p in path.parent.iterdir()) == ["out.ply"]


def test_save_rejects_unknown_suffix(tmp_path, sphere):
    with pytest.raises(ValueError, match="path must end in one of"):
        save_mesh(sphere, tmp_path / "mesh.xyz")
    assert not list(tmp_path.iterdir())


def test_load_merges_obj_seam_duplicates(tmp_path):
    # A tetrahedron whose vertex 0 is repeated (as at a UV seam) and one duplicated face.
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 0 0 0\n"
            "f 1 3 2\nf 5 2 4\nf 1 4 3\nf 2 3 4\nf 2 3 4\n")
    mesh = load_mesh(write(tmp_path / "seam.obj", text))
    assert len(mesh.vertices) == 4
    assert len(mesh.triangles) == 4
    assert open_edge_count(*mesh_arrays(mesh)) == 0


def test_load_drops_degenerate_triangles(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\nf 1 1 2\n"
    assert len(load_mesh(write(tmp_path / "degenerate.obj", text)).triangles) == 4


def test_load_missing_file_names_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing_here.ply"):
        load_mesh(tmp_path / "nothing_here.ply")


def test_load_directory_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="is not a file"):
        load_mesh(tmp_path)


@pytest.mark.parametrize("name, text", [
    ("garbage.ply", "this is not a ply file\n"),
    ("empty.obj", ""),
    ("unknown.abc", "v 0 0 0\n"),
])
def test_load_unreadable_file(tmp_path, name, text):
    with pytest.raises(ValueError, match="could not be read"):
        load_mesh(write(tmp_path / name, text))


def test_load_points_only_ply_has_no_triangles(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(ValueError, match="has no triangles"):
        load_mesh(write(tmp_path / "cloud.ply", text))


def test_load_all_degenerate_has_no_triangles(tmp_path):
    # Only repeated indices count as degenerate: a zero-area triangle with three distinct vertices
    # still carries topology and is kept.
    with pytest.raises(ValueError, match="has no triangles"):
        load_mesh(write(tmp_path / "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 2\nf 3 3 1\n"))


def test_load_nan_vertices(tmp_path):
    text = "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\n"
    with pytest.raises(ValueError, match="NaN or inf"):
        load_mesh(write(tmp_path / "nan.obj", text))


# -- mesh_arrays ----------------------------------------------------------------------------------

def test_mesh_arrays_accepts_tensor_mesh(sphere):
    vertices, triangles = mesh_arrays(o3d.t.geometry.TriangleMesh.from_legacy(sphere))
    assert vertices.dtype == np.float64 and triangles.dtype == np.int64
    np.testing.assert_array_equal(triangles, np.asarray(sphere.triangles))


@pytest.mark.parametrize("mesh, error, match", [
    ((np.zeros((4, 3)), np.zeros((0, 3), int)), ValueError, "pred has no triangles"),
    ((np.zeros((4, 3)), np.array([[0, 1, 4]])), ValueError, "outside"),
    ((np.zeros((4, 3)), np.array([[0.0, 1.0, 2.0]])), ValueError, "integer array"),
    ((np.zeros((4, 2)), np.array([[0, 1, 2]])), ValueError, r"shape \(n, 3\)"),
    ("mesh.ply", TypeError, "pred must be"),
])
def test_mesh_arrays_errors(mesh, error, match):
    with pytest.raises(error, match=match):
        mesh_arrays(mesh, "pred")


# -- load_points ----------------------------------------------------------------------------------

def test_load_points_npy_with_and_without_normals(tmp_path):
    rng = np.random.default_rng(0)
    points, normals = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    np.save(tmp_path / "p.npy", points)
    np.save(tmp_path / "pn.npy", np.hstack([points, normals]))
    cloud = load_points(tmp_path / "p.npy")
    assert not cloud.has_normals()
    np.testing.assert_array_equal(np.asarray(cloud.points), points)
    cloud = load_points(tmp_path / "pn.npy")
    np.testing.assert_array_equal(np.asarray(cloud.normals), normals)


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".xyz", ".xyzn"])
def test_load_points_open3d_formats(tmp_path, suffix):
    rng = np.random.default_rng(1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.normal(size=(40, 3))))
    cloud.normals = o3d.utility.Vector3dVector(rng.normal(size=(40, 3)))
    o3d.io.write_point_cloud(str(tmp_path / f"c{suffix}"), cloud)
    loaded = load_points(tmp_path / f"c{suffix}")
    np.testing.assert_allclose(np.asarray(loaded.points), np.asarray(cloud.points), atol=1e-5)
    assert loaded.has_normals() == (suffix != ".xyz")


def test_load_points_leaves_out_an_organized_scan_s_nan_points(tmp_path):
    rng = np.random.default_rng(3)
    points = rng.normal(size=(40, 3))
    points[::10] = np.nan
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.colors = o3d.utility.Vector3dVector(rng.random((40, 3)))
    o3d.io.write_point_cloud(str(tmp_path / "organized.pcd"), cloud)
    with pytest.warns(UserWarning, match="4 of 40 points have NaN or inf coordinates"):
        loaded = load_points(tmp_path / "organized.pcd")
    np.testing.assert_allclose(np.asarray(loaded.points), points[np.isfinite(points).all(axis=1)], atol=1e-5)
    assert len(loaded.colors) == 36


@pytest.mark.parametrize("header", ["", "40\n"])
def test_load_points_text_with_normals(tmp_path, header):
    """CGAL's .pwn and six-column .xyz: x y z nx ny nz a line (a count line first in some)."""
    rng = np.random.default_rng(2)
    array = rng.normal(size=(40, 6))
    for suffix in (".pwn", ".xyz"):
        write(tmp_path / f"c{suffix}", header + "\n".join(" ".join(f"{v:.17g}" for v in row) for row in array))
        loaded = load_points(tmp_path / f"c{suffix}")
        np.testing.assert_array_equal(np.asarray(loaded.points), array[:, :3])
        np.testing.assert_array_equal(np.asarray(loaded.normals), array[:, 3:])


def test_load_points_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.npy"):
        load_points(tmp_path / "missing.npy")
    np.save(tmp_path / "four.npy", np.zeros((5, 4)))
    with pytest.raises(ValueError, match=r"\(n, 3\) or \(n, 6\)"):
        load_points(tmp_path / "four.npy")
    bad = np.zeros((5, 6))
    bad[2, 4] = np.inf  # a normal: passed on, for the reconstruction to repair
    np.save(tmp_path / "inf.npy", bad)
    assert np.isinf(np.asarray(load_points(tmp_path / "inf.npy").normals)[2, 1])
    bad[2, 1] = np.nan  # a position: left out (an organized scan's empty pixel), its normal with it
    np.save(tmp_path / "nan.npy", bad)
    with pytest.warns(UserWarning, match="1 of 5 points have NaN or inf coordinates"):
        cloud = load_points(tmp_path / "nan.npy")
    assert len(cloud.points) == len(cloud.normals) == 4 and np.isfinite(np.asarray(cloud.normals)).all()
    np.save(tmp_path / "all_nan.npy", np.full((5, 3), np.nan))
    with pytest.raises(ValueError, match="NaN or inf"):
        load_points(tmp_path / "all_nan.npy")
    with pytest.raises(ValueError, match="could not be read"):
        load_points(write(tmp_path / "junk.npy", "not numpy"))
    with pytest.raises(ValueError, match="could not be read"):
        load_points(write(tmp_path / "junk.pcd", "not a pcd"))
    with pytest.raises(ValueError, match="empty.xyz holds no points"):
        load_points(write(tmp_path / "empty.xyz", ""))
    with pytest.raises(ValueError, match=r"readable formats are .*\.pwn"):
        load_points(write(tmp_path / "cloud.las", "binary"))


# -- frames ---------------------------------------------------------------------------------------

def test_ndc_frame_centres_bbox_with_unit_diagonal(sphere):
    moved = ndc_frame(sphere).apply_mesh(sphere)
    low, high = moved.get_min_bound(), moved.get_max_bound()
    np.testing.assert_allclose((low + high) / 2, 0, atol=1e-12)
    assert np.linalg.norm(high - low) == pytest.approx(1.0)


def test_fit_frame_is_twice_ndc(sphere):
    ndc, fit = ndc_frame(sphere), fit_frame(sphere)
    np.testing.assert_array_equal(fit.center, ndc.center)
    assert fit.scale == pytest.approx(2 * ndc.scale)
    moved = fit.apply_mesh(sphere)
    assert np.linalg.norm(moved.get_max_bound() - moved.get_min_bound()) == pytest.approx(2.0)
    assert np.abs(np.asarray(moved.vertices)).max() <= 1.0


def test_frames_accept_every_geometry_kind(sphere):
    vertices = np.asarray(sphere.vertices)
    cloud = o3d.geometry.PointCloud(sphere.vertices)
    for geometry in (sphere, cloud, vertices, (vertices, np.asarray(sphere.triangles))):
        frame = ndc_frame(geometry)
        np.testing.assert_allclose(frame.center, ndc_frame(sphere).center)
        assert frame.scale == pytest.approx(ndc_frame(sphere).scale)


def test_apply_mesh_returns_a_new_mesh_and_keeps_normals(sphere):
    sphere.compute_vertex_normals()
    original = np.asarray(sphere.vertices).copy()
    frame = fit_frame(sphere)
    moved = frame.apply_mesh(sphere)
    np.testing.assert_array_equal(np.asarray(sphere.vertices), original)
    np.testing.assert_array_equal(np.asarray(moved.vertex_normals), np.asarray(sphere.vertex_normals))
    back = frame.invert_mesh(moved)
    np.testing.assert_allclose(np.asarray(back.vertices), original, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(points=arrays(np.float64, st.tuples(st.integers(2, 20), st.just(3)),
                     elements=st.floats(-1e4, 1e4, allow_nan=False)))
def test_apply_invert_round_trip(points):
    if np.ptp(points, axis=0).max() < 1e-3:
        return
    frame = ndc_frame(points)
    moved = frame.apply(points)
    assert np.linalg.norm(moved.max(axis=0) - moved.min(axis=0)) == pytest.approx(1.0)
    np.testing.assert_allclose(frame.invert(moved), points, atol=1e-9 * np.abs(points).max() + 1e-9)


@pytest.mark.parametrize("center, scale, match", [
    ([0, 0], 1.0, "center"),
    ([0, 0, np.nan], 1.0, "center"),
    ([0, 0, 0], 0.0, "scale"),
    ([0, 0, 0], np.inf, "scale"),
])
def test_frame_validation(center, scale, match):
    with pytest.raises(ValueError, match=match):
        NormalizationFrame(center=center, scale=scale)


def test_frame_errors():
    with pytest.raises(ValueError, match="zero-size"):
        ndc_frame(np.ones((4, 3)))
    with pytest.raises(ValueError, match="points must have shape"):
        ndc_frame(np.ones((4, 3)) * [1, 2, 3] + np.arange(4)[:, None]).apply(np.zeros((3, 2)))


# -- dev meshes -----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["organic_bunny.off", "cad_fandisk.obj", "abc_00000001.stl", "organic_spot.obj"])
def test_dev_meshes_load_closed(dev_meshes, name):
    # organic_spot.obj is open as stored (UV seams) and abc_*.stl are triangle soups.
    mesh = load_mesh(dev_meshes / name)
    assert open_edge_count(*mesh_arrays(mesh)) == 0


def test_dev_open_mesh_stays_open(dev_meshes):
    mesh = load_mesh(dev_meshes / "thingi32_96481.obj")
    assert open_edge_count(*mesh_arrays(mesh)) > 0


def test_frames_compare_by_value(sphere):
    assert fit_frame(sphere) == fit_frame(sphere)
    assert fit_frame(sphere) != ndc_frame(sphere)
    assert len({fit_frame(sphere), fit_frame(sphere)}) == 1


def test_atomic_path_gives_ordinary_permissions(tmp_path):
    import os
    import stat

    from voro3d.io import atomic_path

    target = tmp_path / "file.txt"
    with atomic_path(target) as tmp:
        Path(tmp).write_text("x")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask


def read_polygon_ply(path):
    """(vertices, faces) of a binary PLY as save_polygons writes it, parsed by hand."""
    data = Path(path).read_bytes()
    header, body = data.split(b"end_header\n", 1)
    counts = dict(line.split()[1:3] for line in header.decode().splitlines() if line.startswith("element"))
    n = int(counts["vertex"])
    vertices = np.frombuffer(body[: 24 * n], "<f8").reshape(n, 3)
    faces, at = [], 24 * n
    for _ in range(int(counts["face"])):
        size = body[at]
        faces.append(np.frombuffer(body[at + 1: at + 1 + 4 * size], "<i4"))
        at += 1 + 4 * size
    assert at == len(body)
    return vertices, faces


def test_save_polygons_roundtrip(tmp_path):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1.0 / 3]])
    faces = [np.array([3, 2, 1, 0]), np.array([0, 1, 4]), np.array([1, 2, 4]), np.array([2, 3, 4]), np.array([3, 0, 4])]
    back_vertices, back_faces = read_polygon_ply(save_polygons((vertices, faces), tmp_path / "p.ply"))
    np.testing.assert_array_equal(back_vertices, vertices)
    assert [f.tolist() for f in back_faces] == [f.tolist() for f in faces]
    obj = save_polygons((vertices, faces), tmp_path / "p.obj").read_text().splitlines()
    assert obj[5] == "f 4 3 2 1" and obj[0] == "v 0.0 0.0 0.0"
    off = save_polygons((vertices, faces), tmp_path / "p.off").read_text().splitlines()
    assert off[:2] == ["OFF", "5 5 0"] and off[7] == "4 3 2 1 0"
    # Open3D reads them, fan-triangulated: 2 + 4 triangles.
    assert len(load_mesh(tmp_path / "p.ply", weld=False).triangles) == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.obj", "p.off", "p.ply"]


@pytest.mark.parametrize("polygons, name, match", [
    ((np.eye(3), [np.array([0, 1, 2])]), "p.stl", "must end in one of .ply, .obj, .off"),
    ((np.eye(3), []), "p.ply", "no faces"),
    ((np.eye(3), [np.array([0, 1])]), "p.ply", "at least 3 corners"),
    ((np.eye(3), [np.array([0, 1, 3])]), "p.obj", r"index vertices in \[0, 3\)"),
    ((np.eye(3), [np.array([0.0, 1.0, 2.0])]), "p.off", "index vertices"),
    ((np.zeros((300, 3)), [np.arange(300)]), "p.ply", "at most 255 corners"),
    ((np.zeros((3, 2)), [np.array([0, 1, 2])]), "p.ply", "vertices must have shape"),
])
def test_save_polygons_bad_input(tmp_path, polygons, name, match):
    with pytest.raises(ValueError, match=match):
        save_polygons(polygons, tmp_path / name)
    assert not list(tmp_path.iterdir())
