import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from voro3d import sampling
from voro3d.generators import AdaptiveBand, grid_nodes, initial_generators


def _reference(samples, grid):
    """Loop version of the official rule: the 8 corner nodes of every voxel holding a sample."""
    h = 2.0 / (grid - 1)
    nodes = set()
    for point in samples:
        low = [min(max(int(np.floor((c + 1) / h)), 0), grid - 2) for c in point]
        for offset in itertools.product((0, 1), repeat=3):
            i, j, k = (low[d] + offset[d] for d in range(3))
            nodes.add((i * grid + j) * grid + k)
    return grid_nodes(grid)[sorted(nodes)]


def test_grid_nodes_is_the_sampling_one():
    assert grid_nodes is sampling.grid_nodes


def test_grid_nodes_order_and_span():
    nodes = grid_nodes(4)
    assert nodes.shape == (64, 3) and nodes.dtype == np.float64
    np.testing.assert_array_equal(nodes[0], [-1, -1, -1])
    np.testing.assert_array_equal(nodes[-1], [1, 1, 1])
    # C order over (i, j, k) = (x, y, z): z varies fastest.
    np.testing.assert_allclose(nodes[1], [-1, -1, -1 / 3])
    np.testing.assert_allclose(nodes[4], [-1, -1 / 3, -1])
    np.testing.assert_allclose(nodes[16], [-1 / 3, -1, -1])


def test_one_sample_gives_its_voxel_corners():
    generators = initial_generators([[0.01, 0.02, 0.03]], 5)
    assert generators.shape == (8, 3)
    expected = np.array(list(itertools.product((0.0, 0.5), repeat=3)))
    np.testing.assert_array_equal(generators, expected)


def test_samples_in_one_voxel_are_deduplicated():
    samples = np.array([[0.1, 0.1, 0.1], [0.2, 0.3, 0.4], [0.45, 0.01, 0.2]])
    assert initial_generators(samples, 5).shape == (8, 3)


def test_neighbouring_voxels_share_corners():
    # Two voxels side by side along x: 12 distinct corners.
    generators = initial_generators([[0.1, 0.1, 0.1], [0.6, 0.1, 0.1]], 5)
    assert generators.shape == (12, 3)


def test_boundary_samples_are_clipped_into_the_grid():
    samples = np.array([[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0], [1.5, 0.0, -2.0]])
    generators = initial_generators(samples, 3)
    assert np.all(np.abs(generators) <= 1)
    np.testing.assert_array_equal(generators, _reference(np.clip(samples, -1, 1), 3))


def test_rows_are_grid_nodes_bit_for_bit():
    rng = np.random.default_rng(0)
    samples = rng.uniform(-0.9, 0.9, (500, 3))
    generators = initial_generators(samples, 17)
    nodes = grid_nodes(17)
    index = np.rint((generators + 1) * 8).astype(int) @ [17 * 17, 17, 1]
    assert np.all(np.diff(index) > 0), "rows must be in increasing node order"
    np.testing.assert_array_equal(generators, nodes[index])


def test_sphere_band_is_thin():
    rng = np.random.default_rng(1)
    samples = rng.normal(size=(20000, 3))
    samples *= 0.5 / np.linalg.norm(samples, axis=1, keepdims=True)
    grid = 32
    generators = initial_generators(samples, grid)
    h = 2 / (grid - 1)
    radius = np.linalg.norm(generators, axis=1)
    # Every corner of a voxel that the sphere crosses lies within one voxel diagonal of it.
    assert np.all(np.abs(radius - 0.5) <= np.sqrt(3) * h + 1e-12)
    assert generators.shape[0] < grid**3 / 4


@settings(max_examples=60, deadline=None)
@given(
    samples=arrays(np.float64, st.tuples(st.integers(1, 40), st.just(3)),
                   elements=st.floats(-1, 1, allow_nan=False, width=64)),
    grid=st.integers(2, 9),
)
def test_matches_loop_reference(samples, grid):
    np.testing.assert_array_equal(initial_generators(samples, grid), _reference(samples, grid))


@pytest.mark.parametrize(
    "samples, grid, error, match",
    [
        (np.zeros((4, 2)), 8, ValueError, "samples"),
        (np.zeros((0, 3)), 8, ValueError, "samples"),
        (np.array([[0.0, np.nan, 0.0]]), 8, ValueError, "samples"),
        (np.array([["a", "b", "c"]]), 8, ValueError, "samples"),
        (np.zeros((4, 3)), 1, ValueError, "grid"),
        (np.zeros((4, 3)), 8.0, TypeError, "grid"),
    ],
)
def test_bad_input(samples, grid, error, match):
    with pytest.raises(error, match=match):
        initial_generators(samples, grid)


def _sphere(n=20_000, radius=0.8, seed=0):
    points = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * points / np.linalg.norm(points, axis=1, keepdims=True)


@pytest.mark.parametrize("grid", [17, 33, 64])
def test_band_without_levels_is_the_uniform_band(grid):
    points = _sphere()
    band = AdaptiveBand(points, grid, levels=0, tolerance=0.1)
    np.testing.assert_array_equal(band.generators(), initial_generators(points, grid))
    np.testing.assert_array_equal(band.level_of(points), 0)


def test_flat_surface_stays_coarse_and_curved_one_is_refined():
    rng = np.random.default_rng(1)
    plane = np.c_[rng.uniform(-0.9, 0.9, (200_000, 2)), np.full(200_000, 0.013)]
    flat = AdaptiveBand(plane, 129, levels=2, tolerance=0.1)
    assert [leaves.size for leaves in flat.leaves[:2]] == [0, 0]  # all coarsest
    np.testing.assert_array_equal(flat.level_of(plane), 2)
    assert flat.generators().shape[0] < initial_generators(plane, 129).shape[0] / 10
    # A small sphere (radius 4 fine voxels) bends within every coarse voxel: none is left coarse.
    ball = AdaptiveBand(_sphere(radius=0.0625), 129, levels=2, tolerance=0.1)
    assert ball.leaves[2].size == 0 and ball.leaves[1].size > 0
    # The tolerance trades generators for detail, monotonically.
    sphere = _sphere()
    counts = [AdaptiveBand(sphere, 129, levels=2, tolerance=t).generators().shape[0] for t in (0.0, 0.01, 0.1)]
    assert counts[0] == initial_generators(sphere, 129).shape[0] and counts[0] > counts[1] > counts[2]


def test_band_generators_lie_on_the_fine_lattice_and_cover_every_leaf():
    sphere = _sphere()
    band = AdaptiveBand(sphere, 65, levels=2, tolerance=0.01)
    generators = band.generators()
    nodes = np.round((generators + 1.0) / 2.0 * 64)
    np.testing.assert_allclose(np.linspace(-1, 1, 65)[nodes.astype(int)], generators)
    assert np.unique(nodes, axis=0).shape[0] == generators.shape[0]
    # Every point's leaf has its 8 corners among the generators.
    level = band.level_of(sphere)
    size = 2.0 ** level * (2.0 / 64)
    lowest = np.floor((sphere + 1.0) / size[:, None]) * size[:, None] - 1.0
    corners = lowest[:, None, :] + np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) * size[:, None, None]
    corners = np.minimum(corners, 1.0)
    keys = {tuple(row) for row in np.round((generators + 1.0) * 32).astype(int)}
    assert all(tuple(row) in keys for row in np.round((corners.reshape(-1, 3) + 1.0) * 32).astype(int))
    np.testing.assert_allclose(band.density(sphere), 0.25 ** level)


@pytest.mark.parametrize("kwargs, match", [(dict(levels=-1, tolerance=0.1), "levels"),
                                           (dict(levels=1, tolerance=-0.1), "tolerance"),
                                           (dict(levels=1, tolerance=float("nan")), "tolerance")])
def test_band_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AdaptiveBand(_sphere(100), 33, **kwargs)
