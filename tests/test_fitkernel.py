"""The compiled fit step voro3d._fitkernel: the torch VoroLoss's value and gradient, the exact kNN
search, thread-count independence, every input check, the GIL released, and a fit through it as
good as through torch."""
import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from voro3d import _cpufit, _fitkernel
from voro3d.fitloop import Adam
from voro3d import fitting as fit_module
from voro3d.extract import extract_mesh
from voro3d.generators import initial_generators
from voro3d.loss import knn_candidates, voroloss
from voro3d.watertight import check_watertight


def _band(grid=16, n=3000, seed=0):
    """Generators on the grid band around a sphere, jittered off the grid; samples on the sphere."""
    rng = np.random.default_rng(seed)
    samples = rng.normal(size=(n, 3))
    samples *= 0.55 / np.linalg.norm(samples, axis=1, keepdims=True)
    generators = initial_generators(samples, grid) + rng.normal(scale=0.2 * 2 / (grid - 1), size=(1, 3))
    generators += rng.normal(scale=0.1 * 2 / (grid - 1), size=generators.shape)
    return samples, generators


def _torch_loss_and_grad(samples, generators, candidates):
    generators_t = torch.tensor(generators, dtype=torch.float64, requires_grad=True)
    loss = voroloss(torch.tensor(samples, dtype=torch.float64), generators_t, candidates=candidates)
    loss.backward()
    return loss.item(), generators_t.grad.numpy()


@pytest.mark.parametrize("seed", range(4))
def test_matches_torch_in_float64(seed):
    rng = np.random.default_rng(seed)
    generators = rng.uniform(-1, 1, (200, 3))
    samples = rng.uniform(-0.9, 0.9, (3000, 3))
    # Shuffled columns: the kernel re-ranks the candidates, like torch.
    candidates = rng.permuted(knn_candidates(samples, generators, k=11), axis=1)
    expected_loss, expected_grad = _torch_loss_and_grad(samples, generators, candidates)
    grad = np.full_like(generators, np.nan)
    loss = _fitkernel.voroloss(samples, generators, candidates, grad, threads=2)
    assert loss == pytest.approx(expected_loss, rel=1e-12)
    # The gradient is summed in fixed point (2^-40 per term).
    np.testing.assert_allclose(grad, expected_grad, rtol=0, atol=1e-12 * np.abs(expected_grad).max() + 1e-14)


def test_matches_torch_on_a_fitted_like_band_with_strided_int32_views():
    samples, generators = _band()
    candidates = knn_candidates(samples, generators, k=11)
    expected_loss, expected_grad = _torch_loss_and_grad(samples, generators, candidates)
    # Coordinate-major storage read through transposed views, as the fit loop passes them.
    samples_t, generators_t = np.ascontiguousarray(samples.T), np.ascontiguousarray(generators.T)
    candidates_t = np.ascontiguousarray(candidates.T.astype(np.int32))
    grad_t = np.zeros_like(generators_t)
    loss = _fitkernel.voroloss(samples_t.T, generators_t.T, candidates_t.T, grad_t.T)
    assert loss == pytest.approx(expected_loss, rel=1e-12)
    np.testing.assert_allclose(grad_t.T, expected_grad, rtol=0, atol=1e-9 * np.abs(expected_grad).max())


def test_float32_agrees_with_float64():
    samples, generators = _band()
    candidates = knn_candidates(samples, generators, k=11)
    grad_64, grad_32 = np.zeros_like(generators), np.zeros(generators.shape, np.float32)
    loss_64 = _fitkernel.voroloss(samples, generators, candidates, grad_64)
    loss_32 = _fitkernel.voroloss(samples.astype(np.float32), generators.astype(np.float32), candidates, grad_32)
    assert loss_32 == pytest.approx(loss_64, rel=1e-4)
    np.testing.assert_allclose(grad_32, grad_64, rtol=0, atol=1e-3 * np.abs(grad_64).max())


def test_any_thread_count_gives_the_same_bits():
    samples, generators = _band(n=20_000)
    samples, generators = samples.astype(np.float32), generators.astype(np.float32)
    candidates = knn_candidates(samples, generators, k=11)
    results = []
    for threads in (1, 2, 3, 8):
        grad = np.zeros_like(generators)
        results.append((_fitkernel.voroloss(samples, generators, candidates, grad, threads=threads), grad))
    for loss, grad in results[1:]:
        assert loss == results[0][0]
        np.testing.assert_array_equal(grad, results[0][1])


def test_copies_of_the_nearest_generator_are_skipped():
    rng = np.random.default_rng(2)
    generators = rng.uniform(-1, 1, (40, 3))
    samples = rng.uniform(-0.5, 0.5, (100, 3))
    doubled = np.vstack([generators, generators[:10]])
    candidates = knn_candidates(samples, doubled, k=20)
    expected_loss, expected_grad = _torch_loss_and_grad(samples, doubled, candidates)
    grad = np.zeros_like(doubled)
    assert _fitkernel.voroloss(samples, doubled, candidates, grad) == pytest.approx(expected_loss, rel=1e-12)
    np.testing.assert_allclose(grad, expected_grad, rtol=0, atol=1e-12)
    # Every candidate a copy of the nearest: no bisector, zero loss and gradient.
    assert _fitkernel.voroloss(samples[:1], doubled, np.array([[0, 40]]), grad) == 0.0
    assert not grad.any()


def _sided_loss(samples, generators, candidates, sides):
    """The loss with sides, sample by sample: the nearest candidate i, then the nearest bisector
    with a candidate labelled unlike i (none: no term)."""
    total = 0.0
    for x, row in zip(samples, candidates):
        i = row[np.argmin(np.square(generators[row] - x).sum(axis=1))]
        others = [j for j in row if sides[j] != sides[i] and np.any(generators[j] != generators[i])]
        if others:
            e = generators[others] - generators[i]
            length = np.linalg.norm(e, axis=1)
            d = length / 2 - np.einsum("ij,j->i", e / length[:, None], x - generators[i])
            total += np.min(d * d)
    return total / len(samples)


@pytest.mark.parametrize("seed", range(3))
def test_sides_keep_the_bisector_between_differently_labelled_cells(seed):
    rng = np.random.default_rng(seed)
    generators = rng.uniform(-1, 1, (150, 3))
    samples = rng.uniform(-0.9, 0.9, (400, 3))
    candidates = knn_candidates(samples, generators, k=9)
    sides = rng.random(150) < 0.5
    grad = np.zeros_like(generators)
    loss = _fitkernel.voroloss(samples, generators, candidates, grad, threads=2, sides=sides)
    assert loss == pytest.approx(_sided_loss(samples, generators, candidates, sides), rel=1e-12)
    assert loss > _fitkernel.voroloss(samples, generators, candidates)  # fewer planes to choose from
    # The torch path (the CUDA one) picks the same pairs and so has the same loss and gradient.
    from voro3d.loss import bisector_distance, bisector_pairs

    samples_t = torch.tensor(samples.T.copy())
    generators_t = torch.tensor(generators.T.copy(), requires_grad=True)
    nearest, other = bisector_pairs(samples_t, generators_t.detach(), torch.tensor(candidates.T.copy()),
                                    sides_t=torch.tensor(sides))
    expected = bisector_distance(samples_t, generators_t, nearest, other).square().mean()
    expected.backward()
    assert loss == pytest.approx(expected.item(), rel=1e-12)
    np.testing.assert_allclose(grad, generators_t.grad.numpy().T, rtol=0, atol=1e-12)
    # All on one side: no face between them, nothing to fit.
    assert _fitkernel.voroloss(samples, generators, candidates, grad, sides=np.ones(150, bool)) == 0.0
    assert not grad.any()


def test_loss_without_gradient():
    samples, generators = _band(n=500)
    candidates = knn_candidates(samples, generators, k=11)
    assert _fitkernel.voroloss(samples, generators, candidates) == pytest.approx(
        voroloss(samples, torch.tensor(generators), candidates=candidates).item(), rel=1e-12)


SAMPLES = np.random.default_rng(0).uniform(-1, 1, (20, 3))
SITES = np.random.default_rng(1).uniform(-1, 1, (10, 3))
CANDIDATES = np.tile(np.arange(4), (20, 1))


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(samples=SAMPLES[:, :2]), ValueError, r"samples must have shape \(m, 3\), got \(20, 2\)"),
    (dict(samples=SAMPLES[:0]), ValueError, "samples must hold at least 1 point, got 0"),
    (dict(generators=SITES[:, None]), ValueError, r"generators must have shape \(n, 3\), got \(10, 1, 3\)"),
    (dict(generators=SITES[:1]), ValueError, "generators must hold at least 2 points, got 1"),
    (dict(candidates=CANDIDATES[:, :1]), ValueError, r"candidates must have shape \(m, c\) with c >= 2, got \(20, 1\)"),
    (dict(candidates=CANDIDATES[:5]), ValueError, r"candidates must have one row per sample, shape \(20, c\), got \(5, 4\)"),
    (dict(candidates=np.where(np.arange(20)[:, None] == 7, 10, CANDIDATES)), ValueError,
     r"candidates holds index 10 at row 7, outside \[0, 10\)"),
    (dict(candidates=np.where(np.arange(20)[:, None] == 3, -1, CANDIDATES)), ValueError,
     r"candidates holds index -1 at row 3, outside \[0, 10\)"),
    (dict(candidates=CANDIDATES.astype(float)), TypeError, "candidates must be an int32 or int64 array of indices, got dtype float64"),
    (dict(samples=np.where(np.arange(20)[:, None] == 4, np.nan, SAMPLES)), ValueError, "samples holds NaN or inf at row 4"),
    (dict(generators=np.where(np.arange(10)[:, None] == 2, np.inf, SITES)), ValueError, "generators holds NaN or inf at row 2"),
    (dict(samples=SAMPLES.astype(np.float16)), TypeError, "samples must be float32 or float64, got dtype float16"),
    (dict(generators=SITES.astype(np.float32)), TypeError, r"generators must have the dtype of samples \(float64\), got float32"),
    (dict(samples=SAMPLES.tolist()), TypeError, "samples must be a numpy array, got list"),
    (dict(grad=np.zeros((9, 3))), ValueError, r"grad must have shape \(10, 3\) like generators, got \(9, 3\)"),
    (dict(grad=np.zeros((10, 3), np.float32)), TypeError, r"grad must have the dtype of generators \(float64\), got float32"),
    (dict(grad=np.broadcast_to(0.0, (10, 3))), ValueError, "grad must be writeable"),
    (dict(threads=0), ValueError, "threads must be >= 1, got 0"),
    (dict(sides=np.zeros(9, bool)), ValueError, r"sides must be an \(n,\) array of 0/1 labels, one per generator \(n = 10\)"),
])
def test_bad_input(kwargs, error, match):
    arguments = dict(samples=SAMPLES, generators=SITES, candidates=CANDIDATES, grad=None, threads=1) | kwargs
    with pytest.raises(error, match=match):
        _fitkernel.voroloss(**arguments)


def test_releases_the_gil(gil_free):
    import time

    # One call long enough (over 0.1 s on this machine, whatever its speed) that holding the GIL
    # would stop the spinning thread for most of it.
    n = 400_000
    while True:
        samples, generators = _band(n=n)
        candidates = knn_candidates(samples, generators, k=11)
        grad = np.zeros_like(generators)
        start = time.perf_counter()
        _fitkernel.voroloss(samples, generators, candidates, grad)
        if time.perf_counter() - start > 0.1 or n >= 6_400_000:
            break
        n *= 2
    elapsed, longest = gil_free(lambda: _fitkernel.voroloss(samples, generators, candidates, grad))
    assert longest < 0.5 * elapsed, (longest, elapsed)


@pytest.mark.parametrize("anchor", [None, -1.0, 0.37, -1e3])
@pytest.mark.parametrize("cell", [1e-4, 0.05, 0.3, 10.0])
def test_nearest_generators_are_the_exact_knn(cell, anchor):
    rng = np.random.default_rng(3)
    generators = rng.uniform(-1, 1, (500, 3))
    # Some samples outside the generators' box, where the grid's border cells are clamped.
    samples = rng.uniform(-1.5, 1.5, (4000, 3))
    found = _fitkernel.nearest_generators(samples, generators, 11, cell=cell, anchor=anchor, threads=2)
    _, expected = cKDTree(generators).query(samples, 11)
    assert found.dtype == np.int32 and found.shape == (4000, 11)
    np.testing.assert_array_equal(found, expected)


def test_nearest_generators_on_a_fitted_like_band_any_threads():
    samples, generators = _band(grid=24, n=20_000)
    samples, generators = samples.astype(np.float32), generators.astype(np.float32)
    one = _fitkernel.nearest_generators(samples, generators, 11, cell=2 / 23)
    np.testing.assert_array_equal(_fitkernel.nearest_generators(samples, generators, 11, cell=2 / 23, threads=3), one)
    squared = ((samples[:, None, :].astype(np.float64) - generators[one]) ** 2).sum(-1)
    _, expected = cKDTree(generators.astype(np.float64)).query(samples.astype(np.float64), 11)
    expected_squared = ((samples[:, None, :].astype(np.float64) - generators[expected]) ** 2).sum(-1)
    np.testing.assert_allclose(squared, expected_squared, rtol=1e-12, atol=0)


def test_nearest_generators_ties_go_to_the_lower_index():
    generators = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [5, 5, 5]])
    found = _fitkernel.nearest_generators(np.zeros((1, 3)), generators, 4, cell=0.5)
    assert found.tolist() == [[0, 1, 2, 3]]


@pytest.mark.parametrize("anchor", [None, -1.0])
@pytest.mark.parametrize("cell", [0.25, 0.04])
def test_nearest_generators_of_samples_sorted_by_cell_with_ties(cell, anchor):
    # Consecutive samples of one cell prune with the last sample's answer; on a lattice (exact ties
    # everywhere) and off it, that must not change a single index. With cells far smaller than the
    # lattice the k nearest lie beyond the shared box, and the rings go on from its answer.
    rng = np.random.default_rng(5)
    lattice = np.stack(np.meshgrid(*[np.arange(-4.0, 5.0)] * 3, indexing="ij"), -1).reshape(-1, 3) / 4
    generators = rng.permutation(np.vstack([lattice, rng.uniform(-1, 1, (200, 3))]))
    samples = np.vstack([rng.integers(-8, 9, (1500, 3)) / 8, rng.uniform(-1, 1, (1500, 3))])
    # Each sample twice in a row: the second's bound is exactly its k-th distance, ties included.
    samples = np.repeat(samples[np.lexsort(np.floor(samples / cell).T[::-1])], 2, axis=0)
    found = _fitkernel.nearest_generators(samples, generators, 9, cell=cell, anchor=anchor, threads=2)
    squared = ((samples[:, None, :] - generators[None]) ** 2).sum(-1)
    expected = np.array([np.lexsort((np.arange(len(generators)), row))[:9] for row in squared])
    np.testing.assert_array_equal(found, expected)


def test_nearest_generators_write_the_rows_asked_for():
    rng = np.random.default_rng(4)
    samples, generators = rng.uniform(-1, 1, (300, 3)), rng.uniform(-1, 1, (50, 3))
    rows = rng.permutation(400)[:300]
    out = np.full((400, 6), -1, np.int32)
    returned = _fitkernel.nearest_generators(samples, generators, 6, cell=0.2, threads=2, out=out, rows=rows)
    assert returned is out
    np.testing.assert_array_equal(out[rows], _fitkernel.nearest_generators(samples, generators, 6, cell=0.2))
    untouched = np.setdiff1d(np.arange(400), rows)
    assert (out[untouched] == -1).all()


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(out=np.zeros((20, 4), np.int32)), ValueError, "out and rows must be given together"),
    (dict(rows=np.arange(20)), ValueError, "out and rows must be given together"),
    (dict(out=np.zeros((20, 4), np.int64), rows=np.arange(20)), TypeError, "out must be int32, got dtype int64"),
    (dict(out=np.zeros((20, 3), np.int32), rows=np.arange(20)), ValueError, r"out must have shape \(rows, 4\), got \(20, 3\)"),
    (dict(out=np.zeros((20, 4), np.int32), rows=np.arange(19)), ValueError, r"rows must have shape \(20,\)"),
    (dict(out=np.zeros((20, 4), np.int32), rows=np.arange(1, 21)), ValueError, r"rows holds 20, outside \[0, 20\)"),
    (dict(out=np.zeros((20, 4), np.int32), rows=np.r_[np.arange(19), 3]), ValueError, "rows holds 3 twice"),
    (dict(out=np.zeros((20, 8), np.int32)[:, ::2], rows=np.arange(20)), ValueError, "out must be writeable and C-contiguous"),
])
def test_nearest_generators_bad_out(kwargs, error, match):
    arguments = dict(samples=SAMPLES, generators=SITES, k=4, cell=0.1, threads=1) | kwargs
    with pytest.raises(error, match=match):
        _fitkernel.nearest_generators(**arguments)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(k=0), ValueError, r"k must be in \[1, 10\] \(the number of generators\), got 0"),
    (dict(k=11), ValueError, r"k must be in \[1, 10\] \(the number of generators\), got 11"),
    (dict(cell=0.0), ValueError, "cell must be a finite number > 0"),
    (dict(anchor=float("nan")), ValueError, "anchor must be finite"),
    (dict(cell=np.nan), ValueError, "cell must be a finite number > 0"),
    (dict(threads=0), ValueError, "threads must be >= 1, got 0"),
    (dict(samples=SAMPLES[:, :2]), ValueError, r"samples must have shape \(m, 3\), got \(20, 2\)"),
    (dict(samples=np.where(np.arange(20)[:, None] == 5, np.nan, SAMPLES)), ValueError, "samples holds NaN or inf at row 5"),
    (dict(generators=np.where(np.arange(10)[:, None] == 2, np.inf, SITES)), ValueError, "generators holds NaN or inf at row 2"),
    (dict(generators=SITES.astype(np.float32)), TypeError, r"generators must have the dtype of samples \(float64\), got float32"),
    (dict(samples=SAMPLES.astype(int)), TypeError, "samples must be float32 or float64, got dtype int64"),
])
def test_nearest_generators_bad_input(kwargs, error, match):
    arguments = dict(samples=SAMPLES, generators=SITES, k=4, cell=0.1, threads=1) | kwargs
    with pytest.raises(error, match=match):
        _fitkernel.nearest_generators(**arguments)


def _sphere_samples(n):
    rng = np.random.default_rng(0)
    samples = rng.normal(size=(n, 3))
    return 0.9 * samples / np.linalg.norm(samples, axis=1, keepdims=True)


def _inside(points):
    return np.linalg.norm(points, axis=1) < 0.9


@pytest.mark.parametrize("boundary_steps", [0, 20])
def test_fit_through_the_kernel_matches_the_torch_path(monkeypatch, boundary_steps):
    samples = _sphere_samples(20_000)
    options = dict(steps=60, milestones=(30, 45), boundary_steps=boundary_steps, progress=False)
    kernel, kernel_info = fit_module.fit_samples(samples, _inside, 20, **options)
    monkeypatch.setattr(fit_module, "_CPU_KERNEL", False)
    reference, reference_info = fit_module.fit_samples(samples, _inside, 20, **options)
    assert kernel_info.final_loss == pytest.approx(reference_info.final_loss, rel=0.03)
    assert (kernel.occupancy == reference.occupancy).mean() > 0.99
    assert np.abs(kernel.generators - reference.generators).max() < 0.1 * 2 / 19
    for shape in (kernel, reference):
        assert check_watertight(extract_mesh(shape.generators, shape.occupancy), self_intersection=False).watertight


def test_boundary_steps_bring_the_labelled_faces_onto_the_samples():
    import open3d as o3d

    samples = _sphere_samples(20_000)
    results = []
    for boundary_steps in (0, 40):
        shape, _ = fit_module.fit_samples(samples, _inside, 16, steps=120, boundary_steps=boundary_steps)
        sided = _fitkernel.voroloss(samples, shape.generators, knn_candidates(samples, shape.generators, k=16),
                                    sides=shape.occupancy)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(shape.to_open3d(clean=False)))
        distance = scene.compute_distance(o3d.core.Tensor(samples.astype(np.float32))).numpy().mean()
        results.append((sided, distance))
    (sided_before, distance_before), (sided_after, distance_after) = results
    # The loss of the faces between inside and outside cells is what those steps lower; the mesh is those faces.
    assert sided_after < 0.98 * sided_before, results
    assert distance_after < 0.995 * distance_before, results


def test_fit_is_the_same_for_a_seed_whatever_the_threads():
    samples = _sphere_samples(5000)
    options = dict(steps=30, milestones=(20,), progress=False)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        first, _ = fit_module.fit_samples(samples, _inside, 12, **options)
        torch.set_num_threads(3)
        again, _ = fit_module.fit_samples(samples, _inside, 12, **options)
    finally:
        torch.set_num_threads(threads)
    np.testing.assert_array_equal(again.generators, first.generators)
    np.testing.assert_array_equal(again.occupancy, first.occupancy)


def test_cpu_fit_imports_no_torch():
    script = ("import sys, numpy as np\n"
              "from voro3d.fitting import fit_samples\n"
              "rng = np.random.default_rng(0)\n"
              "x = rng.normal(size=(3000, 3)); x = 0.9 * x / np.linalg.norm(x, axis=1, keepdims=True)\n"
              "shape, info = fit_samples(x, lambda p: np.linalg.norm(p, axis=1) < 0.9, 8, steps=5)\n"
              "print(shape.occupancy.any(), 'torch' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["True", "False"]


def test_numpy_adam_matches_torch_optim():
    start = np.random.default_rng(0).normal(size=(50, 3))
    ours, theirs = start.copy(), torch.tensor(start, requires_grad=True)
    adam = Adam(ours)  # on a numpy array, as the CPU kernel's loop steps it
    reference = torch.optim.Adam([theirs], lr=0.01, foreach=False)
    schedule = torch.optim.lr_scheduler.MultiStepLR(reference, milestones=[3, 6], gamma=0.5)
    for step in range(10):
        adam.step(2 * ours + step, 0.01 * 0.5 ** sum(step >= m for m in (3, 6)))
        theirs.grad = None
        (theirs.square().sum() + theirs.sum() * step).backward()
        reference.step()
        schedule.step()
    np.testing.assert_allclose(ours, theirs.detach().numpy(), rtol=1e-12, atol=1e-14)


def test_cpu_threads_follow_torch_then_the_environment(monkeypatch):
    assert _cpufit.cpu_threads() == torch.get_num_threads()
    monkeypatch.delitem(sys.modules, "torch")
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert _cpufit.cpu_threads() == 3
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert _cpufit.cpu_threads() >= 1
