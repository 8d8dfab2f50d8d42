"""The optional dependencies (extras): a feature that needs a missing one says, in one line, how to get it.

``pip install voro3d`` brings what ``reconstruct``, ``fit`` on the CPU, ``predict``, ``extract_mesh``,
``clean`` and ``batch`` need. Training, ONNX export and ``device="cuda"`` need torch
(``voro3d[torch]``), the export onnx too (``voro3d[onnx]``), ``engine="ray"`` Ray (``voro3d[ray]``).
"""
from __future__ import annotations

from importlib import import_module

__all__ = ["MissingExtra", "require"]


class MissingExtra(ImportError):
    """An optional dependency a feature needs is not installed; the message names the extra."""


def require(module: str, feature: str, extras: str | None = None):
    """Import ``module`` for ``feature``, or raise :class:`MissingExtra` naming the extras that install it.

    Parameters
    ----------
    module : str
        The top-level module (``"torch"``, ``"onnx"``, ``"ray"``).
    feature : str
        What asked for it, as the user named it (``"device='cuda'"``, ``"voro3d train"``).
    extras : str, optional
        The extras to name, comma-separated; default ``module``.

    Returns
    -------
    module
    """
    try:
        return import_module(module)
    except ModuleNotFoundError as error:
        if error.name != module:  # installed, but something it imports is not: that error says more
            raise
        raise MissingExtra(f"{feature} needs {module}: pip install 'voro3d[{extras or module}]'") from None
