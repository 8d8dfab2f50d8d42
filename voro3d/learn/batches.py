"""Stage-1 batches: augmented shapes, their band inputs joined into one graph, and the batch loss.

:class:`Stage1Batches` makes the batches of an epoch (numpy only, so DataLoader workers can build
them beside the training loop); :func:`join_inputs` turns a batch's band inputs into one graph,
so the network runs once per step; :func:`batch_loss` is the paper's stage-1 loss of a batch.
"""
from __future__ import annotations

import numpy as np
import torch

from ..infer import NetworkInput
from ..loss import voroloss

__all__ = ["Stage1Batches", "as_batch", "as_torch", "augment", "batch_loss", "generators_of", "join_inputs"]


def augment(sdf: np.ndarray, points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random axis permutation and flips, applied alike to a ``(g, g, g)`` grid and ``(m, 3)`` points.

    The grid is symmetric about 0 (node ``i`` of ``g`` mirrors node ``g - 1 - i``), so flipping an
    axis of the array negates that coordinate exactly.
    """
    perm = rng.permutation(3)
    flips = rng.random(3) < 0.5
    sdf = np.transpose(sdf, perm)
    sdf = np.ascontiguousarray(np.flip(sdf, axis=tuple(np.flatnonzero(flips))))
    points = points[:, perm] * np.where(flips, -1.0, 1.0).astype(points.dtype)
    return sdf, points


def as_torch(arrays: dict, device="cpu") -> dict:
    """Numpy arrays by name as torch tensors on ``device``."""
    return {name: torch.from_numpy(array).to(device) for name, array in arrays.items()}


def generators_of(net_input: NetworkInput, offsets: torch.Tensor) -> torch.Tensor:
    """``(n, 3)`` float32 generators in ``[-1, 1]^3``: node positions plus offsets times the voxel size."""
    positions = torch.from_numpy(net_input.positions.astype(np.float32)).to(offsets.device)
    return positions + net_input.step * offsets


def join_inputs(inputs: list[NetworkInput]) -> tuple[dict, np.ndarray]:
    """Band inputs of several shapes as one graph, for one network call.

    Each level's rows are stacked and every index shifted by the rows of the shapes before it;
    indices of absent nodes (a shape's row count) become the joined graph's absent row. The
    network's outputs for the joined graph are those of the shapes, in order (its layers are
    all per node or per neighbourhood).

    Parameters
    ----------
    inputs : list of NetworkInput
        From :func:`voro3d.infer.band_input` (three levels).

    Returns
    -------
    arrays : dict of str to numpy.ndarray
        The joined :data:`voro3d.infer.BAND_INPUTS`.
    bounds : (len(inputs) + 1,) int64
        Shape ``s`` owns output rows ``bounds[s]:bounds[s + 1]``.
    """
    counts = {level: np.array([x.arrays[f"neighbours{level}"].shape[0] for x in inputs]) for level in range(3)}
    starts = {level: np.concatenate([[0], np.cumsum(c)]) for level, c in counts.items()}

    def shifted(name, s, level):
        # Rows of `level`: the absent index (that shape's count) maps to the joined absent row.
        index = inputs[s].arrays[name]
        return np.where(index == counts[level][s], starts[level][-1], index + starts[level][s])

    arrays = {"band_sdf": np.concatenate([x.arrays["band_sdf"] for x in inputs])}
    for level in range(3):
        arrays[f"neighbours{level}"] = np.concatenate([shifted(f"neighbours{level}", s, level)
                                                       for s in range(len(inputs))])
    for level in (1, 2):
        arrays[f"children{level}"] = np.concatenate([shifted(f"children{level}", s, level - 1)
                                                     for s in range(len(inputs))])
        arrays[f"up{level}"] = np.concatenate([x.arrays[f"up{level}"] + 8 * starts[level][s]
                                               for s, x in enumerate(inputs)])
    arrays["targets"] = np.concatenate([x.arrays["targets"] + starts[0][s] for s, x in enumerate(inputs)])
    bounds = np.concatenate([[0], np.cumsum([x.arrays["targets"].shape[0] for x in inputs])])
    return arrays, bounds


def batch_loss(model: torch.nn.Module, shapes: list[tuple[NetworkInput, np.ndarray]], *,
               reg_weight: float) -> tuple[torch.Tensor, dict]:
    """Stage-1 loss of a batch: the mean over shapes of VoroLoss in voxel units plus ``reg_weight`` times the largest offset.

    Parameters
    ----------
    model : BandNet
        On the device the loss is computed on.
    shapes : list of (NetworkInput, (m, 3) float32)
        Each shape's band input (``model.network_input``) and surface samples in the grid's
        ``[-1, 1]^3`` frame.
    reg_weight : float
        The paper's lambda, per voxel of offset.

    Returns
    -------
    loss : torch.Tensor
        0-dim, differentiable in the model's CNN and MLP1 parameters.
    parts : dict
        Means over the shapes of ``voroloss`` (voxel^2) and ``max_offset`` (voxels), as floats.
    """
    device = next(model.parameters()).device
    arrays, bounds = join_inputs([net_input for net_input, _ in shapes])
    offsets = model.offset_head(model.node_features(**as_torch(arrays, device)))
    losses, distances, largest = [], [], []
    for s, (net_input, samples) in enumerate(shapes):
        own = offsets[bounds[s]:bounds[s + 1]]
        samples_t = torch.from_numpy(samples).to(device)
        distances.append(voroloss(samples_t, generators_of(net_input, own)) / net_input.step**2)
        largest.append(own.norm(dim=1).max())
        losses.append(distances[-1] + reg_weight * largest[-1])
    return torch.stack(losses).mean(), {"voroloss": torch.stack(distances).mean().item(),
                                        "max_offset": torch.stack(largest).mean().item()}


class Stage1Batches(torch.utils.data.Dataset):
    """The batches of one stage-1 epoch of ``shapes`` (a :class:`~voro3d.learn.data.ShapeSet`), each a list of
    ``(NetworkInput, samples)``.

    Batch ``b`` draws its grid sizes, samples and augmentations from a generator seeded by
    ``(seed, 1, epoch, b)``, so the batches do not depend on which worker makes them or when.
    ``context`` is the network's band half-width (its ``network_input``), in voxels.
    """

    def __init__(self, shapes, config: dict, epoch: int, context: float):
        self.shapes, self.config, self.epoch, self.context = shapes, config, epoch, context
        stage = config["stage1"]
        order = np.random.default_rng([config["seed"], 1, epoch]).permutation(len(shapes))
        self.batches = [order[start:start + stage["batch_size"]] for start in range(0, len(order), stage["batch_size"])]

    def __len__(self) -> int:
        return len(self.batches)

    def __getitem__(self, b: int) -> list:
        from ..infer import band_input

        config, stage = self.config, self.config["stage1"]
        rng = np.random.default_rng([config["seed"], 1, self.epoch, b])
        weights = np.asarray(stage["grid_weights"], float)
        batch = []
        for i in self.batches[b]:
            shape = self.shapes[int(i)]
            grid = int(rng.choice(config["data"]["grids"], p=weights / weights.sum()))
            count = min(stage["samples_per_shape"], shape["samples"].shape[0])
            sdf, samples = shape[f"sdf_{grid}"], shape["samples"][rng.choice(shape["samples"].shape[0], count,
                                                                            replace=False)]
            if stage["augment"]:
                sdf, samples = augment(sdf, samples, rng)
            batch.append((band_input(sdf, near=config["near"], context=self.context), samples))
        return batch


def as_batch(batch):
    """The DataLoader's collate step: a batch is already one item of :class:`Stage1Batches`."""
    return batch
