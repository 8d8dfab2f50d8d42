"""The VoroMesh networks: SDF grid in, per-node generator offsets and occupancy logits out.

:class:`BandNet` (``"arch": "band"``) runs sparse convolutions on the band of nodes near the
surface; :class:`VoroNet` (``"arch": "dense"``, the shipped model's network) runs dense
convolutions on the cropped grid. :func:`build_model` makes either from a config.

VoroNet layout (``w = width``, ``c = coarse_width``)::

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

import numpy as np
import torch
from torch import nn

from ..infer import BAND_INPUTS, DENSE_INPUTS, NetworkInput, band_input, network_input

__all__ = ["BandNet", "VoroNet", "build_model", "load_checkpoint", "save_checkpoint"]

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
    input_names = DENSE_INPUTS

    def __init__(self, *, width: int = 16, coarse_width: int = 32, head_width: int = 64, truncation: float = 3.0):
        super().__init__()
        self.config = {"arch": "dense", "width": width, "coarse_width": coarse_width, "head_width": head_width,
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

    def network_input(self, sdf: np.ndarray, *, near: float) -> NetworkInput:
        """:func:`voro3d.infer.network_input` of a ``(g, g, g)`` float32 grid, cropped to the receptive radius."""
        return network_input(sdf, near=near, margin=self.receptive_radius)

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


class _SparseConv(nn.Module):
    """Submanifold 3^3 convolution: gather each node's 27 neighbours' features, one matmul.

    ``forward(x, neighbours)``: ``x (n, c_in)``, ``neighbours (m, 27)`` int64 rows of ``x``
    (``n`` = absent, read as zeros) -> ``(m, c_out)``. ``m`` may differ from ``n``: the
    convolution can be evaluated at a subset of the nodes.
    """

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.linear = nn.Linear(27 * c_in, c_out)

    def forward(self, x, neighbours):
        rows = nn.functional.pad(x, (0, 0, 0, 1)).index_select(0, neighbours.flatten())
        return self.linear(rows.view(neighbours.shape[0], -1))


class _SparseResidual(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.first = _SparseConv(channels, channels)
        self.second = _SparseConv(channels, channels)
        with torch.no_grad():
            self.second.linear.weight.mul_(0.1)  # start close to the identity

    def forward(self, x, neighbours):
        return torch.relu(x + self.second(torch.relu(self.first(x, neighbours)), neighbours))


class _Down(nn.Module):
    """Stride-2 2^3 convolution: the children's features in parity order, one matmul (absent = zeros)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.linear = nn.Linear(8 * c_in, c_out)

    def forward(self, x, children):
        rows = nn.functional.pad(x, (0, 0, 0, 1)).index_select(0, children.flatten())
        return self.linear(rows.view(children.shape[0], -1))


class _Up(nn.Module):
    """Stride-2 2^3 transposed convolution: a ``c_in -> c_out`` map per child parity, read at ``8 parent + parity``."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.c_out = c_out
        self.linear = nn.Linear(c_in, 8 * c_out)

    def forward(self, coarse, up):
        return self.linear(coarse).view(-1, self.c_out).index_select(0, up)


class BandNet(nn.Module):
    """Sparse residual U-Net on the band of nodes near the surface, read at the generator nodes.

    Layout (``w0, w1, w2 = widths``; every convolution is a submanifold 3^3 one over the band's
    nodes of its level, built by :func:`voro3d.infer.band_input`)::

        x = band_sdf / context                                   (n0, 1), in [-1, 1]
        level 0:  conv 1→w0, res(w0)                             f0 (n0, w0)
        level 1:  down w0→w1, res(w1), res(w1)                   f1 (n1, w1)
        level 2:  down w1→w2, res(w2), res(w2)                   f2 (n2, w2)
        level 1:  f1 + up(f2) w2→w1, res(w1)                     u1
        level 0:  f0 + up(u1) w1→w0                              u0
        at the generator nodes only: conv(u0) w0→head, and the raw 3^3 patch of x (27)
        MLP1 → offset (3, voxels); MLP2 on [features, offset] → occupancy logit

    Compute is spent where the surface is: a 64^3 grid has about 30,000 band nodes with
    ``context = 4``, against 262,144 grid nodes. A node's features depend on band nodes within
    35 nodes of it (receptive field 71^3 in the grid; the paper's is about 19^3), so context
    reaches across the band and along the surface; only the band's extent limits it. There is no
    normalisation layer: a node's outputs depend on its neighbourhood alone (and on the parity of
    its position, through the stride-2 levels).

    Parameters
    ----------
    widths : tuple of 3 int
        Channels at strides 1, 2 and 4.
    head_width : int
        Channels of the generator nodes' convolution and hidden width of both MLPs.
    context : float
        Band half-width in voxels: nodes with ``|sdf| < context`` are the network's input.
    """

    input_names = BAND_INPUTS
    receptive_radius = 35

    def __init__(self, *, widths=(16, 32, 64), head_width: int = 64, context: float = 4.0):
        super().__init__()
        w0, w1, w2 = (int(w) for w in widths)
        self.config = {"arch": "band", "widths": [w0, w1, w2], "head_width": head_width, "context": float(context)}
        self.context = float(context)
        self.stem = _SparseConv(1, w0)
        self.res0 = _SparseResidual(w0)
        self.down1 = _Down(w0, w1)
        self.res1 = nn.ModuleList([_SparseResidual(w1), _SparseResidual(w1)])
        self.down2 = _Down(w1, w2)
        self.res2 = nn.ModuleList([_SparseResidual(w2), _SparseResidual(w2)])
        self.up2 = _Up(w2, w1)
        self.res1_up = _SparseResidual(w1)
        self.up1 = _Up(w1, w0)
        self.head = _SparseConv(w0, head_width)
        features = head_width + 27
        self.offset_head = _mlp(features, head_width, 3)
        self.occupancy_head = _mlp(features + 3, head_width, 1)
        with torch.no_grad():
            self.offset_head[-1].weight.normal_(std=0.01)
            self.offset_head[-1].bias.zero_()

    def network_input(self, sdf: np.ndarray, *, near: float) -> NetworkInput:
        """:func:`voro3d.infer.band_input` of a ``(g, g, g)`` float32 grid with this network's context."""
        return band_input(sdf, near=near, context=self.context)

    def node_features(self, band_sdf, neighbours0, neighbours1, neighbours2, children1, children2, up1, up2,
                      targets) -> torch.Tensor:
        """``(k, head_width + 27)`` features of the generator nodes (arguments: :data:`voro3d.infer.BAND_INPUTS`)."""
        x = band_sdf / self.context
        f0 = self.res0(torch.relu(self.stem(x, neighbours0)), neighbours0)
        f1 = torch.relu(self.down1(f0, children1))
        for block in self.res1:
            f1 = block(f1, neighbours1)
        f2 = torch.relu(self.down2(f1, children2))
        for block in self.res2:
            f2 = block(f2, neighbours2)
        u1 = self.res1_up(torch.relu(f1 + self.up2(f2, up2)), neighbours1)
        u0 = torch.relu(f0 + self.up1(u1, up1))
        local = neighbours0.index_select(0, targets)
        patch = nn.functional.pad(x, (0, 0, 0, 1)).index_select(0, local.flatten()).view(-1, 27)
        return torch.cat([torch.relu(self.head(u0, local)), patch], dim=1)

    def occupancy(self, node_features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """``(k,)`` occupancy logits (positive inside) from node features and ``(k, 3)`` offsets."""
        return self.occupancy_head(torch.cat([node_features, offsets], dim=1))[:, 0]

    def forward(self, band_sdf, neighbours0, neighbours1, neighbours2, children1, children2, up1, up2, targets):
        """Offsets ``(k, 3)`` float32 in voxels and occupancy logits ``(k,)`` of the generator nodes.

        The arguments are the arrays of :func:`voro3d.infer.band_input` as tensors, in the
        order of :data:`voro3d.infer.BAND_INPUTS`; ``k`` is the length of ``targets``.
        """
        features = self.node_features(band_sdf, neighbours0, neighbours1, neighbours2, children1, children2, up1,
                                      up2, targets)
        offsets = self.offset_head(features)
        return offsets, self.occupancy(features, offsets)


# Networks by the "arch" entry of a model config.
ARCHITECTURES = {"dense": VoroNet, "band": BandNet}


def build_model(config: dict) -> nn.Module:
    """The network of a model config: ``"arch"`` (``"dense"``, the default, or ``"band"``) and its keyword arguments.

    Raises
    ------
    ValueError
        Unknown ``arch`` or an argument that network does not take.
    """
    options = dict(config)
    arch = options.pop("arch", "dense")
    if arch not in ARCHITECTURES:
        raise ValueError(f"model arch must be one of {sorted(ARCHITECTURES)}, got {arch!r}")
    try:
        return ARCHITECTURES[arch](**options)
    except TypeError as error:
        raise ValueError(f"bad model config {config}: {error}") from None


def save_checkpoint(path, model: nn.Module, **state) -> None:
    """Write ``model`` (config and weights) and any extra training ``state`` atomically."""
    from ..io import atomic_path

    with atomic_path(path, suffix=".pt") as tmp:
        torch.save({"model_config": model.config, "model": model.state_dict(), **state}, tmp)


def load_checkpoint(path) -> tuple[nn.Module, dict]:
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
        model = build_model(checkpoint["model_config"])
        model.load_state_dict(checkpoint["model"])
    except Exception as error:  # pickle, zip and key errors of a foreign or corrupt file
        raise ValueError(f"{path} is not a voro3d.learn checkpoint: {error}") from error
    return model, checkpoint
