"""Headless pictures: PNGs that show something, shared cameras, atomic writes, every bad input."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from PIL import Image

from voro3d import render
from voro3d.render import open3d_backend
from voro3d.shapes import example_mesh

SMALL = (160, 120)


def _pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


@pytest.fixture(scope="module")
def sphere():
    return example_mesh("sphere")


@pytest.fixture(scope="module")
def bracket():
    return example_mesh("bracket")


@pytest.fixture
def no_open3d(monkeypatch):
    """Make ``backend="auto"`` resolve without running the (slow) child-process probe."""
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", render.Open3DStatus(False, False, "disabled in tests"))


# --------------------------------------------------------------------------- render_meshes


def test_side_by_side_png_is_not_blank(tmp_path, sphere, bracket):
    out = render.render_meshes([sphere, bracket], tmp_path / "pair.png", titles=["sphere", "bracket"],
                               size=(320, 240), backend="matplotlib")
    assert out == tmp_path / "pair.png"
    image = _pixels(out)
    assert image.shape == (240 + render.TITLE_BAND, 2 * 320, 3)
    for panel in (image[render.TITLE_BAND:, :320], image[render.TITLE_BAND:, 320:]):
        assert panel.std() > 20  # shaded shape on white, not a flat colour
        assert (panel.mean(axis=2) < 200).mean() > 0.05  # the shape covers a real part of the panel
    assert image[: render.TITLE_BAND].std() > 5  # titles were drawn


def test_a_long_title_is_set_smaller_to_fit_its_panel(tmp_path, sphere, bracket):
    # At the full size this title is about twice as wide as its panel: cut at the edges, it ran
    # into its neighbour's.
    title = "organic_bunny.off: range scan 3 views (30000 pts), VoroMesh 64^3"
    image = _pixels(render.render_meshes([sphere, bracket], tmp_path / "t.png", titles=[title, "short"], size=(320, 240),
                                         backend="matplotlib"))
    ink = np.nonzero((image[: render.TITLE_BAND].mean(axis=2) < 160).any(axis=0))[0]
    first = ink[ink < 320]
    assert first.size and first.min() > 3 and first.max() < 317  # inside its own panel
    assert ink[ink >= 320].size and ink[ink >= 320].min() > 400  # "short" kept its size, centred


def test_no_titles_no_title_band(tmp_path, sphere, no_open3d):
    out = render.render_meshes(sphere, tmp_path / "one.png", size=SMALL)
    assert _pixels(out).shape == (SMALL[1], SMALL[0], 3)


def test_shapes_are_framed_inside_the_panel(tmp_path, bracket):
    image = _pixels(render.render_meshes([bracket], tmp_path / "b.png", size=SMALL, backend="matplotlib"))
    border = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    assert (border == 255).all()  # nothing touches the edge...
    rows, cols = np.nonzero(image.mean(axis=2) < 250)
    # ...and the shape fills most of the panel in at least one direction.
    assert max(np.ptp(rows) / SMALL[1], np.ptp(cols) / SMALL[0]) > 0.7


def test_panels_share_one_camera(tmp_path, bracket):
    # The same mesh twice must give identical panels; a per-mesh camera would too, so add a
    # larger second mesh: the bracket then has to shrink in both panels alike.
    width = SMALL[0]
    pair = _pixels(render.render_meshes([bracket, bracket], tmp_path / "pair.png", size=SMALL, backend="matplotlib"))
    np.testing.assert_array_equal(pair[:, :width], pair[:, width:])
    big = o3d.geometry.TriangleMesh(bracket).scale(2.0, center=(0.0, 0.0, 0.0))
    alone = _pixels(render.render_meshes([bracket], tmp_path / "alone.png", size=SMALL, backend="matplotlib"))
    beside = _pixels(render.render_meshes([bracket, big], tmp_path / "beside.png", size=SMALL, backend="matplotlib"))
    coverage_alone = (alone.mean(axis=2) < 250).mean()
    coverage_beside = (beside[:, :width].mean(axis=2) < 250).mean()
    assert coverage_beside < 0.5 * coverage_alone


def test_same_input_same_pixels(tmp_path, bracket):
    first = _pixels(render.render_meshes([bracket], tmp_path / "a.png", size=SMALL, backend="matplotlib"))
    second = _pixels(render.render_meshes([bracket], tmp_path / "b.png", size=SMALL, backend="matplotlib"))
    np.testing.assert_array_equal(first, second)


@pytest.mark.parametrize("view", [None, "iso", "front", "side", "top", (30.0, -20.0), (0.0, 90.0), [10, -90]])
@pytest.mark.parametrize("up", ["x", "y", "z"])
def test_every_view_shows_the_shape(tmp_path, bracket, view, up):
    image = _pixels(render.render_meshes([bracket], tmp_path / "v.png", size=(96, 72), view=view, up=up,
                                         backend="matplotlib"))
    assert image.std() > 10
    assert (image[0] == 255).all() and (image[-1] == 255).all()


@pytest.mark.parametrize("shading", ["flat", "smooth"])
def test_colours_and_shading_reach_the_picture(tmp_path, sphere, shading):
    image = _pixels(render.render_meshes([sphere], tmp_path / "c.png", size=SMALL, colors=["red"], shading=shading,
                                         backend="matplotlib"))
    shape = image[image.mean(axis=2) < 250]
    assert (shape[:, 0] > shape[:, 1] + 20).mean() > 0.9  # red dominates
    assert shape[:, 0].std() > 5  # and it is shaded, not flat


@pytest.mark.parametrize("backend", ["matplotlib", "auto"])
def test_a_mesh_with_vertex_colours_is_drawn_in_them(tmp_path, backend):
    """Top half green, bottom half red (a coloured cloud's reconstruction carries its colours)."""
    mesh = example_mesh("sphere")
    top = np.asarray(mesh.vertices)[:, 2] > 0
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.where(top[:, None], [0.1, 0.8, 0.1], [0.8, 0.1, 0.1]))
    image = _pixels(render.render_meshes([mesh], tmp_path / "v.png", size=SMALL, view="front", backend=backend))
    shape = image.mean(axis=2) < 250
    rows = np.flatnonzero(shape.any(axis=1))
    upper, lower = image[rows[0]: rows[len(rows) // 3]], image[rows[-len(rows) // 3]: rows[-1]]
    upper, lower = upper[upper.mean(axis=2) < 250], lower[lower.mean(axis=2) < 250]
    assert (upper[:, 1] > upper[:, 0] + 20).mean() > 0.8 and (lower[:, 0] > lower[:, 1] + 20).mean() > 0.8
    plain = _pixels(render.render_meshes([mesh], tmp_path / "p.png", size=SMALL, view="front", colors=["tab:blue"],
                                         backend=backend))
    plain = plain[plain.mean(axis=2) < 250]
    assert (plain[:, 2] > plain[:, 0]).mean() > 0.9  # colors= still overrides them
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.zeros((len(mesh.vertices), 3)))  # Open3D's "no colours"
    blank = _pixels(render.render_meshes([mesh], tmp_path / "b.png", size=SMALL, view="front", backend=backend))
    blank = blank[blank.mean(axis=2) < 250]
    assert (blank[:, 2] > blank[:, 0]).mean() > 0.9 and blank.mean() > 60  # the default colour, shaded, not black


def test_accepts_tensor_meshes_and_array_pairs(tmp_path, sphere):
    vertices, triangles = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    tensor = o3d.t.geometry.TriangleMesh.from_legacy(sphere)
    out = render.render_meshes([tensor, (vertices, triangles)], tmp_path / "kinds.png", size=SMALL, backend="matplotlib")
    image = _pixels(out)
    np.testing.assert_allclose(image[:, : SMALL[0]], image[:, SMALL[0]:], atol=2)


def test_large_mesh_is_decimated_and_drawn(tmp_path):
    import trimesh

    dense = trimesh.creation.icosphere(subdivisions=6)  # 81,920 faces, over MAX_MATPLOTLIB_FACES
    assert len(dense.faces) > render.MAX_MATPLOTLIB_FACES
    image = _pixels(render.render_meshes([(dense.vertices, dense.faces)], tmp_path / "dense.png", size=SMALL,
                                         backend="matplotlib"))
    assert image.std() > 20


def test_open_and_inconsistently_oriented_meshes_still_draw(tmp_path, sphere):
    triangles = np.asarray(sphere.triangles).copy()
    triangles[::2] = triangles[::2, ::-1]  # half the faces flipped: back faces must not be culled
    flipped = (np.asarray(sphere.vertices), triangles)
    open_half = (np.asarray(sphere.vertices), np.asarray(sphere.triangles)[: len(triangles) // 2])
    reference = _pixels(render.render_meshes([sphere], tmp_path / "r.png", size=SMALL, backend="matplotlib"))
    image = _pixels(render.render_meshes([flipped], tmp_path / "f.png", size=SMALL, backend="matplotlib"))
    # The silhouette is the same as the clean sphere's: no face went missing.
    np.testing.assert_array_equal(image.mean(axis=2) < 250, reference.mean(axis=2) < 250)
    assert _pixels(render.render_meshes([open_half], tmp_path / "o.png", size=SMALL, backend="matplotlib")).std() > 10


# --------------------------------------------------------------------------- render_error_map


def test_error_map_colours_by_distance(tmp_path, sphere):
    coarse = sphere.simplify_quadric_decimation(target_number_of_triangles=200)
    out = render.render_error_map(coarse, sphere, tmp_path / "err.png", size=(320, 240), backend="matplotlib")
    image = _pixels(out)
    assert image.shape[0] == 240 + render.TITLE_BAND
    assert image.shape[1] > 320  # room for the colour bar
    saturation = image.max(axis=2) - image.min(axis=2)
    assert (saturation > 40).mean() > 0.05  # coloured, not grey shading only
    assert image[: render.TITLE_BAND].std() > 5  # the mean/max title


def test_error_map_of_identical_meshes_and_explicit_vmax(tmp_path, sphere, no_open3d):
    render.render_error_map(sphere, sphere, tmp_path / "zero.png", size=SMALL)
    coarse = sphere.simplify_quadric_decimation(target_number_of_triangles=200)
    render.render_error_map(coarse, sphere, tmp_path / "vmax.png", size=SMALL, vmax=1e-4, title="saturated")
    assert _pixels(tmp_path / "zero.png").std() > 10
    assert _pixels(tmp_path / "vmax.png").std() > 10


@pytest.mark.parametrize("vmax", [0, -1.0, float("nan"), float("inf"), "1", True])
def test_error_map_rejects_bad_vmax(tmp_path, sphere, vmax):
    with pytest.raises(ValueError, match="vmax"):
        render.render_error_map(sphere, sphere, tmp_path / "x.png", vmax=vmax)


def test_error_map_rejects_empty_meshes_and_bad_cmap(tmp_path, sphere):
    with pytest.raises(ValueError, match="reference"):
        render.render_error_map(sphere, o3d.geometry.TriangleMesh(), tmp_path / "x.png")
    with pytest.raises(ValueError, match="mesh"):
        render.render_error_map(o3d.geometry.TriangleMesh(), sphere, tmp_path / "x.png")
    with pytest.raises(ValueError, match="cmap"):
        render.render_error_map(sphere, sphere, tmp_path / "x.png", cmap="no-such-map")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad input


def _points_only(mesh):
    empty = o3d.geometry.TriangleMesh()
    empty.vertices = mesh.vertices
    return empty


@pytest.mark.parametrize("meshes, match", [
    ([], "meshes must hold at least one mesh"),
    ((), "meshes must hold at least one mesh"),
    ([o3d.geometry.TriangleMesh()], r"meshes\[0\] has no triangles"),
])
def test_rejects_no_meshes_or_no_triangles(tmp_path, meshes, match):
    with pytest.raises(ValueError, match=match):
        render.render_meshes(meshes, tmp_path / "x.png")


def test_rejects_mesh_with_vertices_but_no_triangles(tmp_path, sphere):
    with pytest.raises(ValueError, match=r"meshes\[1\] has no triangles"):
        render.render_meshes([sphere, _points_only(sphere)], tmp_path / "x.png")
    with pytest.raises(TypeError, match="meshes"):
        render.render_meshes(42, tmp_path / "x.png")


@pytest.mark.parametrize("options, match", [
    ({"titles": ["only one"]}, "titles"),
    ({"titles": "ab"}, "titles"),
    ({"colors": ["red"]}, "colors"),
    ({"colors": ["red", "not-a-colour"]}, r"colors\[1\]"),
    ({"size": (0, 100)}, "size"),
    ({"size": (100,)}, "size"),
    ({"size": (100.5, 100)}, "size"),
    ({"size": "big"}, "size"),
    ({"view": "diagonal"}, "view"),
    ({"view": (10.0, 120.0)}, "view"),
    ({"view": (float("nan"), 0.0)}, "view"),
    ({"up": "w"}, "up"),
    ({"shading": "phong"}, "shading"),
    ({"backend": "vtk"}, "backend"),
])
def test_rejects_bad_options(tmp_path, sphere, options, match):
    with pytest.raises(ValueError, match=match):
        render.render_meshes([sphere, sphere], tmp_path / "x.png", **options)
    assert list(tmp_path.iterdir()) == []


def test_rejects_non_png_path(tmp_path, sphere):
    with pytest.raises(ValueError, match="path"):
        render.render_meshes([sphere], tmp_path / "x.jpg")


# --------------------------------------------------------------------------- atomic output


def test_output_is_atomic(tmp_path, sphere, monkeypatch):
    target = tmp_path / "out.png"
    render.render_meshes([sphere], target, size=SMALL, backend="matplotlib")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]  # no stray temp files
    before = target.read_bytes()

    def broken_savefig(*args, **kwargs):
        raise OSError("disk full")

    from matplotlib.figure import Figure

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        render.render_meshes([sphere], target, size=(200, 150), backend="matplotlib")
    assert target.read_bytes() == before  # the old picture survives a failed write
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


def test_creates_missing_folders(tmp_path, sphere):
    out = render.render_meshes([sphere], tmp_path / "a" / "b" / "c.png", size=SMALL, backend="matplotlib")
    assert out.is_file()


# --------------------------------------------------------------------------- backend choice


def test_auto_uses_matplotlib_without_open3d(tmp_path, sphere, no_open3d, monkeypatch):
    def no_child(*args, **kwargs):
        raise AssertionError("no Open3D child should start")

    monkeypatch.setattr(open3d_backend, "_run_child", no_child)
    assert _pixels(render.render_meshes([sphere], tmp_path / "x.png", size=SMALL)).std() > 10
    with pytest.raises(RuntimeError, match="matplotlib"):
        render.render_meshes([sphere], tmp_path / "y.png", size=SMALL, backend="open3d")


@pytest.mark.parametrize("works", [True, None])
def test_auto_skips_software_rasterisers(tmp_path, sphere, monkeypatch, works):
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", render.Open3DStatus(works, True, "llvmpipe"))
    monkeypatch.setattr(open3d_backend, "_run_child", lambda *a, **k: pytest.fail("auto must not use llvmpipe"))
    assert _pixels(render.render_meshes([sphere], tmp_path / "x.png", size=SMALL)).std() > 10


def test_auto_falls_back_when_the_open3d_child_fails(tmp_path, sphere, monkeypatch):
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", render.Open3DStatus(True, False, "a GPU"))

    def stalled(*args, **kwargs):
        raise open3d_backend._Open3DFailed("the Open3D renderer took longer than 1 s and was stopped")

    monkeypatch.setattr(open3d_backend, "_run_child", stalled)
    with pytest.warns(RuntimeWarning, match="matplotlib"):
        out = render.render_meshes([sphere], tmp_path / "x.png", size=SMALL)
    assert _pixels(out).std() > 10
    assert open3d_backend._OPEN3D_STATUS.works is False  # later pictures do not wait again
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", render.Open3DStatus(True, False, "a GPU"))
    with pytest.raises(RuntimeError, match="longer than"):
        render.render_meshes([sphere], tmp_path / "y.png", size=SMALL, backend="open3d")


@pytest.mark.parametrize("output, image, expected", [
    ("Vulkan device driver: NVIDIA 550.54\nVORO3D-PANEL-DONE", np.full((32, 48, 3), 200, np.uint8), (False, False)),
    ("Vulkan device driver: NVIDIA 550.54\nVORO3D-PANEL-DONE", np.arange(32 * 48 * 3, dtype=np.uint8).reshape(32, 48, 3),
     (True, False)),
    ("Vulkan device driver: llvmpipe Mesa 22.3.6\nVORO3D-PANEL-DONE", None, (None, True)),
])
def test_probe_reads_the_device_and_tests_hardware(monkeypatch, output, image, expected):
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", None)
    monkeypatch.setattr(open3d_backend, "_run_child", lambda arguments, timeout: output)
    monkeypatch.setattr(open3d_backend, "_run_open3d_child", lambda job, timeout: image)
    status = render.open3d_status()
    assert (status.works, status.software) == expected
    assert render.open3d_status() is status  # cached


def test_probe_failure_means_matplotlib(monkeypatch, tmp_path, sphere):
    monkeypatch.setattr(open3d_backend, "_OPEN3D_STATUS", None)

    def crashed(arguments, timeout):
        raise open3d_backend._Open3DFailed("the Open3D renderer exited with -6: Precondition")

    monkeypatch.setattr(open3d_backend, "_run_child", crashed)
    assert render.open3d_status() == render.Open3DStatus(False, False, "the Open3D renderer exited with -6: Precondition")
    assert _pixels(render.render_meshes([sphere], tmp_path / "x.png", size=SMALL)).std() > 10
    with pytest.raises(RuntimeError, match="-6"):
        render.render_meshes([sphere], tmp_path / "y.png", size=SMALL, backend="open3d")


def test_open3d_child_is_a_module_run_with_python_m(tmp_path):
    # From another folder, with the environment the backend gives its children: this voro3d is found.
    env = open3d_backend._child_environment()
    command = [sys.executable, "-m", "voro3d.render.open3d_child"]
    result = subprocess.run(command, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "usage: python -m voro3d.render.open3d_child" in result.stderr
    code = "import voro3d, sys; print(voro3d.__file__)"
    where = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert Path(where.stdout.strip()) == Path(render.__file__).parents[1] / "__init__.py"


def test_open3d_backend_when_it_works(tmp_path, bracket):
    # Filament on a CPU rasteriser works here but can take minutes per frame; only run it on a
    # GPU, or when asked to.
    status = render.open3d_status()
    if status.works is False:
        pytest.skip(f"Open3D offscreen rendering unavailable: {status.detail}")
    if status.software and not os.environ.get("VORO3D_TEST_OPEN3D"):
        pytest.skip(f"software rasteriser ({status.detail}); set VORO3D_TEST_OPEN3D=1 to run anyway")
    image = _pixels(render.render_meshes([bracket], tmp_path / "o3d.png", size=SMALL, backend="open3d"))
    assert image.std() > 20
    assert (np.concatenate([image[0], image[-1]]) > 245).all()  # white background after tone mapping


# --------------------------------------------------------------------------- show


def test_show_without_display_points_to_render_meshes(sphere, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(RuntimeError, match="display.*render_meshes"):
        render.show([sphere])
    with pytest.raises(ValueError, match="meshes"):
        render.show([])
