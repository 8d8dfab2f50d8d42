"""voro3d: watertight, self-intersection-free surface meshes with VoroMesh.

Public names are imported lazily so that ``import voro3d`` (and ``voro3d --help``) stays
instant and inference never loads torch. No module is named like a public function (the fit
lives in ``fitting``): importing a submodule binds its name on the package, which would hide
a function of the same name.

API conventions
---------------
One style for every public function (``tests/test_api.py`` walks them all and checks it):

- **Arguments.** The input comes first (a mesh, a cloud, an SDF grid, a folder), then at most one
  more positional argument (the grid, or a second input: ``fit(mesh, 32)``, ``evaluate(pred, gt)``);
  every option after those is keyword-only.
- **One name per thing.** ``grid`` (nodes per axis of the VoroMesh grid), ``n_samples`` (surface
  samples: ``fit``, ``sample_surface``, ``evaluate``; the CLI's ``eval --n-samples``, which still accepts
  the old ``--n-points``), ``seed`` (an int: the same seed gives the same output), ``steps``, ``device``
  (``"cpu"``, ``"cuda"``, ``"cuda:N"``: torch work only), ``model`` (an ONNX file, or a ``Predictor`` for
  ``predict``), ``threads``, ``tolerance``, ``progress``. In ``voro3d.pointcloud``, ``resolution`` is the
  lattice of the target field, which is not the VoroMesh grid.
- **``progress=False`` everywhere.** Library calls run inside pipelines, batches, notebooks and
  tests, where a bar nobody asked for is noise on stderr (Open3D's and scikit-image's functions
  print nothing either). The ``voro3d`` command is where a person waits: it shows bars unless ``-q``.
- **One documented return type per function; no argument changes what or how many values come
  back** (no ``return_info=``):

  | call | returns |
  |---|---|
  | ``reconstruct(geometry)``, ``VoroMeshStage(...)(geometry)``, ``extract_mesh``, ``VoroMesh.to_open3d()``, ``clean(mesh)``, ``snap(mesh, surface)``, ``pointcloud.cloud_mesh(shape, target)`` | ``open3d.geometry.TriangleMesh`` (geometry in, geometry out, like Open3D's Poisson); ``extract_mesh`` gives the Voronoi faces as they are, ``reconstruct``, ``VoroMeshStage``, ``to_open3d`` and ``cloud_mesh`` take ``clean=True`` |
  | ``fit(mesh, grid)``, ``fitting.fit_samples`` | ``(VoroMesh, FitInfo)``, always: an optimisation has a loss curve and a time split worth reading; ``shape, _ = fit(mesh)`` when only the shape matters |
  | ``pointcloud.reconstruct_points(points)`` | ``(VoroMesh, SnapTarget, PointCloudInfo)``, always: the target surface the stages after extraction fit to, and what was found |
  | ``predict(sdf)``, ``predict_from_mesh(mesh, grid)``, ``Predictor.predict``, ``Predictor.predict_from_mesh`` | ``VoroMesh``: a forward pass has no loss or convergence to report |

  A ``VoroMesh`` is generators with their occupancy, grid and frame (``voxel``, ``save``, ``load``, ``to_open3d()``); "mesh" always
  means a triangle mesh, so ``predict_from_mesh`` names what goes in: a mesh in, a VoroMesh out, as
  with ``fit``.
- **Options a method does not use are refused, not dropped**, with a ``ValueError`` that names
  both: ``reconstruct(cloud, method="learned", steps=100)`` raises ``method='learned' takes no steps
  (only method='fit' uses it)``; likewise ``seed`` and ``device`` there, in ``VoroMeshStage`` and in
  ``pointcloud.reconstruct_points``; ``run_batch(method="learned", steps=...)`` and
  ``run_batch(method="fit", model=...)``; ``plan`` with a mesh; ``voroloss(k=..., candidates=...)``;
  ``voro3d predict sdf.npy --grid 32``. So the fit's options of ``reconstruct`` default to None,
  meaning the fit's own defaults (400 steps, 120 for a cloud, seed 0, ``"cpu"``). ``progress`` is taken by every
  method: it only asks to see whatever runs.
- **Bad input** raises ``ValueError`` (or ``TypeError`` for a wrong type) naming the argument, what was
  expected and what arrived; the CLI prints it as one line and exits with status 2.
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
