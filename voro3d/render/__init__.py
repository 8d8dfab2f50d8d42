"""Headless pictures of meshes: side-by-side panels and distance-error maps, written as PNG.

Two backends draw the panels with the same camera:

``"open3d"``
    Open3D's Filament ``OffscreenRenderer`` (physically based lighting), run in a child process
    per panel with a time limit. A broken GPU driver can abort a process instead of raising, and
    on a software rasteriser (Mesa llvmpipe) Filament sometimes takes minutes for a frame that
    usually takes half a second; the child keeps both away from the caller.
``"matplotlib"``
    A painter's-algorithm renderer: faces projected with the same perspective camera, Lambert
    shaded in numpy, long faces split, sorted back to front and drawn as one ``PolyCollection``.
    Always available, and about as fast as Open3D on a CPU-only machine.

``backend="auto"`` picks Open3D when a once-per-process probe finds it working on a hardware GPU
and matplotlib otherwise. Titles, colour bars and the PNG itself are always drawn by matplotlib
(Agg, no display).
"""
from __future__ import annotations

from .camera import BACKENDS, DEFAULT_COLOR, MAX_MATPLOTLIB_FACES, SHADINGS, TITLE_BAND, UP_AXES, VIEWS
from .open3d_backend import Open3DStatus, open3d_status
from .pictures import render_error_map, render_meshes, show

__all__ = ["BACKENDS", "DEFAULT_COLOR", "MAX_MATPLOTLIB_FACES", "Open3DStatus", "SHADINGS", "TITLE_BAND", "UP_AXES",
           "VIEWS", "open3d_status", "render_error_map", "render_meshes", "show"]
