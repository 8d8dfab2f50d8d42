"""The fit loop's CPU backend, without torch: each step's VoroLoss and gradient and the kNN searches
come from the compiled kernel ``voro3d._fitkernel``, Adam is a few numpy operations.

:class:`voro3d._torchfit.TorchLoop` is the same loop in torch (the reference, and the CUDA path); this
one spares a CPU fit the 2-6 s of importing torch and its per-operation overhead.

Threads, determinism, the reference
-----------------------------------
The extension ``voro3d._fitkernel`` (``src/voro3d_fitkernel.cpp``) computes each step's loss and
gradient in one pass over the candidates and runs the kNN searches (an exact grid search), on
``fit(threads=)`` threads, by default ``torch.get_num_threads()`` when torch is loaded, else
``OMP_NUM_THREADS``, else every CPU the process may use (:func:`cpu_threads`). Its gradient is
summed in fixed point, so a seed gives the same output on any thread count. The torch loop is the reference (the tests check the kernel's loss and gradient against
it in float64, and a fit through each) and the ``device="cuda"`` path, which is still untested on a
GPU. Speed: ``benchmarks/README.md`` (``fit_speed``, ``profile_fit_kernel``).

The search's bucket cells are anchored at the frame's corner and the samples are searched in the
order of those same cells. Anchored at the generators' lowest corner (as before 2026-12-04), the
cells slid off the samples' order once the generators had moved, and every search after the first
took about twice as long: at 10^5 true-normal points (836k samples, 26.7k generators, 6 searches)
the armadillo's searches took 2.16-2.37 s against 1.39-1.44 s anchored, fandisk's 0.87-0.93 against
0.70-0.75 and abc_00000005's 0.77-0.78 against 0.69-0.71, with the same candidates and so the same
mesh, bit for bit.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from . import _fitkernel
from ._system import available_cpus
from .fitloop import Adam, FitLoop, spatial_order
from .geometry import grid_voxel

__all__ = ["KernelLoop", "cpu_threads"]


def cpu_threads() -> int:
    """Threads for the kernel: torch's setting when torch is loaded (a caller, such as a batch
    worker, may have set it), else ``OMP_NUM_THREADS``, else the CPUs this process may run on."""
    torch = sys.modules.get("torch")  # None where torch is blocked (sys.modules["torch"] = None)
    if torch is not None:
        return torch.get_num_threads()
    setting = os.environ.get("OMP_NUM_THREADS", "")
    if setting.isdigit() and int(setting) > 0:
        return int(setting)
    return available_cpus()


class KernelLoop(FitLoop):
    """Samples, generators and their kNN candidates, point-major, for :func:`voro3d.fitting.fit_samples`;
    batches as in :mod:`voro3d.fitloop`."""

    def __init__(self, samples: np.ndarray, generators: np.ndarray, *, grid: int, k: int, batch_fraction: float,
                 threads: int, reach: np.ndarray | None = None):
        self.n_samples = samples.shape[0]
        self.batch = max(1, int(round(batch_fraction * self.n_samples)))
        self.samples = np.concatenate([samples, samples[: self.batch]]).astype(np.float32)
        self.positions = generators.astype(np.float32)
        self.grad = np.zeros_like(self.positions)
        self.k = min(k, generators.shape[0])
        self.threads = threads
        # Bucket cells about one generator wide (the search's speed depends on it, not its answers).
        self.cell = grid_voxel(grid) * (1.0 if reach is None else float(np.median(reach)))
        self.reach_squared = None if reach is None else np.square(reach)
        # The search runs in the order of its own cells (anchored at the frame's corner, however the
        # generators have moved) and writes each answer to its sample's row.
        self.search_rows = spatial_order(samples, self.cell)
        self.search_samples = np.ascontiguousarray(samples[self.search_rows], dtype=np.float32)
        self.candidates = np.empty((self.samples.shape[0], self.k), np.int32)
        self.searches = 0
        self._search()

    def _search(self):
        _fitkernel.nearest_generators(self.search_samples, self.positions, self.k, cell=self.cell, anchor=-1.0,
                                      threads=self.threads, out=self.candidates, rows=self.search_rows)
        self.candidates[self.n_samples:] = self.candidates[: self.batch]  # the first window, repeated
        self.searched_at = self.positions.copy()
        self.searches += 1

    def _optimizer(self) -> Adam:
        return Adam(self.positions)

    def _gradient(self, offset: int) -> float:
        window = slice(offset, offset + self.batch)
        return _fitkernel.voroloss(self.samples[window], self.positions, self.candidates[window], self.grad,
                                   threads=self.threads, sides=self.sides)

    def _descend(self, adam: Adam, lr: float) -> None:
        if self.fixed is not None:
            self.grad[self.fixed] = 0.0
        adam.step(self.grad, lr)
        np.clip(self.positions, -1.0, 1.0, out=self.positions)

    def _moved(self):
        moved = np.square(self.positions - self.searched_at).sum(axis=1)
        return (moved if self.reach_squared is None else moved / self.reach_squared).max()

    def loss(self) -> float:
        """VoroLoss over all samples with the current candidates."""
        return _fitkernel.voroloss(self.samples[: self.n_samples], self.positions, self.candidates[: self.n_samples],
                                   threads=self.threads, sides=self.sides)

    def generators(self) -> np.ndarray:
        return self.positions.astype(np.float64)

