"""ONNX export of a trained network of :mod:`voro3d.learn.model`, checked against torch.

The graph (opset 17, torch's TorchScript-based exporter: the dynamo exporter needs onnxscript,
which voro3d does not depend on) has

* inputs: the arrays of :func:`voro3d.infer.band_input` (:data:`voro3d.infer.BAND_INPUTS`),
  every row count dynamic; the graph is gathers, matmuls, adds, pads and ReLUs;
* outputs ``offsets`` ``(n, 3)`` float32 in voxel units and ``logits`` ``(n,)`` float32, one row
  per generator node.

Metadata carries what :class:`voro3d.infer.Predictor` needs to build the input the model was
trained on (``near``, ``context``) and a record of its training.
"""
from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require

# Before .model, which needs torch too, so that the message names what was asked for.
torch = require("torch", "ONNX export (voro3d export-onnx)", "torch,onnx")

from ..infer import NEAR, OUTPUT_NAMES, check_sdf
from .model import BandNet, load_checkpoint

__all__ = ["ExportReport", "TOLERANCE", "check_grids", "export_model", "export_onnx"]

OPSET = 17
# Largest offset difference (voxel units) between onnxruntime and torch that export accepts.
TOLERANCE = 1e-4


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export_onnx` wrote and how closely onnxruntime reproduces torch.

    Attributes
    ----------
    path : pathlib.Path
    max_offset_diff : float
        Largest absolute difference of offsets (voxel units) over the check grids.
    max_logit_diff : float
        Largest absolute difference of occupancy logits.
    n_nodes : int
        Nodes compared.
    """

    path: Path
    max_offset_diff: float
    max_logit_diff: float
    n_nodes: int


def check_grids() -> list[np.ndarray]:
    """Analytic SDF grids (a capped cylinder at 24^3, a box with a spherical bite at 35^3).

    Two sizes, one odd, so the check covers the dynamic axes and the padding of odd crops.
    """
    from ..sampling import grid_nodes

    grids = []
    for g in (24, 35):
        p = grid_nodes(g)
        if g == 24:
            radial = np.linalg.norm(p[:, :2], axis=1) - 0.6
            sdf = np.maximum(radial, np.abs(p[:, 2]) - 0.5)
        else:
            box = np.abs(p) - np.array([0.7, 0.5, 0.4])
            sdf = np.linalg.norm(np.maximum(box, 0), axis=1) + np.minimum(box.max(axis=1), 0)
            sdf = np.maximum(sdf, 0.45 - np.linalg.norm(p - [0.7, 0.5, 0.4], axis=1))
        grids.append(sdf.reshape(g, g, g).astype(np.float32))
    return grids


def export_model(model: BandNet, out_path, *, near: float, metadata: dict | None = None) -> ExportReport:
    """Export ``model`` to ``out_path`` and compare onnxruntime with torch on :func:`check_grids`.

    Parameters
    ----------
    model : BandNet
    out_path : str or os.PathLike
        ``.onnx`` file, written atomically.
    near : float
        Node threshold in voxels the model was trained with (stored as metadata).
    metadata : dict, optional
        Extra string-able entries for the model's metadata (training record).

    Returns
    -------
    ExportReport

    Raises
    ------
    RuntimeError
        onnxruntime and torch differ by more than ``TOLERANCE`` (the file is not written).
    """
    import onnxruntime as ort

    onnx = require("onnx", "ONNX export (voro3d export-onnx)", "torch,onnx")

    from ..io import atomic_path

    model = model.eval()
    out_path = Path(out_path)
    example = model.network_input(check_grids()[0], near=near)
    names = list(model.input_names)
    inputs = tuple(torch.from_numpy(example.arrays[name]) for name in names)
    # Every row count depends on the grid; the 27 taps, 8 children and the channel do not.
    dynamic = {name: {0: f"{name}_rows"} for name in names}
    dynamic.update(offsets={0: "n"}, logits={0: "n"})
    entries = {"near": repr(float(near)), "context": repr(model.context),
               "receptive_radius": str(model.receptive_radius), "opset": str(OPSET),
               "model_config": json.dumps(model.config), **{k: str(v) for k, v in (metadata or {}).items()}}
    with atomic_path(out_path, suffix=".onnx") as tmp:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
            torch.onnx.export(model, inputs, tmp, dynamo=False, opset_version=OPSET, input_names=names,
                              output_names=list(OUTPUT_NAMES), dynamic_axes=dynamic)
        proto = onnx.load(tmp)
        for key, value in entries.items():
            proto.metadata_props.add(key=key, value=value)
        onnx.save(proto, tmp)

        session = ort.InferenceSession(tmp, providers=["CPUExecutionProvider"])
        offset_diff = logit_diff = 0.0
        n_nodes = 0
        for sdf in check_grids():
            net_input = model.network_input(check_sdf(sdf), near=near)
            with torch.no_grad():
                offsets, logits = model(**{k: torch.from_numpy(v) for k, v in net_input.arrays.items()})
            ort_offsets, ort_logits = session.run(None, net_input.arrays)
            offset_diff = max(offset_diff, float(np.abs(ort_offsets - offsets.numpy()).max()))
            logit_diff = max(logit_diff, float(np.abs(ort_logits - logits.numpy()).max()))
            n_nodes += net_input.ijk.shape[0]
        if offset_diff > TOLERANCE:
            raise RuntimeError(f"onnxruntime offsets differ from torch by {offset_diff:.3g} voxels "
                               f"(> {TOLERANCE}); not writing {out_path}")
    return ExportReport(out_path, offset_diff, logit_diff, n_nodes)


def export_onnx(checkpoint, out_path) -> ExportReport:
    """Export the model of a training checkpoint (:func:`voro3d.learn.train.train_main`) to ONNX.

    Parameters
    ----------
    checkpoint : str or os.PathLike
        A ``.pt`` checkpoint.
    out_path : str or os.PathLike
        The ``.onnx`` file to write.

    Returns
    -------
    ExportReport
        Including the largest onnxruntime-vs-torch offset difference, at most ``TOLERANCE``.

    Raises
    ------
    FileNotFoundError, ValueError
        Missing or unreadable checkpoint.
    RuntimeError
        onnxruntime disagrees with torch.
    """
    model, state = load_checkpoint(checkpoint)
    record = {key: json.dumps(state[key]) for key in ("training", "validation") if key in state}
    return export_model(model, out_path, near=float(state.get("near", NEAR)), metadata=record)
