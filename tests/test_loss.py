import numpy as np
import pytest
import torch
from scipy.spatial import Delaunay, cKDTree

from voro3d.generators import initial_generators
from voro3d import loss as loss_module
from voro3d.loss import (DEFAULT_K, KNN_BLOCK, _argmin_rows_, bisector_distance, knn_candidates,
                         nearest_indices_on_device, voroloss)

DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")),
]


def _cell_boundary_distance(samples, generators):
    """Distance from each sample to the boundary of the Voronoi cell holding it, by brute force.

    The cell of q_i is the intersection of the half-spaces of its Voronoi (Delaunay) neighbours,
    taken here from Qhull, independently of any kNN; x lies inside that convex cell, so its
    distance to the boundary is its distance to the nearest facet plane.
    """
    nearest = np.argmin(((samples[:, None] - generators[None]) ** 2).sum(-1), axis=1)
    indptr, neighbours = Delaunay(generators).vertex_neighbor_vertices
    result = np.empty(len(samples))
    for row, (x, i) in enumerate(zip(samples, nearest)):
        q_j = generators[neighbours[indptr[i]:indptr[i + 1]]]
        edge = q_j - generators[i]
        result[row] = np.min((edge * ((generators[i] + q_j) / 2 - x)).sum(1) / np.linalg.norm(edge, axis=1))
    return result


def _sphere_band(grid=24, n=4000, radius=0.55, seed=0):
    """A fitted-like configuration: generators on the grid band around a sphere, samples on it."""
    rng = np.random.default_rng(seed)
    samples = rng.normal(size=(n, 3))
    samples *= radius / np.linalg.norm(samples, axis=1, keepdims=True)
    generators = initial_generators(samples, grid)
    # Off the grid, so that no sample has tied nearest generators.
    generators = generators + rng.normal(scale=0.1 * 2 / (grid - 1), size=generators.shape)
    return samples, generators


@pytest.mark.parametrize("device", DEVICES)
def test_matches_cell_boundary_distance(device):
    rng = np.random.default_rng(0)
    generators = rng.uniform(-1, 1, (60, 3))
    samples = rng.uniform(-0.8, 0.8, (300, 3))
    reference = np.mean(_cell_boundary_distance(samples, generators) ** 2)
    generators_t = torch.tensor(generators, device=device)
    np.testing.assert_allclose(voroloss(samples, generators_t, k=60).item(), reference, rtol=1e-12)
    # The official k = 11 already finds every sample's nearest facet here.
    np.testing.assert_allclose(voroloss(samples, generators_t).item(), reference, rtol=1e-12)


@pytest.mark.parametrize("device", DEVICES)
def test_raising_k_does_not_change_a_fitted_like_loss(device):
    samples, generators = _sphere_band()
    generators_t = torch.tensor(generators, device=device)
    loss_11 = voroloss(samples, generators_t, k=11).item()
    loss_32 = voroloss(samples, generators_t, k=32).item()
    assert loss_11 > 0
    assert loss_11 == pytest.approx(loss_32, rel=1e-12)


def test_default_k_is_the_official_one():
    assert DEFAULT_K == 11


@pytest.mark.parametrize("device", DEVICES)
def test_gradcheck_float64(device):
    rng = np.random.default_rng(1)
    generators = torch.tensor(rng.uniform(-1, 1, (30, 3)), device=device, requires_grad=True)
    samples = torch.tensor(rng.uniform(-0.7, 0.7, (80, 3)), device=device, requires_grad=True)
    candidates = knn_candidates(samples, generators, k=11)
    assert torch.autograd.gradcheck(lambda q, x: voroloss(x, q, candidates=candidates), (generators, samples))


@pytest.mark.parametrize("device", DEVICES)
def test_gradient_flows_to_both_generators_of_the_bisector(device):
    generators = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64, device=device,
                              requires_grad=True)
    samples = torch.tensor([[0.1, 0.3, 0.0]], dtype=torch.float64, device=device)
    loss = voroloss(samples, generators)
    loss.backward()
    # d = 0.4 from the bisector x = 0.5. dd/dq_i = x - q_i + d u and dd/dq_j = q_j - x - d u
    # (|q_j - q_i| = 1, u = e_x): both shift the plane along x, and tilt it about the sample's y.
    assert loss.item() == pytest.approx(0.16)
    np.testing.assert_allclose(generators.grad.cpu().numpy(), [[0.4, 0.24, 0], [0.4, -0.24, 0]], atol=1e-12)


@pytest.mark.parametrize("device", DEVICES)
def test_float32_agrees_with_float64(device):
    samples, generators = _sphere_band(grid=16, n=2000)
    loss_64 = voroloss(samples, torch.tensor(generators, device=device)).item()
    loss_32 = voroloss(samples, torch.tensor(generators, dtype=torch.float32, device=device)).item()
    assert loss_32 == pytest.approx(loss_64, rel=1e-4)


def test_stale_candidates_are_re_ranked():
    samples, generators = _sphere_band(grid=16, n=2000)
    candidates = knn_candidates(samples, generators, k=16)
    generators_t = torch.tensor(generators)
    expected = voroloss(samples, generators_t, candidates=candidates).item()
    # Column order does not matter: the nearest candidate is found again.
    shuffled = np.random.default_rng(0).permuted(candidates, axis=1)
    assert voroloss(samples, generators_t, candidates=shuffled).item() == pytest.approx(expected, rel=1e-12)
    # Nor does a small move of the generators after the search.
    moved = generators + np.random.default_rng(1).normal(scale=1e-3, size=generators.shape)
    assert voroloss(samples, torch.tensor(moved), candidates=candidates).item() == pytest.approx(
        voroloss(samples, torch.tensor(moved), k=16).item(), rel=1e-12)


def test_blocks_give_the_same_loss(monkeypatch):
    samples, generators = _sphere_band(grid=16, n=1000)
    generators_t = torch.tensor(generators)
    whole = voroloss(samples, generators_t).item()
    monkeypatch.setattr(loss_module, "PAIR_BLOCK", 37)
    assert voroloss(samples, generators_t).item() == whole


def test_copies_of_the_nearest_generator_are_skipped():
    rng = np.random.default_rng(2)
    generators = rng.uniform(-1, 1, (40, 3))
    samples = rng.uniform(-0.5, 0.5, (100, 3))
    doubled = torch.tensor(np.vstack([generators, generators[:10]]), requires_grad=True)
    loss = voroloss(samples, doubled, k=20)
    loss.backward()
    assert loss.item() == pytest.approx(voroloss(samples, torch.tensor(generators), k=20).item(), rel=1e-12)
    assert torch.isfinite(doubled.grad).all()


def test_bisector_distance_of_coincident_generators_is_zero_with_zero_gradient():
    generators = torch.zeros((3, 2), dtype=torch.float64, requires_grad=True)
    samples = torch.tensor([[0.3], [0.1], [0.2]], dtype=torch.float64)
    index = torch.tensor([0])
    distance = bisector_distance(samples, generators, index, index + 1)
    distance.sum().backward()
    assert distance.item() == 0
    assert torch.count_nonzero(generators.grad) == 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("rows", [2, 11, 16, 17, 40])
def test_argmin_rows_matches_argmin(dtype, rows):
    values = torch.rand(rows, 500, dtype=dtype, generator=torch.Generator().manual_seed(rows))
    values[rows // 2, ::7] = float("inf")
    values[:, 3] = float("inf")
    values[:, 5] = 0.25  # ties go to the first row
    expected = values.argmin(0)
    found, finite = _argmin_rows_(values.clone())
    assert torch.equal(found[finite], expected[finite])
    assert finite.tolist() == [column != 3 for column in range(500)]
    assert found[5] == 0


def test_knn_candidates_are_the_nearest_in_order():
    rng = np.random.default_rng(3)
    generators = rng.uniform(-1, 1, (500, 3))
    samples = rng.uniform(-1, 1, (2000, 3))
    found = knn_candidates(samples, generators, k=11)
    assert found.shape == (2000, 11) and found.dtype == np.int64
    distance, _ = cKDTree(generators).query(samples, k=11)
    found_distance = np.linalg.norm(samples[:, None] - generators[found], axis=-1)
    np.testing.assert_allclose(found_distance, distance, rtol=1e-5)


def test_device_search_matches_the_kd_tree_across_blocks():
    rng = np.random.default_rng(4)
    generators = rng.uniform(-1, 1, (300, 3))
    samples = rng.uniform(-1, 1, (KNN_BLOCK + 500, 3))  # two blocks
    found = nearest_indices_on_device(torch.from_numpy(samples), torch.from_numpy(generators), 11)
    assert found.dtype == torch.int64 and found.shape == (samples.shape[0], 11)
    distance, _ = cKDTree(generators).query(samples, k=11)
    found_distance = np.linalg.norm(samples[:, None] - generators[found.numpy()], axis=-1)
    np.testing.assert_allclose(found_distance, distance, rtol=1e-6)


def test_knn_candidates_cap_k_and_accept_tensors():
    generators = torch.rand(5, 3)
    found = knn_candidates(torch.rand(7, 3), generators, k=11)
    assert found.shape == (7, 5)
    assert np.all(np.sort(found, axis=1) == np.arange(5))


def test_loss_is_zero_on_bisectors():
    generators = torch.tensor([[-1.0, 0, 0], [1.0, 0, 0]], dtype=torch.float64)
    samples = np.array([[0.0, 0.3, -0.2], [0.0, -5.0, 1.0]])
    assert voroloss(samples, generators).item() == 0


@pytest.mark.parametrize(
    "samples, generators, kwargs, error, match",
    [
        (np.zeros((4, 3)), np.zeros((5, 3)), {}, TypeError, "generators"),
        (np.zeros((4, 3)), torch.zeros(5, 2), {}, ValueError, "generators"),
        (np.zeros((4, 3)), torch.zeros(5, 3, dtype=torch.int64), {}, ValueError, "generators"),
        (np.zeros((4, 3)), torch.zeros(1, 3), {}, ValueError, "generators"),
        (np.zeros((4, 3)), torch.full((5, 3), float("nan")), {}, ValueError, "generators"),
        (np.zeros((4, 2)), torch.rand(5, 3), {}, ValueError, "samples"),
        (torch.zeros(4, 2), torch.rand(5, 3), {}, ValueError, "samples"),
        (np.zeros((0, 3)), torch.rand(5, 3), {}, ValueError, "samples"),
        (np.full((4, 3), np.inf), torch.rand(5, 3), {}, ValueError, "samples"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"k": 1}, ValueError, "k"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"candidates": np.zeros((4, 1), int)}, ValueError, "candidates"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"candidates": np.zeros((3, 2), int)}, ValueError, "candidates"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"candidates": np.full((4, 2), 5)}, ValueError, "candidates"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"candidates": np.zeros((4, 2))}, ValueError, "candidates"),
        (np.zeros((4, 3)), torch.rand(5, 3), {"k": 4, "candidates": np.zeros((4, 2), int)}, ValueError,
         "k or candidates, not both"),
    ],
)
def test_bad_input(samples, generators, kwargs, error, match):
    with pytest.raises(error, match=match):
        voroloss(samples, generators, **kwargs)


@pytest.mark.parametrize(
    "samples, generators, k, match",
    [
        (np.zeros((4, 2)), np.zeros((5, 3)), 11, "samples"),
        (np.zeros((4, 3)), np.zeros((1, 3)), 11, "generators"),
        (np.zeros((4, 3)), np.zeros((5, 3)), 1, "k"),
    ],
)
def test_knn_candidates_bad_input(samples, generators, k, match):
    with pytest.raises(ValueError, match=match):
        knn_candidates(samples, generators, k=k)
