"""Tests for voro3d.metrics: CD / F1 / NC with the paper's conventions, and triangle quality."""

import numpy as np
import open3d as o3d
import pytest

from voro3d.baselines import marching_cubes
from voro3d.frames import fit_frame
from voro3d.io import load_mesh, mesh_arrays
from voro3d.metrics import evaluate, triangle_quality
from voro3d.queries import sdf_grid


KEYS = {"chamfer", "chamfer_x1e5", "chamfer_l1", "precision", "recall", "f1", "nc", "n_vertices", "n_triangles"}


@pytest.fixture(scope="module")
def cube():
    return mesh_arrays(o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0))


def sampling_floor(ndc_area, n_samples, delta):
    """Chamfer and F1 of a surface against itself, from independent uniform samples.

    Nearest-neighbour distances among n uniform points on area A are Rayleigh distributed:
    E[d^2] = A / (pi n) and P(d < delta) = 1 - exp(-pi n delta^2 / A).
    """
    return 2 * ndc_area / (np.pi * n_samples), 1 - np.exp(-np.pi * n_samples * delta**2 / ndc_area)


def test_identical_surfaces_sit_at_the_sampling_floor(cube):
    result = evaluate(cube, cube)  # paper defaults: 100,000 samples, delta 0.003
    assert set(result) == KEYS
    # The unit cube's NDC area is 6 / 3 (diagonal sqrt 3 scaled to 1).
    chamfer, f1 = sampling_floor(2.0, 100_000, 0.003)
    assert result["chamfer"] == pytest.approx(chamfer, rel=0.05)
    assert result["chamfer_x1e5"] == pytest.approx(result["chamfer"] * 1e5)
    assert result["f1"] == pytest.approx(f1, abs=0.01)
    assert result["precision"] == pytest.approx(result["recall"], abs=0.01)
    assert result["nc"] > 0.99
    assert (result["n_vertices"], result["n_triangles"]) == (8, 12)


@pytest.mark.parametrize("offset, f1", [(0.001, None), (0.01, 0.0)])
def test_offset_surface(cube, offset, f1):
    # Every face of the prediction lies `offset` outside the ground truth's: in NDC units that is
    # offset / sqrt(3), added in quadrature to the sampling floor.
    vertices, triangles = cube
    grown = (vertices - 0.5) * (1 + 2 * offset) + 0.5
    result = evaluate((grown, triangles), cube, n_samples=20_000)
    floor, _ = sampling_floor(2.0, 20_000, 0.003)
    assert result["chamfer"] == pytest.approx(2 * offset**2 / 3 + floor, rel=0.1)
    if f1 is not None:
        assert result["f1"] == f1
    else:
        assert result["f1"] > 0.15
    assert result["nc"] > 0.98


def test_uses_the_ground_truth_frame(cube):
    vertices, triangles = cube
    rng = np.random.default_rng(0)
    pred = (vertices * [1.0, 1.1, 0.9] + rng.normal(scale=0.01, size=vertices.shape), triangles)
    base = evaluate(pred, cube, n_samples=5000)
    moved = evaluate((pred[0] * 37.0 + [5, -3, 100], triangles), (vertices * 37.0 + [5, -3, 100], triangles),
                     n_samples=5000)
    for key in KEYS:
        assert moved[key] == pytest.approx(base[key], rel=1e-6, abs=1e-12)
    # Scaling only the prediction is an error the metric must see.
    assert evaluate((pred[0] * 2, triangles), cube, n_samples=5000)["chamfer"] > 10 * base["chamfer"]


def test_open3d_and_array_inputs_agree_and_seed_is_reproducible(cube):
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.5, 10).translate([0.5, 0.5, 0.5])
    first = evaluate(sphere, box, n_samples=3000, seed=4)
    assert first == evaluate(mesh_arrays(sphere), cube, n_samples=3000, seed=4)
    assert first != evaluate(sphere, box, n_samples=3000, seed=5)


def test_normal_consistency_ignores_orientation(cube):
    vertices, triangles = cube
    flipped = evaluate((vertices, triangles[:, ::-1]), cube, n_samples=5000)
    assert flipped["nc"] == pytest.approx(evaluate(cube, cube, n_samples=5000)["nc"], abs=0.01)
    assert flipped["nc"] > 0.97


@pytest.mark.parametrize("kwargs, error, match", [
    ({"n_samples": 0}, ValueError, "n_samples must be >= 1"),
    ({"n_samples": 1.5}, TypeError, "n_samples must be an integer"),
    ({"delta": 0.0}, ValueError, "delta must be finite and > 0"),
    ({"delta": np.nan}, ValueError, "delta must be finite and > 0"),
])
def test_argument_errors(cube, kwargs, error, match):
    with pytest.raises(error, match=match):
        evaluate(cube, cube, **kwargs)


def test_mesh_errors(cube):
    empty = (np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="pred has no triangles"):
        evaluate(empty, cube)
    with pytest.raises(ValueError, match="gt has no triangles"):
        evaluate(cube, empty)
    with pytest.raises(TypeError, match="pred must be"):
        evaluate("pred.obj", cube)


@pytest.mark.parametrize("name", ["organic_bunny.off", "cad_fandisk.obj"])
def test_dev_marching_cubes_baseline(dev_meshes, name):
    gt = load_mesh(dev_meshes / name)
    frame = fit_frame(gt)
    vertices, triangles = marching_cubes(sdf_grid(frame.apply_mesh(gt), 32))
    # Back in the file's units: the metric must not care which frame the pair arrives in.
    pred = (frame.invert(vertices), triangles)
    result = evaluate(pred, gt, n_samples=50_000)
    assert 0.3 < result["f1"] < 0.95
    assert 1e-6 < result["chamfer"] < 1e-4
    assert result["nc"] > 0.9
    assert result["n_triangles"] == triangles.shape[0]
    same = evaluate((vertices, triangles), frame.apply_mesh(gt), n_samples=50_000)
    assert same["chamfer"] == pytest.approx(result["chamfer"], rel=1e-6)


def test_triangle_quality():
    """An octahedron judged against itself: nothing off-normal; a flattened one has slivers."""
    vertices = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    triangles = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    assert triangle_quality((vertices, triangles), (vertices, triangles)) == {
        "off_normal_share": 0.0, "sliver_share": 0.0, "off_normal_area_share": 0.0}
    flat = vertices * [1, 1, 0.01]
    quality = triangle_quality((flat, triangles), (vertices, triangles))
    assert quality["sliver_share"] == 0.0 and quality["off_normal_share"] == quality["off_normal_area_share"] == 1.0
    # The top apex raised to z = 10: its four faces (area |(10, 10, 1)| / 2 each) are turned 31 degrees
    # or more from the octahedron's, the bottom four (area sqrt(3) / 2) are its own.
    spire = vertices.copy()
    spire[4, 2] = 10
    quality = triangle_quality((spire, triangles), (vertices, triangles))
    top = np.sqrt(201) / 2
    assert quality["off_normal_share"] == 0.5
    assert quality["off_normal_area_share"] == pytest.approx(top / (top + np.sqrt(3) / 2))
    needle = vertices * [1, 0.02, 0.02]
    assert triangle_quality((needle, triangles), (needle, triangles))["sliver_share"] == 1.0


@pytest.mark.parametrize("options, match", [({"max_angle": 0}, "max_angle"), ({"max_angle": 91}, "max_angle"),
                                            ({"sliver_angle": -1}, "sliver_angle"), ({"sliver_angle": np.nan}, "sliver_angle")])
def test_triangle_quality_bad_options(options, match):
    octahedron = o3d.geometry.TriangleMesh.create_octahedron()
    with pytest.raises(ValueError, match=match):
        triangle_quality(octahedron, octahedron, **options)
    with pytest.raises(ValueError, match="pred has no triangles"):
        triangle_quality((np.eye(3), np.zeros((0, 3), int)), octahedron)
