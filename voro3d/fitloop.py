"""The fit loop's skeleton, one for both backends: batches, learning-rate schedule, Adam, candidate refresh.

A backend (:class:`voro3d._cpufit.KernelLoop`, the compiled CPU kernel; :class:`voro3d._torchfit.TorchLoop`,
torch on CPU or CUDA) holds the samples, the generators and their kNN candidates, and gives one
batch's loss and gradient, the Adam step and clamp, and the kNN search; :meth:`FitLoop.run` is the
rest. Batches are windows of consecutive samples at a random offset: the samples are i.i.d. on the
surface, so a window is a random batch, and a slice instead of a gather (which cost more than the
loss itself). The first window's worth of samples is repeated at the end so that every offset gives
a full window and every sample is equally likely to be used. A seed gives the same batches on
every backend.
"""
from __future__ import annotations

import bisect
from abc import ABC, abstractmethod

import numpy as np

__all__ = ["Adam", "FitLoop", "spatial_order"]


def spatial_order(samples: np.ndarray, cell: float) -> np.ndarray:
    """Sample indices sorted by cubic cells of side ``cell`` with corners at ``-1 + j * cell`` (fit
    frame): kNN queries in this order find their data in cache (1.5 times faster than the samples'
    random order with a KD-tree)."""
    voxel = np.maximum(np.floor((samples + 1.0) / cell), 0).astype(np.int64)
    size = int(voxel.max(initial=0)) + 1
    return np.argsort((voxel[:, 0] * size + voxel[:, 1]) * size + voxel[:, 2], kind="stable")


class Adam:
    """``torch.optim.Adam``'s update with its defaults (betas 0.9 and 0.999, eps 1e-8), in place.

    Written with operators that numpy arrays and torch tensors share, so that one update serves both
    backends (a torch tensor is stepped under ``torch.no_grad()``). Creating a ``torch.optim``
    optimiser imports ``torch._dynamo``, which took 3 to 10 seconds on first use here: longer than a
    whole fit at grid 32.
    """

    BETA1, BETA2, EPS = 0.9, 0.999, 1e-8

    def __init__(self, parameter):
        self.parameter = parameter
        self.mean = parameter - parameter  # zeros of the parameter's kind (array or tensor), +0 everywhere
        self.square = parameter - parameter
        self.steps = 0

    def step(self, grad, lr: float) -> None:
        self.steps += 1
        self.mean += (1 - self.BETA1) * (grad - self.mean)
        self.square *= self.BETA2
        self.square += (1 - self.BETA2) * grad * grad
        correction1 = 1 - self.BETA1**self.steps
        correction2 = 1 - self.BETA2**self.steps
        denominator = self.square**0.5 / correction2**0.5 + self.EPS
        self.parameter -= (lr / correction1) * self.mean / denominator


class FitLoop(ABC):
    """Adam on VoroLoss over windows of the samples; the backend supplies the operations below.

    Attributes a backend sets: ``n_samples`` (samples, without the repeated window), ``batch``
    (window length) and ``searches`` (kNN searches so far, the first included). ``fixed``, None or
    an (n,) bool mask (numpy, or a tensor on the loop's device): generators whose gradient is
    zeroed, so that Adam never moves them (a tile's frozen neighbours). ``sides``, None or an (n,) bool
    array (numpy, or a tensor on the loop's device): each generator's label, where the loss is that of
    the faces between differently labelled cells only (the kernel's ``sides``).
    """

    fixed = None
    sides = None

    def run(self, steps: int, *, lr: float, milestones, gamma: float, seed: int, refresh_distance: float,
            progress: bool = False) -> np.ndarray:
        """``steps`` Adam steps; the learning rate times ``gamma`` at each milestone; the candidates searched
        again once a generator has moved ``refresh_distance`` since the last search. Returns each batch's loss."""
        from tqdm.auto import tqdm

        adam = self._optimizer()
        offsets = np.random.default_rng(seed).integers(self.n_samples, size=steps).tolist()
        losses = np.empty(steps)
        # disable=None: a bar on a terminal only; a log would get a line per update.
        for step in tqdm(range(steps), desc="VoroMesh fit", disable=None if progress else True, leave=False):
            losses[step] = self._gradient(offsets[step])
            self._descend(adam, lr * gamma ** bisect.bisect_right(milestones, step))
            if self._moved() > refresh_distance**2 and step + 1 < steps:
                self._search()
        return losses

    def search(self) -> None:
        """The kNN candidates searched again, at the generators as they are."""
        self._search()

    @abstractmethod
    def _optimizer(self) -> Adam:
        """An :class:`Adam` over the generators."""

    @abstractmethod
    def _gradient(self, offset: int) -> float:
        """The loss of the window starting at ``offset``, its gradient left where :meth:`_descend` takes it."""

    @abstractmethod
    def _descend(self, adam: Adam, lr: float) -> None:
        """One Adam step at ``lr``, then the generators clamped to ``[-1, 1]^3``."""

    @abstractmethod
    def _moved(self):
        """The largest squared distance a generator has moved since the last search, in the backend's own
        precision (a float32 scalar or tensor: the refresh compares it there)."""

    @abstractmethod
    def _search(self) -> None:
        """The kNN candidates of every sample at the current generators."""
