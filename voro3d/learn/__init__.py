"""Learning VoroMesh from SDF grids: training data, network, two-stage training, ONNX export.

Torch is imported by :mod:`~voro3d.learn.model`, :mod:`~voro3d.learn.train` and
:mod:`~voro3d.learn.export` only; this package itself and :mod:`~voro3d.learn.data` stay light.
"""
from __future__ import annotations

import os
import platform
from pathlib import Path

__all__ = ["machine_description"]


def machine_description() -> str:
    """CPU model and core count, for training records and benchmark tables."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:  # not Linux
        pass
    return f"{name}, {os.cpu_count()} cores"
