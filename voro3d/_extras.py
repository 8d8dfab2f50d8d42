"""The optional dependencies (extras): a feature that needs a missing one says, in one line, how to get it.

``pip install voro3d`` brings what ``reconstruct``, ``fit`` on the CPU, ``predict``, ``extract_mesh``,
``clean`` and ``batch`` need. Training, ONNX export and ``device="cuda"`` need torch
(``voro3d[torch]``), the export onnx too (``voro3d[onnx]``), ``engine="ray"`` Ray (``voro3d[ray]``).
"""
from __future__ import annotations

import contextlib
import logging
import os
from importlib import import_module

__all__ = ["MissingExtra", "ray_session", "require"]


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


@contextlib.contextmanager
def ray_session(num_cpus: int, *, address: str | None = None):
    """Ray for ``engine='ray'``: the running one, else one started here (``num_cpus`` CPUs, or joined at
    ``address``) and shut down on leaving; yields the ``ray`` module."""
    ray = require("ray", "engine='ray'")
    started_here = not ray.is_initialized()
    if started_here:
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report: runs offline
        options = {"address": address} if address else {"num_cpus": num_cpus, "include_dashboard": False}
        ray.init(**options, log_to_driver=False, logging_level=logging.WARNING)
    try:
        yield ray
    finally:
        if started_here:
            ray.shutdown()
