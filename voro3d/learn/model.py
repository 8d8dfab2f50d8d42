"""The VoroMesh network: a 3D CNN on the SDF grid, two per-node MLP heads.

Layout (``w = width``, ``c = coarse_width``)::

    x = clamp(sdf / voxel, ±truncation) / truncation                   (1, 1, d, h, w), dense
    coarse path:  conv3 1→w ─ conv2/2 w→c ─ res(c) ─ res(c)            dense, half resolution
                  read at each node's coarse cell, then the 2x2x2 stride-2 transposed
                  convolution evaluated at that node only (one c→w map per parity)  → (n, w)
    fine path:    the 5^3 patch of x around each node ─ MLP 125→2w→2w               → (n, 2w)
    heads:        features (3w) ─ MLP1 → offset (3, voxel units)
                  [features, offset] (3w + 3) ─ MLP2 → occupancy logit

A node's features depend on the SDF within 10 nodes (receptive field 21^3; the paper's is about
19^3): a full-resolution 3^3 convolution, a stride-2 one, then four 3^3 at half resolution, each
reaching two nodes further. Only the first two layers and the half-resolution ones are dense;
full-resolution detail comes from the nodes' own patches, so a 64^3 grid costs about 0.1 s on
one CPU core. There is no normalisation layer, so a node's features depend only on the SDF within
its receptive field and cropping the grid (:func:`voro3d.infer.network_input`) changes nothing.
Offsets are unbounded (no tanh); training penalises their maximum norm instead, as the paper does.
"""
from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

__all__ = ["VoroNet", "load_checkpoint", "save_checkpoint"]

# Slope of the leaky ReLUs (the official code's).
SLOPE = 0.01


def _mlp(n_in: int, width: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, width), nn.LeakyReLU(SLOPE), nn.Linear(width, width), nn.LeakyReLU(SLOPE),
                         nn.Linear(width, n_out))


class _Residual(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.branch = nn.Sequential(nn.Conv3d(channels, channels, 3, padding=1), nn.LeakyReLU(SLOPE),
                                    nn.Conv3d(channels, channels, 3, padding=1))
        with torch.no_grad():
            self.branch[-1].weight.mul_(0.1)  # start close to the identity

    def forward(self, x):
        return nn.functional.leaky_relu(x + self.branch(x), SLOPE)


def _cube(radius: int) -> torch.Tensor:
    """``((2 radius + 1)^3, 3)`` int64 offsets of a cube of nodes, in C order (a convolution's tap order)."""
    span = torch.arange(-radius, radius + 1)
    return torch.stack(torch.meshgrid(span, span, span, indexing="ij"), dim=-1).view(-1, 3)


# Offsets of a node's 5^3 patch.
_PATCH = _cube(2)


def _flat_index(ijk: torch.Tensor, shape) -> torch.Tensor:
    """C-order flat index of ``(n, 3)`` integer coordinates in a grid of ``shape`` (traced sizes)."""
    return (ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2]


class VoroNet(nn.Module):
    """SDF grid + node coordinates -> per-node generator offsets and occupancy logits.

    Parameters
    ----------
    width : int
        Channels of the full-resolution convolution and of the coarse node features; the fine
        node features have ``2 * width``.
    coarse_width : int
        Channels at half resolution.
    head_width : int
        Hidden width of both MLPs.
    truncation : float
        The SDF input is clamped to ``±truncation`` voxels: far values carry no local detail.

    Notes
    -----
    The input is the SDF divided by the voxel size, so one network serves every grid size.
    Grid dimensions must be even (the network halves the resolution once).
    """

    receptive_radius = 10

    def __init__(self, *, width: int = 16, coarse_width: int = 32, head_width: int = 64, truncation: float = 3.0):
        super().__init__()
        self.config = {"width": width, "coarse_width": coarse_width, "head_width": head_width,
                       "truncation": truncation}
        self.width = width
        self.truncation = float(truncation)
        self.stem = nn.Conv3d(1, width, 3, padding=1)
        self.down = nn.Conv3d(width, coarse_width, 2, stride=2)
        self.coarse = nn.Sequential(_Residual(coarse_width), _Residual(coarse_width))
        # The 2x2x2 stride-2 transposed convolution, one c -> w block per child parity.
        self.up = nn.Linear(coarse_width, 8 * width)
        self.patch = nn.Sequential(nn.Linear(_PATCH.shape[0], 2 * width), nn.LeakyReLU(SLOPE),
                                   nn.Linear(2 * width, 2 * width), nn.LeakyReLU(SLOPE))
        self.offset_head = _mlp(3 * width, head_width, 3)
        self.occupancy_head = _mlp(3 * width + 3, head_width, 1)
        with torch.no_grad():
            # Start every generator at its node (the official code's small final weights).
            self.offset_head[-1].weight.normal_(std=0.01)
            self.offset_head[-1].bias.zero_()

    def node_features(self, sdf_voxels: torch.Tensor, nodes: torch.Tensor) -> torch.Tensor:
        """``(n, 3 * width)`` features of ``(n, 3)`` int64 nodes of a ``(1, 1, d, h, w)`` SDF in voxel units."""
        x = sdf_voxels.clamp(-self.truncation, self.truncation) / self.truncation
        shape = sdf_voxels.shape[2:]

        coarse = self.coarse(nn.functional.leaky_relu(
            self.down(nn.functional.leaky_relu(self.stem(x), SLOPE)), SLOPE))
        # Rows of the (cells, c) table gather fast; the table is small at half resolution.
        table = coarse.flatten(2)[0].t()
        cell = table.index_select(0, _flat_index(nodes // 2, coarse.shape[2:]))
        parity = ((nodes[:, 0] % 2) * 4 + (nodes[:, 1] % 2) * 2 + nodes[:, 2] % 2)
        children = self.up(cell).view(-1, 8, self.width)
        up = children.gather(1, parity.view(-1, 1, 1).expand(-1, 1, self.width))[:, 0]

        padded = nn.functional.pad(x, (2,) * 6).flatten()
        padded_shape = [n + 4 for n in shape]
        patches = padded[_flat_index(nodes + 2, padded_shape)[:, None] + _flat_index(_PATCH, padded_shape)[None, :]]
        fine = self.patch(patches)
        return torch.cat([fine, nn.functional.leaky_relu(up, SLOPE)], dim=1)

    def occupancy(self, node_features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """``(n,)`` occupancy logits (positive inside) from ``(n, 3w)`` features and ``(n, 3)`` offsets."""
        return self.occupancy_head(torch.cat([node_features, offsets], dim=1))[:, 0]

    def forward(self, sdf_voxels: torch.Tensor, nodes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Offsets and logits of the generator nodes.

        Parameters
        ----------
        sdf_voxels : (1, 1, d, h, w) float32 torch.Tensor
            SDF divided by the voxel size; ``d, h, w`` even.
        nodes : (n, 3) int64 torch.Tensor
            Node coordinates ``(i, j, k)`` in the ``(d, h, w)`` grid.

        Returns
        -------
        offsets : (n, 3) float32
            In voxel units: generator = node position + offset * voxel size.
        logits : (n,) float32
            Occupancy of each generator's cell, positive inside.
        """
        features = self.node_features(sdf_voxels, nodes)
        offsets = self.offset_head(features)
        return offsets, self.occupancy(features, offsets)


def save_checkpoint(path, model: VoroNet, **state) -> None:
    """Write ``model`` (config and weights) and any extra training ``state`` atomically."""
    from ..io import atomic_path

    with atomic_path(path, suffix=".pt") as tmp:
        torch.save({"model_config": model.config, "model": model.state_dict(), **state}, tmp)


def load_checkpoint(path) -> tuple[VoroNet, dict]:
    """The model of a checkpoint written by :func:`save_checkpoint`, and the whole checkpoint dict.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        The file is not such a checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
        model = VoroNet(**checkpoint["model_config"])
        model.load_state_dict(checkpoint["model"])
    except Exception as error:  # pickle, zip and key errors of a foreign or corrupt file
        raise ValueError(f"{path} is not a voro3d.learn checkpoint: {error}") from error
    return model, checkpoint
