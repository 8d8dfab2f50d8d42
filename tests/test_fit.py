import numpy as np
import open3d as o3d
import pytest
import torch

from voro3d.fitloop import Adam
from voro3d import fitting as fit_module
from voro3d.extract import extract_mesh
from voro3d.voromesh import VoroMesh
from voro3d.fitting import FitInfo, fit
from voro3d.io import load_mesh, mesh_arrays
from voro3d.queries import InsideOutside
from voro3d.sampling import sample_surface
from voro3d.watertight import check_watertight

# Enough steps to converge well at grids up to 32, few enough to keep this file fast.
QUICK = dict(steps=100, milestones=(40, 60, 80))
# For tests of behaviour rather than quality.
TINY = dict(steps=40, milestones=(20, 30))

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")),
]


def _chamfer(mesh_a, mesh_b, n=20000):
    """Mean of the two one-sided mean distances from surface samples to the other surface.

    Distances to the exact surface (not to samples of it), so sampling adds no floor.
    """
    a, _ = sample_surface(mesh_a, n, seed=1)
    b, _ = sample_surface(mesh_b, n, seed=2)
    return (InsideOutside(mesh_b).unsigned_distance(a).mean() + InsideOutside(mesh_a).unsigned_distance(b).mean()) / 2


@pytest.fixture(scope="module")
def sphere():
    return o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=40)


@pytest.fixture(scope="module")
def sphere_fit(sphere):
    # A third of the default samples: quick, and still about 40 per surface voxel.
    return fit(sphere, 32, n_samples=50_000, **QUICK)


def test_sphere_is_watertight_and_close(sphere, sphere_fit):
    voromesh, _ = sphere_fit
    assert isinstance(voromesh, VoroMesh)
    surface = extract_mesh(voromesh.generators, voromesh.occupancy)
    report = check_watertight(surface, self_intersection=False)
    assert report.watertight
    # Voxel side in the input's units: the fit frame maps the diagonal 2 sqrt(3) to 2.
    h = 2 / 31 * np.sqrt(3)
    assert _chamfer(surface, sphere) < 0.05 * h
    assert report.volume == pytest.approx(4 / 3 * np.pi, rel=0.03)


def test_generators_come_back_in_the_input_frame(sphere):
    vertices, triangles = mesh_arrays(sphere)
    moved = (vertices * 10 + [100, -50, 3], triangles)
    voromesh, _ = fit(moved, 12, **TINY)
    centre = voromesh.generators[voromesh.occupancy].mean(axis=0)
    np.testing.assert_allclose(centre, [100, -50, 3], atol=1.0)
    radius = np.linalg.norm(voromesh.generators - [100, -50, 3], axis=1)
    h = 2 / 11 * np.sqrt(3) * 10  # voxel side in the input's units
    assert np.all(np.abs(radius - 10) < 2 * h)


def test_torus_topology():
    torus = o3d.geometry.TriangleMesh.create_torus(torus_radius=1.0, tube_radius=0.4, radial_resolution=48,
                                                   tubular_resolution=24)
    voromesh, _ = fit(torus, 20, **QUICK)
    surface = extract_mesh(voromesh.generators, voromesh.occupancy)
    assert check_watertight(surface, self_intersection=False).watertight
    euler = len(surface.vertices) - len(surface.triangles) * 3 // 2 + len(surface.triangles)
    assert euler == 0
    assert _chamfer(surface, torus) < 0.05 * 2 / 19 * np.linalg.norm([2.8, 2.8, 0.8]) / 2


def test_info(sphere_fit):
    voromesh, info = sphere_fit
    assert isinstance(info, FitInfo)
    assert info.n_samples == 50_000
    assert info.n_generators == voromesh.generators.shape[0]
    assert info.losses.shape == (QUICK["steps"],)
    assert info.losses[-10:].mean() < 0.05 * info.losses[:10].mean()
    assert 0 <= info.final_loss < 2 * info.losses[-10:].mean()
    assert info.candidate_searches >= 1
    phases = (info.sampling_seconds, info.init_seconds, info.optimisation_seconds, info.occupancy_seconds)
    assert all(t >= 0 for t in phases)
    assert sum(phases) <= info.total_seconds + 1e-6


def test_same_seed_same_generators(sphere):
    first, _ = fit(sphere, 12, **TINY)
    again, _ = fit(sphere, 12, **TINY)
    np.testing.assert_array_equal(again.generators, first.generators)
    np.testing.assert_array_equal(again.occupancy, first.occupancy)
    other, _ = fit(sphere, 12, seed=1, **TINY)
    assert other.generators.shape != again.generators.shape or not np.array_equal(other.generators, again.generators)


def test_candidates_are_searched_again_after_moves(sphere, monkeypatch):
    monkeypatch.setattr(fit_module, "REFRESH_VOXELS", 0.1)
    _, often = fit(sphere, 12, **TINY)
    monkeypatch.setattr(fit_module, "REFRESH_VOXELS", np.inf)
    monkeypatch.setattr(fit_module, "MAX_REFRESH_DISTANCE", np.inf)
    _, never = fit(sphere, 12, **TINY)
    assert often.candidate_searches > never.candidate_searches == 1


def test_boundary_steps_are_an_option_of_fit(sphere):
    plain, plain_info = fit(sphere, 12, **TINY)
    ended, ended_info = fit(sphere, 12, boundary_steps=10, **TINY)
    assert not np.array_equal(ended.generators, plain.generators)  # the steps ran on the mesh's fit
    assert ended_info.n_generators == plain_info.n_generators


def test_refresh_distance_is_an_option_of_fit_samples():
    samples, _ = sample_surface(o3d.geometry.TriangleMesh.create_sphere(radius=0.8, resolution=30), 20_000, seed=0)
    inside = lambda points: np.linalg.norm(points, axis=1) < 0.8  # noqa: E731
    _, often = fit_module.fit_samples(samples, inside, 12, refresh_voxels=0.1, **TINY)
    _, seldom = fit_module.fit_samples(samples, inside, 12, refresh_voxels=1.0, **TINY)
    assert often.candidate_searches > seldom.candidate_searches
    with pytest.raises(ValueError, match="refresh_voxels"):
        fit_module.fit_samples(samples, inside, 12, refresh_voxels=0.0, **TINY)


def test_adam_matches_torch_optim():
    start = torch.randn(3, 50, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    ours, theirs = start.clone().requires_grad_(), start.clone().requires_grad_()
    with torch.no_grad():  # the one Adam of both backends (voro3d.fitloop), here on a torch tensor
        adam = Adam(ours)
    reference = torch.optim.Adam([theirs], lr=0.01, foreach=False)
    schedule = torch.optim.lr_scheduler.MultiStepLR(reference, milestones=[3, 6], gamma=0.5)
    for step in range(10):
        for parameter in (ours, theirs):
            parameter.grad = None
            (parameter.square().sum() + parameter.sum() * step).backward()
        with torch.no_grad():
            adam.step(ours.grad, 0.01 * 0.5 ** sum(step >= m for m in (3, 6)))
        reference.step()
        schedule.step()
    torch.testing.assert_close(ours, theirs, rtol=1e-12, atol=1e-14)


def test_options_are_used(sphere):
    _, info = fit(sphere, 8, steps=5, n_samples=1000, batch_fraction=0.5, k=6)
    assert info.n_samples == 1000 and info.losses.shape == (5,)


def test_progress_bar_is_off_unless_asked_for_and_on_a_terminal(sphere, capsys, monkeypatch):
    import io
    import sys

    fit(sphere, 6, steps=3)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    fit(sphere, 6, steps=3, progress=True)  # stderr is a pipe here, as in a log: no bar
    assert capsys.readouterr().err == ""

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    fit(sphere, 6, steps=3, progress=True)
    assert "VoroMesh fit" in sys.stderr.getvalue()


def test_torch_threads_are_restored(sphere):
    before = torch.get_num_threads()
    fit(sphere, 6, steps=3)
    assert torch.get_num_threads() == before


@pytest.mark.parametrize("device", DEVICES)
def test_devices(sphere, device):
    voromesh, _ = fit(sphere, 8, steps=20, device=device)
    assert voromesh.generators.dtype == np.float64 and voromesh.occupancy.any()


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available")
def test_cuda_without_a_device_is_an_error(sphere):
    with pytest.raises(ValueError, match="CUDA"):
        fit(sphere, 8, steps=2, device="cuda")


def test_open_mesh_needs_allow_open():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    open_mesh = (vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2]]))
    with pytest.raises(ValueError, match="allow_open"):
        fit(open_mesh, 6, steps=2)
    assert fit(open_mesh, 6, steps=2, allow_open=True)[0].occupancy.dtype == bool


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(grid=1), ValueError, "grid"),
        (dict(grid=8.5), TypeError, "grid"),
        (dict(steps=0), ValueError, "steps"),
        (dict(lr=0.0), ValueError, "lr"),
        (dict(lr=float("nan")), ValueError, "lr"),
        (dict(gamma=0.0), ValueError, "gamma"),
        (dict(batch_fraction=0.0), ValueError, "batch_fraction"),
        (dict(batch_fraction=1.5), ValueError, "batch_fraction"),
        (dict(k=1), ValueError, "k"),
        (dict(n_samples=0), ValueError, "n_samples"),
        (dict(milestones=(10, -1)), ValueError, "milestones"),
        (dict(device="tpu"), ValueError, "device"),
        (dict(device=3.5), ValueError, "device"),
        (dict(boundary_steps=-1), ValueError, "boundary_steps"),
    ],
)
def test_bad_arguments(sphere, kwargs, error, match):
    with pytest.raises(error, match=match):
        fit(sphere, **{"grid": 8, **kwargs})


def test_bad_mesh():
    with pytest.raises(ValueError, match="mesh"):
        fit((np.zeros((3, 3)), np.zeros((0, 3), int)), 8)


def test_bunny(dev_meshes):
    bunny = load_mesh(dev_meshes / "organic_bunny.off")
    voromesh, _ = fit(bunny, 16, **QUICK)
    surface = extract_mesh(voromesh.generators, voromesh.occupancy)
    assert check_watertight(surface, self_intersection=False).watertight
    vertices, _ = mesh_arrays(bunny)
    h = 2 / 15 * np.linalg.norm(vertices.max(0) - vertices.min(0)) / 2
    assert _chamfer(surface, bunny) < 0.05 * h
