"""voro3d: watertight, self-intersection-free surface meshes with VoroMesh.

Public names are imported lazily so that ``import voro3d`` (and ``voro3d --help``) stays
instant and inference never loads torch. No module is named like a public function (the fit
lives in ``fitting``): importing a submodule binds its name on the package, which would hide
a function of the same name.
"""
from importlib import import_module

from ._open3d_import import defer_web_viewer as _defer_web_viewer

__version__ = "0.1.0"

# Open3D's plotly/dash web viewer, which voro3d never uses, is loaded only if something calls it.
_defer_web_viewer()

_PUBLIC = {
    "load_mesh": "io",
    "save_mesh": "io",
    "sample_surface": "sampling",
    "initial_generators": "generators",
    "voroloss": "loss",
    "knn_candidates": "loss",
    "fit": "fitting",
    "FitInfo": "fitting",
    "label_cells": "occupancy",
    "VoroMesh": "voromesh",
    "extract_mesh": "extract",
    "check_watertight": "watertight",
    "WatertightReport": "watertight",
    "evaluate": "metrics",
    "clean": "cleaning",
    "snap": "snapping",
    "render_meshes": "render",
    "predict": "infer",
    "predict_from_mesh": "infer",
    "Predictor": "infer",
    "reconstruct": "reconstruction",
    "VoroMeshStage": "reconstruction",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name):
    if name in _PUBLIC:
        return getattr(import_module(f".{_PUBLIC[name]}", __name__), name)
    raise AttributeError(f"module 'voro3d' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_PUBLIC))
