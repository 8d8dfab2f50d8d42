"""map_rows: row-wise work in blocks over threads gives the whole call's answer to the last bit."""
import numpy as np
import pytest

from voro3d import rowblocks
from voro3d.pointcloud.preprocess import _plane_residuals, _quadric_residuals


def _neighbourhoods(n, k, seed=0):
    return np.random.default_rng(seed).normal(size=(n, k, 3))


@pytest.mark.parametrize("threads", [1, 2])
def test_blocks_give_the_whole_calls_values_to_the_last_bit(monkeypatch, threads):
    monkeypatch.setattr(rowblocks, "ROW_THREADS", threads)
    wide, near = _neighbourhoods(10_001, 25), _neighbourhoods(10_001, 9, seed=1)
    # 10,001 rows in blocks of 1,000: the last block holds one row.
    assert np.array_equal(rowblocks.map_rows(_plane_residuals, wide, block=1000), _plane_residuals(wide))
    assert np.array_equal(rowblocks.map_rows(_quadric_residuals, near, block=1000), _quadric_residuals(near))


def test_tuple_outputs_and_several_inputs_are_joined_in_order():
    a, b = np.arange(10.0), np.arange(10.0)[:, None] * np.ones((1, 3))
    first, second = rowblocks.map_rows(lambda x, y: (x * 2, y.sum(axis=1)), a, b, block=3)
    assert np.array_equal(first, a * 2) and np.array_equal(second, 3 * a)


def test_one_block_or_none_calls_the_function_once():
    calls = []
    rowblocks.map_rows(lambda x: calls.append(len(x)) or x, np.zeros(5), block=8)
    rowblocks.map_rows(lambda x: calls.append(len(x)) or x, np.zeros(0), block=8)
    assert calls == [5, 0]
