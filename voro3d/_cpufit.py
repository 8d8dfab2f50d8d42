"""The fit loop on CPU, without torch: each step's VoroLoss and gradient and the kNN searches come
from the compiled kernel ``voro3d._fitkernel``, Adam is a few numpy operations.

:class:`voro3d.fitting._FitLoop` is the same loop in torch (the reference, and the CUDA path); this
one spares a CPU fit the 2-6 s of importing torch and its per-operation overhead.

Threads, determinism, the reference
-----------------------------------
The extension ``voro3d._fitkernel`` (``src/voro3d_fitkernel.cpp``) computes each step's loss and
gradient in one pass over the candidates and runs the kNN searches (an exact grid search), on
``torch.get_num_threads()`` threads when torch is loaded, else ``OMP_NUM_THREADS``, else every CPU
the process may use. Its gradient is summed in fixed point, so a seed gives the same output on any
thread count. The torch loop is the reference (the tests check the kernel's loss and gradient against
it in float64, and a fit through each) and the ``device="cuda"`` path, which is still untested on a
GPU. Speed: ``benchmarks/README.md`` (``fit_speed``, ``profile_fit_kernel``).
"""
from __future__ import annotations

import bisect
import os
import sys

import numpy as np

from . import _fitkernel

__all__ = ["KernelLoop", "NumpyAdam", "cpu_threads", "spatial_order"]


def cpu_threads() -> int:
    """Threads for the kernel: torch's setting when torch is loaded (a caller, such as a batch
    worker, may have set it), else ``OMP_NUM_THREADS``, else the CPUs this process may run on."""
    torch = sys.modules.get("torch")  # None where torch is blocked (sys.modules["torch"] = None)
    if torch is not None:
        return torch.get_num_threads()
    setting = os.environ.get("OMP_NUM_THREADS", "")
    if setting.isdigit() and int(setting) > 0:
        return int(setting)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def spatial_order(samples: np.ndarray, grid: int) -> np.ndarray:
    """Sample indices sorted by grid voxel: kNN queries in this order find their data in cache
    (1.5 times faster than the samples' random order with a KD-tree)."""
    voxel = np.floor((samples + 1.0) * (grid - 1) / 2.0).astype(np.int64)
    return np.argsort((voxel[:, 0] * grid + voxel[:, 1]) * grid + voxel[:, 2], kind="stable")


class KernelLoop:
    """Samples, generators and their kNN candidates, point-major, for :func:`voro3d.fitting.fit_samples`.

    Batches are windows of consecutive samples at a random offset, with the first window's worth
    of samples repeated at the end, as in :class:`voro3d.fitting._FitLoop`.
    """

    def __init__(self, samples: np.ndarray, generators: np.ndarray, *, grid: int, k: int, batch_fraction: float,
                 threads: int):
        self.n_samples = samples.shape[0]
        self.batch = max(1, int(round(batch_fraction * self.n_samples)))
        self.samples = np.concatenate([samples, samples[: self.batch]]).astype(np.float32)
        self.positions = generators.astype(np.float32)
        self.grad = np.zeros_like(self.positions)
        self.k = min(k, generators.shape[0])
        self.threads = threads
        self.voxel = 2.0 / (grid - 1)
        # The search runs in spatial order and writes each answer to its sample's row.
        self.search_rows = spatial_order(samples, grid)
        self.search_samples = np.ascontiguousarray(samples[self.search_rows], dtype=np.float32)
        self.candidates = np.empty((self.samples.shape[0], self.k), np.int32)
        self.searches = 0
        self._search()

    def _search(self):
        _fitkernel.nearest_generators(self.search_samples, self.positions, self.k, cell=self.voxel,
                                      threads=self.threads, out=self.candidates, rows=self.search_rows)
        self.candidates[self.n_samples:] = self.candidates[: self.batch]  # the first window, repeated
        self.searched_at = self.positions.copy()
        self.searches += 1

    def run(self, steps, *, lr, milestones, gamma, seed, refresh_distance, progress) -> np.ndarray:
        from tqdm.auto import tqdm

        optimizer = NumpyAdam(self.positions)
        offsets = np.random.default_rng(seed).integers(self.n_samples, size=steps)
        losses = np.empty(steps)
        # disable=None: a bar on a terminal only; a log would get a line per update.
        for step in tqdm(range(steps), desc="VoroMesh fit", disable=None if progress else True, leave=False):
            window = slice(offsets[step], offsets[step] + self.batch)
            losses[step] = _fitkernel.voroloss(self.samples[window], self.positions, self.candidates[window],
                                               self.grad, threads=self.threads)
            optimizer.step(self.grad, lr * gamma ** bisect.bisect_right(milestones, step))
            np.clip(self.positions, -1.0, 1.0, out=self.positions)
            moved = np.square(self.positions - self.searched_at).sum(axis=1).max()
            if moved > refresh_distance**2 and step + 1 < steps:
                self._search()
        return losses

    def loss(self) -> float:
        """VoroLoss over all samples with the current candidates."""
        return _fitkernel.voroloss(self.samples[: self.n_samples], self.positions, self.candidates[: self.n_samples],
                                   threads=self.threads)

    def generators(self) -> np.ndarray:
        return self.positions.astype(np.float64)


class NumpyAdam:
    """``torch.optim.Adam``'s update with its defaults (betas 0.9 and 0.999, eps 1e-8), in place on
    a float32 array, in the order of :class:`voro3d.fitting._Adam`."""

    BETA1, BETA2, EPS = 0.9, 0.999, 1e-8

    def __init__(self, parameter: np.ndarray):
        self.parameter = parameter
        self.mean = np.zeros_like(parameter)
        self.square = np.zeros_like(parameter)
        self.steps = 0

    def step(self, grad: np.ndarray, lr: float) -> None:
        self.steps += 1
        self.mean += (1 - self.BETA1) * (grad - self.mean)
        self.square *= self.BETA2
        self.square += (1 - self.BETA2) * grad * grad
        correction1 = 1 - self.BETA1**self.steps
        correction2 = 1 - self.BETA2**self.steps
        denominator = np.sqrt(self.square) / correction2**0.5 + self.EPS
        self.parameter -= (lr / correction1) * self.mean / denominator
