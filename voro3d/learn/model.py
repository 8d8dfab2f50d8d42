"""The VoroMesh network: SDF grid in, per-node generator offsets and occupancy logits out.

:class:`BandNet` runs sparse (submanifold) convolutions on the band of nodes near the surface,
as gathers over precomputed neighbour indices plus matmuls (cheap on a CPU, standard ONNX ops),
and reads its outputs at the generator nodes only. :func:`build_model` makes it from a config
(``"arch": "band"``). The dense CNN that shipped before it (VoroNet: dense convolutions on the
cropped grid) was removed when BandNet replaced it; it lives in the git history.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .._extras import require
from ..infer import BAND_INPUTS, NetworkInput, band_input

torch = require("torch", "the network (voro3d.learn.model)")
nn = torch.nn

__all__ = ["BandNet", "build_model", "load_checkpoint", "save_checkpoint"]

# Slope of the leaky ReLUs (the official code's).
SLOPE = 0.01


def _mlp(n_in: int, width: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, width), nn.LeakyReLU(SLOPE), nn.Linear(width, width), nn.LeakyReLU(SLOPE),
                         nn.Linear(width, n_out))


class _GatherConv(nn.Module):
    """A convolution over indexed nodes: gather each output node's ``taps`` input rows, one matmul.

    ``forward(x, taps_index)``: ``x (n, c_in)``, ``taps_index (m, taps)`` int64 rows of ``x``
    (``n`` = absent, read as zeros) -> ``(m, c_out)``. With the 27 neighbours of a node it is a
    submanifold 3^3 convolution (``m`` may differ from ``n``: it can be evaluated at a subset of
    the nodes); with the 8 children of a coarse node, in parity order, a stride-2 2^3 one.
    """

    def __init__(self, c_in: int, c_out: int, taps: int = 27):
        super().__init__()
        self.linear = nn.Linear(taps * c_in, c_out)

    def forward(self, x, taps_index):
        rows = nn.functional.pad(x, (0, 0, 0, 1)).index_select(0, taps_index.flatten())
        return self.linear(rows.view(taps_index.shape[0], -1))


class _SparseResidual(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.first = _GatherConv(channels, channels)
        self.second = _GatherConv(channels, channels)
        with torch.no_grad():
            self.second.linear.weight.mul_(0.1)  # start close to the identity

    def forward(self, x, neighbours):
        return torch.relu(x + self.second(torch.relu(self.first(x, neighbours)), neighbours))


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

    Compute is spent where the surface is: a 64^3 grid has 20,000-30,000 band nodes with
    ``context = 3``, against 262,144 grid nodes. A node's features depend on band nodes within
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

    def __init__(self, *, widths=(16, 32, 64), head_width: int = 64, context: float = 3.0):
        super().__init__()
        w0, w1, w2 = (int(w) for w in widths)
        self.config = {"arch": "band", "widths": [w0, w1, w2], "head_width": head_width, "context": float(context)}
        self.context = float(context)
        self.stem = _GatherConv(1, w0)
        self.res0 = _SparseResidual(w0)
        self.down1 = _GatherConv(w0, w1, taps=8)
        self.res1 = nn.ModuleList([_SparseResidual(w1), _SparseResidual(w1)])
        self.down2 = _GatherConv(w1, w2, taps=8)
        self.res2 = nn.ModuleList([_SparseResidual(w2), _SparseResidual(w2)])
        self.up2 = _Up(w2, w1)
        self.res1_up = _SparseResidual(w1)
        self.up1 = _Up(w1, w0)
        self.head = _GatherConv(w0, head_width)
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
ARCHITECTURES = {"band": BandNet}


def build_model(config: dict) -> nn.Module:
    """The network of a model config: ``"arch"`` (``"band"``, the default) and its keyword arguments.

    Raises
    ------
    ValueError
        Unknown ``arch`` or an argument that network does not take.
    """
    options = dict(config)
    arch = options.pop("arch", "band")
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
