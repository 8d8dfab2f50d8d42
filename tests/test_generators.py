import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from voro3d import sampling
from voro3d.generators import grid_nodes, initial_generators


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
