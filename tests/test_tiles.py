import importlib.util

import numpy as np
import pytest

import voro3d.pointcloud.tiles as tiles_module
from voro3d import fitting
from voro3d.fitting import fit_schedule, optimise_generators
from voro3d.generators import initial_generators
from voro3d.metrics import evaluate
from voro3d.pointcloud import cloud_mesh, reconstruct_points
from voro3d.pointcloud.tiles import analysis_subset, fit_tiles, seam_tile, split_tiles
from voro3d.sampling import sample_surface
from voro3d.shapes import example_mesh
from voro3d.watertight import check_watertight


@pytest.fixture(scope="module")
def sphere_samples():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(40_000, 3))
    points = 0.8 * points / np.linalg.norm(points, axis=1, keepdims=True)
    return points, initial_generators(points, 24)


def test_split_tiles_gives_every_generator_one_core(sphere_samples):
    samples, generators = sphere_samples
    tiles = split_tiles(samples, generators, max_samples=6_000, margin=0.1)
    assert len(tiles) >= 7
    owner = np.concatenate([tile.generators[:tile.n_core] for tile in tiles])
    assert np.array_equal(np.sort(owner), np.arange(len(generators)))
    for tile in tiles:
        core = generators[tile.generators[:tile.n_core]]
        assert np.all((core >= tile.low) & (core < tile.high))
        assert len(tile.generators) == len(np.unique(tile.generators))
        inner = np.all((samples >= tile.low) & (samples < tile.high), axis=1)
        assert inner.sum() <= 6_000
        # The margin: every sample within it is taken, none beyond it.
        grown = np.all((samples >= tile.low - 0.1) & (samples < tile.high + 0.1), axis=1)
        assert np.array_equal(np.sort(tile.samples), np.flatnonzero(grown))


def test_tiles_that_see_everything_give_the_untiled_fit(sphere_samples):
    # A margin over the whole box: each tile's fit is the whole fit, so the merged generators are
    # the untiled ones exactly (and with no cut nearer than the seam width, no seam pass).
    samples, generators = sphere_samples
    options = fit_schedule(steps=30)
    whole = optimise_generators(samples, generators, 24, reach=None, threads=1, **options).generators
    tiles = split_tiles(samples, generators, max_samples=15_000, margin=10.0)
    assert len(tiles) > 1
    merged = fit_tiles(samples, generators, 24, reach=None, tiles=tiles, seam=0.0, workers=1, options=options)
    assert np.array_equal(merged, whole)


@pytest.mark.parametrize("backend", ["kernel", "torch"])
def test_the_seam_pass_moves_only_generators_at_the_cuts(sphere_samples, backend, monkeypatch):
    if backend == "torch":
        pytest.importorskip("torch")
        monkeypatch.setattr(fitting, "_CPU_KERNEL", False)
    samples, generators = sphere_samples
    tiles = split_tiles(samples, generators, max_samples=15_000, margin=0.2)
    seam = seam_tile(samples, generators, tiles, width=0.1, margin=0.1)
    free = generators[seam.generators[:seam.n_core]]
    assert 0 < seam.n_core < len(generators)
    distance = np.full(len(free), np.inf)
    for tile in tiles:
        inside = np.all((free >= tile.low) & (free < tile.high), axis=1)
        distance[inside] = np.minimum(free[inside] - tile.low, tile.high - free[inside]).min(axis=1)
    assert np.all(distance < 0.1)
    fixed = np.zeros(len(seam.generators), bool)
    fixed[seam.n_core:] = True
    start = generators[seam.generators]
    moved = optimise_generators(samples[seam.samples], start, 24, reach=None, threads=1, fixed=fixed,
                                **fit_schedule(steps=20)).generators
    # Held where they are (both loops keep float32 positions).
    assert np.array_equal(moved[seam.n_core:], start[seam.n_core:].astype(np.float32))
    assert not np.array_equal(moved[:seam.n_core], start[:seam.n_core])


def test_analysis_subset_only_for_large_clouds(monkeypatch):
    assert analysis_subset(1000, 0) is None
    monkeypatch.setattr(tiles_module, "TILE_POINTS", 500)
    monkeypatch.setattr(tiles_module, "ANALYSIS_POINTS", 300)
    subset = analysis_subset(1000, 0)
    assert len(subset) == 300 and np.all(np.diff(subset) > 0)
    assert np.array_equal(subset, analysis_subset(1000, 0))


def test_unknown_engine_is_refused():
    points, normals = sample_surface(example_mesh("sphere"), 2000, seed=0)
    with pytest.raises(ValueError, match="engine must be one of"):
        reconstruct_points(points, normals, engine="dask")
    with pytest.raises(ValueError, match="workers"):
        reconstruct_points(points, normals, workers=0)


@pytest.fixture(scope="module")
def tiled_bracket():
    """A dense bracket cloud reconstructed as a large one: planned on a subset, fitted in tiles."""
    mesh = example_mesh("bracket")
    points, normals = sample_surface(mesh, 150_000, seed=2)
    patch = pytest.MonkeyPatch()
    patch.setattr(tiles_module, "TILE_POINTS", 100_000)
    patch.setattr(tiles_module, "ANALYSIS_POINTS", 60_000)
    runs = {}
    try:
        for name, tile_samples, workers in (("tiled", 40_000, 2), ("in-process", 40_000, 1), ("whole", 10**9, 1)):
            patch.setattr(tiles_module, "TILE_SAMPLES", tile_samples)
            shape, target, info = reconstruct_points(points, normals, steps=60, workers=workers)
            runs[name] = (cloud_mesh(shape, target), info)
        if importlib.util.find_spec("ray") is not None:
            patch.setattr(tiles_module, "TILE_SAMPLES", 40_000)
            shape, target, info = reconstruct_points(points, normals, steps=60, workers=2, engine="ray")
            runs["ray"] = (cloud_mesh(shape, target), info)
    finally:
        patch.undo()
    return mesh, runs


def test_a_large_cloud_is_fitted_in_tiles_into_one_closed_mesh(tiled_bracket):
    mesh, runs = tiled_bracket
    out, info = runs["tiled"]
    assert info.tiles > 1 and runs["whole"][1].tiles == 1
    report = check_watertight(out)
    assert report.watertight and report.self_intersecting_pairs == 0
    assert len(np.unique(np.asarray(out.cluster_connected_triangles()[0]))) == 1
    tiled, whole = (evaluate(runs[name][0], mesh) for name in ("tiled", "whole"))
    assert tiled["chamfer_x1e5"] < 1.05 * whole["chamfer_x1e5"]
    assert tiled["nc"] > whole["nc"] - 0.005


def test_the_tiles_give_the_same_mesh_wherever_they_run(tiled_bracket):
    _, runs = tiled_bracket
    meshes = [runs[name][0] for name in ("tiled", "in-process", "ray") if name in runs]
    for other in meshes[1:]:
        assert np.array_equal(np.asarray(other.vertices), np.asarray(meshes[0].vertices))
        assert np.array_equal(np.asarray(other.triangles), np.asarray(meshes[0].triangles))


def test_objects_far_apart_are_found_on_a_subset(monkeypatch):
    # A cloud over SEPARATE_POINTS (and TILE_POINTS) is split into objects on a subset, every point
    # then going with its nearest subset point: both spheres are kept, each with all its points; a
    # clump too small to stand alone stays with the rest.
    import voro3d.reconstruction as reconstruction
    from voro3d.reconstruction import _objects, reconstruct

    points, _ = sample_surface(example_mesh("sphere"), 3000, seed=3)
    cloud = np.vstack([points, points + [6.0, 0.0, 0.0]])
    monkeypatch.setattr(reconstruction, "SEPARATE_POINTS", 1500)
    monkeypatch.setattr(tiles_module, "TILE_POINTS", 4000)
    monkeypatch.setattr(tiles_module, "ANALYSIS_POINTS", 2000)
    groups = _objects(cloud)
    assert sorted(len(group) for group in groups) == [3000, 3000]
    assert np.array_equal(np.sort(np.concatenate(groups)), np.arange(6000))
    assert len(_objects(cloud[:3050])) == 1
    out = reconstruct(cloud, grid=32, steps=100)
    assert check_watertight(out).watertight
    assert len(np.unique(np.asarray(out.cluster_connected_triangles()[0]))) == 2


def test_a_script_without_a_main_guard_gets_a_clear_error(tmp_path):
    # The spawned tile workers import the script again, which starts its own tiled reconstruct mid-bootstrap.
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text(
        "from voro3d.pointcloud import reconstruct_points, tiles\n"
        "from voro3d.sampling import sample_surface\n"
        "from voro3d.shapes import example_mesh\n"
        "tiles.TILE_POINTS, tiles.ANALYSIS_POINTS, tiles.TILE_SAMPLES = 3000, 2000, 3000\n"
        "points, normals = sample_surface(example_mesh('sphere'), 4000, seed=0)\n"
        "reconstruct_points(points, normals, grid=16, steps=10, workers=2)\n")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert run.returncode != 0
    assert "if __name__ == \"__main__\":" in run.stderr.splitlines()[-1]
