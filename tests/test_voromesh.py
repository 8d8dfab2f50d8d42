"""The VoroMesh type: its grid and frame (so its voxel), one triangulation per call, save/load."""
import numpy as np
import pytest

import voro3d
from voro3d import VoroMesh
from voro3d.frames import NormalizationFrame
from voro3d.shapes import example_mesh


@pytest.fixture
def count_delaunay(monkeypatch):
    """The number of CGAL Delaunay tetrahedralisations run since the fixture was set up."""
    from voro3d import _cgal

    calls = []
    original = _cgal.delaunay_tetrahedra

    def counted(points):
        calls.append(len(points))
        return original(points)

    monkeypatch.setattr(_cgal, "delaunay_tetrahedra", counted)
    return calls


def _random_shape(**options):
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (200, 3))
    return VoroMesh(points, np.linalg.norm(points, axis=1) < 0.6, **options)


def test_roundtrip_keeps_grid_and_frame(tmp_path):
    frame = NormalizationFrame(center=np.array([1.0, -2.0, 0.5]), scale=0.25)
    shape = _random_shape(grid=17, frame=frame)
    path = tmp_path / "shape.npz"
    shape.save(path)
    loaded = VoroMesh.load(path)
    np.testing.assert_array_equal(loaded.generators, shape.generators)
    np.testing.assert_array_equal(loaded.occupancy, shape.occupancy)
    assert loaded.generators.dtype == np.float64 and loaded.occupancy.dtype == bool
    assert loaded.grid == 17 and loaded.frame == frame
    assert loaded.voxel == pytest.approx(2.0 / 16 / 0.25, rel=1e-15)
    assert len(loaded.to_open3d().triangles) > 0
    assert [p.name for p in tmp_path.iterdir()] == ["shape.npz"]


def test_a_file_of_generators_and_occupancy_only_loads_without_grid(tmp_path):
    shape = _random_shape()
    np.savez(tmp_path / "old.npz", generators=shape.generators, occupancy=shape.occupancy)
    loaded = VoroMesh.load(tmp_path / "old.npz")
    assert loaded.grid is None and loaded.frame is None and loaded.voxel is None


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        VoroMesh.load(tmp_path / "missing.npz")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable"):
        VoroMesh.load(corrupt)
    other = tmp_path / "other.npz"
    np.savez(other, points=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="lacks arrays"):
        VoroMesh.load(other)


@pytest.mark.parametrize("options, error, match", [
    (dict(grid=1), ValueError, "grid must be an int >= 2"),
    (dict(grid=3.5), ValueError, "grid must be an int >= 2"),
    (dict(frame=(0, 1)), TypeError, "frame must be"),
])
def test_bad_grid_or_frame(options, error, match):
    with pytest.raises(error, match=match):
        _random_shape(**options)


def test_a_triangulation_of_other_generators_is_refused():
    shape = _random_shape()
    with pytest.raises(ValueError, match="triangulation is of 200 generators"):
        VoroMesh(shape.generators[:100], shape.occupancy[:100], triangulation=shape.triangulated())


def test_fit_gives_its_grid_frame_and_voxel():
    mesh = example_mesh()
    shape, _ = voro3d.fit(mesh, 12, steps=5)
    assert shape.grid == 12
    extent = np.ptp(np.asarray(mesh.vertices), axis=0)
    assert shape.voxel == pytest.approx(2.0 / 11 / shape.frame.scale, rel=1e-12)
    assert shape.voxel == pytest.approx(np.linalg.norm(extent) / 11, rel=1e-12)  # the frame has diagonal 2


def test_the_clean_and_the_snap_measure_in_the_grid_voxel(monkeypatch):
    """Not the clean's estimate from triangle sides (0.90-1.21 of the voxel on the dev meshes)."""
    from voro3d import cleaning, snapping

    mesh = example_mesh()
    shape, _ = voro3d.fit(mesh, 12, steps=5)
    seen = {}
    for module, name in ((cleaning, "clean_surface"), (snapping, "snap_to_surface")):
        original = getattr(module, name)

        def recorded(*args, _original=original, _name=name, **kwargs):
            seen[_name] = kwargs["voxel"]
            return _original(*args, **kwargs)

        monkeypatch.setattr(module, name, recorded)
    shape.to_open3d(surface=mesh)
    assert seen == {"clean_surface": shape.voxel, "snap_to_surface": shape.voxel}
    assert cleaning.voxel_size(*voro3d.io.mesh_arrays(shape.to_open3d(clean=False))) != shape.voxel


def test_a_surface_without_the_clean_is_refused():
    with pytest.raises(ValueError, match="surface needs clean=True"):
        _random_shape().to_open3d(clean=False, surface=example_mesh())


def test_relabelled_keeps_everything_but_the_occupancy(count_delaunay):
    shape = _random_shape(grid=9)
    shape.triangulated()
    other = shape.relabelled(~shape.occupancy)
    assert other.triangulation is shape.triangulation and other.grid == 9
    np.testing.assert_array_equal(other.occupancy, ~shape.occupancy)
    other.to_open3d(clean=False)
    other.to_polygons()
    assert len(count_delaunay) == 1


def test_one_delaunay_per_mesh_reconstruct(count_delaunay):
    voro3d.reconstruct(example_mesh(), 12, steps=5)
    assert len(count_delaunay) == 1


def test_two_delaunays_per_cloud_reconstruct(count_delaunay):
    """One for the labels the fit's boundary steps start from (CLOUD_BOUNDARY_STEPS), one for the
    labels after them, which the stray-cell pass and the extraction share."""
    points, _ = voro3d.sample_surface(example_mesh(), 3000, seed=0)
    voro3d.reconstruct(points, 16, steps=5)
    assert len(count_delaunay) == 2
