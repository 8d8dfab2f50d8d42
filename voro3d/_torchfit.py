"""The torch backend of :mod:`voro3d.fitloop`: the reference loop, and the CUDA path.

:func:`voro3d.fitting.optimise_generators` takes it for ``device="cuda"`` (and for the CPU when the
compiled kernel of :mod:`voro3d._cpufit` is switched off); torch is imported only when it is built.
"""
from __future__ import annotations

import numpy as np

from .fitloop import Adam, FitLoop, spatial_order
from .geometry import grid_voxel

__all__ = ["TorchLoop"]


class TorchLoop(FitLoop):
    """The torch backend of :mod:`voro3d.fitloop` (the reference, and the CUDA path): samples,
    generators and their kNN candidates, coordinate-major."""

    def __init__(self, samples: np.ndarray, generators: np.ndarray, *, grid: int, k: int,
                 batch_fraction: float, device: torch.device, reach: np.ndarray | None = None):
        import torch

        self.n_samples = samples.shape[0]
        self.batch = max(1, int(round(batch_fraction * self.n_samples)))
        wrapped = np.concatenate([samples, samples[: self.batch]])
        self.samples_t = torch.tensor(wrapped.T, dtype=torch.float32, device=device).contiguous()
        self.generators_t = torch.nn.Parameter(
            torch.tensor(generators.T, dtype=torch.float32, device=device).contiguous())
        self.k = min(k, generators.shape[0])
        self.reach = None if reach is None else torch.tensor(reach, device=device)
        # The samples never move, so they are sorted for the KD-tree once.
        order = spatial_order(samples, grid_voxel(grid))
        self.search_samples = np.ascontiguousarray(samples[order], dtype=np.float32)
        self.search_rank = torch.empty(order.size, dtype=torch.int64)
        self.search_rank[torch.from_numpy(order)] = torch.arange(order.size)
        self.searches = 0
        self._search()

    def _search(self):
        import torch

        from .loss import nearest_indices

        sites = self.generators_t.detach()
        positions = np.ascontiguousarray(sites.t().cpu().numpy())
        found = torch.from_numpy(nearest_indices(self.search_samples, positions, self.k))
        # Back to the samples' order, coordinate-major, with the first window repeated at the end.
        found = found.index_select(0, self.search_rank).t()
        self.candidates_t = torch.cat([found, found[:, : self.batch]], dim=1).to(sites.device)
        self.searched_at = sites.clone()
        self.searches += 1

    def _optimizer(self) -> Adam:
        import torch

        with torch.no_grad():
            return Adam(self.generators_t)

    def _gradient(self, offset: int) -> float:
        import torch

        from .loss import PAIR_BLOCK, bisector_distance, bisector_pairs

        generators_t = self.generators_t
        generators_t.grad = None
        loss = torch.zeros((), device=generators_t.device)
        # The batch's loss is a sum over samples, so blocks of it can be backpropagated one at a time:
        # their temporaries then stay in cache instead of being allocated afresh.
        for start in range(0, self.batch, PAIR_BLOCK):
            window = slice(offset + start, offset + min(start + PAIR_BLOCK, self.batch))
            samples_t = self.samples_t[:, window].contiguous()
            nearest, other = bisector_pairs(samples_t, generators_t.detach(), self.candidates_t[:, window],
                                            sides_t=self.sides)
            block_loss = bisector_distance(samples_t, generators_t, nearest, other).square().sum() / self.batch
            block_loss.backward()
            loss += block_loss.detach()
        return float(loss)

    def _descend(self, adam: Adam, lr: float) -> None:
        import torch

        with torch.no_grad():
            if self.fixed is not None:
                self.generators_t.grad[:, self.fixed] = 0.0  # coordinate-major
            adam.step(self.generators_t.grad, lr)
            self.generators_t.clamp_(-1.0, 1.0)

    def _moved(self):
        import torch

        with torch.no_grad():
            moved = (self.generators_t - self.searched_at).square_().sum(0)
            return (moved if self.reach is None else moved / self.reach.square()).amax()

    def loss(self) -> float:
        """VoroLoss over all samples with the current candidates."""
        import torch

        from .loss import bisector_distance, bisector_pairs

        with torch.no_grad():
            samples_t = self.samples_t[:, : self.n_samples]
            sites = self.generators_t.detach()
            nearest, other = bisector_pairs(samples_t, sites, self.candidates_t[:, : self.n_samples],
                                            sides_t=self.sides)
            return float(bisector_distance(samples_t, sites, nearest, other).square().mean())

    def generators(self) -> np.ndarray:
        return self.generators_t.detach().t().cpu().numpy().astype(np.float64)
