"""The Open3D backend: Filament's offscreen renderer in a child process per panel, and the probe
that decides whether ``backend="auto"`` uses it.

The child is :mod:`voro3d.render.open3d_child`, run with ``python -m``.
"""
from __future__ import annotations

import os
import re
import site
import subprocess
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import face_area_vectors as _triangle_normals, vertex_normals
from .camera import BACKENDS, _Camera, _choice, _fit_camera, _light_directions, _srgb_to_linear, _unit
from .open3d_child import DONE

__all__ = ["OPEN3D_TIMEOUT", "Open3DStatus", "PROBE_TIMEOUT", "open3d_status"]

# Seconds for one Open3D child: starting Python, Open3D and Filament takes 2-3 s and a frame under
# 1 s on a GPU; Mesa llvmpipe on a loaded 2-core machine has taken 25 s to start and minutes to draw.
OPEN3D_TIMEOUT = 120.0
PROBE_TIMEOUT = 60.0
# Software rasterisers as Filament and Open3D name them; the driver names make the better message.
_SOFTWARE_DRIVER = re.compile(r"llvmpipe|lavapipe|softpipe|swiftshader", re.IGNORECASE)
_SOFTWARE_DEVICE = re.compile(r"software (device|rasteri[sz]er)", re.IGNORECASE)


@dataclass(frozen=True)
class Open3DStatus:
    """What the Open3D offscreen probe found; see :func:`open3d_status`."""

    works: bool | None  # None: not tried, because the device is a software rasteriser
    software: bool  # the device is a CPU rasteriser (Mesa llvmpipe and the like)
    detail: str  # the device line Filament printed, or why it does not work


_OPEN3D_STATUS: Open3DStatus | None = None


class _Open3DFailed(RuntimeError):
    pass


def _child_environment() -> dict:
    env = dict(os.environ)
    if sys.platform.startswith("linux") and not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY")):
        # Headless builds that go through EGL need its surfaceless platform; Vulkan ignores it.
        env.setdefault("EGL_PLATFORM", "surfaceless")
    # The child must import this very voro3d, also when it was put on sys.path by hand; a site
    # folder is on the child's path anyway, and ahead of the standard library it could shadow it.
    package_root = str(Path(__file__).resolve().parents[2])
    site_folders = {str(Path(folder).resolve()) for folder in [*site.getsitepackages(), site.getusersitepackages()]}
    if package_root not in site_folders:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [package_root, env.get("PYTHONPATH")]))
    return env


def _run_child(arguments: list[str], timeout: float) -> str:
    """Run :mod:`voro3d.render.open3d_child` with ``arguments``; return its output or raise ``_Open3DFailed``."""
    try:
        child = subprocess.run([sys.executable, "-m", "voro3d.render.open3d_child", *arguments],
                               env=_child_environment(), capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise _Open3DFailed(f"the Open3D renderer took longer than {timeout:.0f} s and was stopped") from None
    except OSError as error:
        raise _Open3DFailed(f"could not start the Open3D renderer: {error}") from None
    output = child.stdout + child.stderr
    if child.returncode != 0 or DONE not in child.stdout:
        raise _Open3DFailed(f"the Open3D renderer exited with {child.returncode}: {output.strip()[-600:]}")
    return output


def _run_open3d_child(job: dict, timeout: float) -> np.ndarray:
    """Render one panel in a child Python; returns the ``(height, width, 3)`` uint8 picture."""
    with tempfile.TemporaryDirectory(prefix="voro3d-render-") as folder:
        job_path, image_path = os.path.join(folder, "job.npz"), os.path.join(folder, "image.npy")
        np.savez(job_path, **job)
        _run_child([job_path, image_path], timeout)
        return np.load(image_path)


def _panel_job(vertices, triangles, camera: _Camera, *, shading: str, base_rgb=None, vertex_rgb=None) -> dict:
    if shading == "flat":
        # One vertex per corner, so each face is lit by its own normal.
        normals = np.repeat(_unit(_triangle_normals(vertices, triangles)), 3, axis=0)
        colors = None if vertex_rgb is None else vertex_rgb[triangles].reshape(-1, 3)
        vertices, triangles = vertices[triangles].reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3)
    else:
        normals, colors = vertex_normals(vertices, triangles), vertex_rgb
    key, _ = _light_directions(camera)
    job = {"size": np.array([camera.width, camera.height]), "vertices": np.ascontiguousarray(vertices, np.float64),
           "triangles": np.ascontiguousarray(triangles, np.int32), "normals": normals, "light": -key,
           "fov": np.array(camera.fov_y), "center": camera.center, "eye": camera.eye, "up": camera.up}
    if colors is not None:
        job["colors"] = np.ascontiguousarray(_srgb_to_linear(colors))
    else:
        job["base_color"] = _srgb_to_linear(base_rgb)
    return job


def _whiten(image: np.ndarray) -> np.ndarray:
    """Scale colours so the background comes out white.

    Filament's tone mapping turns the white clear colour into a warm grey. The camera margin keeps
    the four corners on background, so their colour measures that shift and its inverse undoes it
    (a white balance that leaves relative shading alone).
    """
    corners = np.stack([image[0, 0], image[0, -1], image[-1, 0], image[-1, -1]]).astype(np.float64)
    background = np.maximum(np.median(corners, axis=0), 1.0)
    return np.clip(np.rint(image * (255.0 / background)), 0, 255).astype(np.uint8)


def open3d_status() -> Open3DStatus:
    """Whether Open3D offscreen rendering works here, and on what device.

    Probed once per process, then cached: a child Python starts Filament and reports the device
    it picked; on a hardware device a second child renders a small box. Children, because a
    broken driver can abort a process rather than raise. On a software rasteriser the test frame
    is skipped (``works`` is None): ``backend="auto"`` does not use Open3D there anyway.

    Returns
    -------
    Open3DStatus
        ``works`` (True, False, or None when not tried), ``software`` and ``detail`` (the device
        line, or why Open3D does not work).
    """
    global _OPEN3D_STATUS
    if _OPEN3D_STATUS is not None:
        return _OPEN3D_STATUS
    try:
        output = _run_child(["device"], PROBE_TIMEOUT)
    except _Open3DFailed as error:
        _OPEN3D_STATUS = Open3DStatus(False, False, str(error))
        return _OPEN3D_STATUS
    lines = output.splitlines()
    software = (next((line.strip() for line in lines if _SOFTWARE_DRIVER.search(line)), "")
                or next((line.strip() for line in lines if _SOFTWARE_DEVICE.search(line)), ""))
    if software:
        _OPEN3D_STATUS = Open3DStatus(None, True, software)
        return _OPEN3D_STATUS
    device = next((line.strip() for line in lines if re.search(r"device|renderer|vendor", line, re.IGNORECASE)), "")
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    job = _panel_job(box, faces, _fit_camera(box, None, "z", 48, 32), shading="flat", base_rgb=(0.5, 0.5, 0.5))
    try:
        image = _run_open3d_child(job, PROBE_TIMEOUT)
    except _Open3DFailed as error:
        _OPEN3D_STATUS = Open3DStatus(False, False, str(error))
    else:
        drew = float(image.std()) > 0.0
        _OPEN3D_STATUS = Open3DStatus(drew, False, device if drew else "the Open3D renderer drew a blank image")
    return _OPEN3D_STATUS


def _resolve_backend(backend: str) -> str:
    _choice(backend, "backend", BACKENDS)
    if backend == "matplotlib":
        return backend
    status = open3d_status()
    if backend == "open3d":
        if status.works is False:
            raise RuntimeError(f"Open3D offscreen rendering does not work here ({status.detail}); use backend='matplotlib'")
        return backend
    return "open3d" if status.works and not status.software else "matplotlib"


def _open3d_panels(jobs: list[dict], *, required: bool) -> list[np.ndarray] | None:
    """Pictures for ``jobs``, or None after a failure when the caller can fall back."""
    global _OPEN3D_STATUS
    pictures = []
    for job in jobs:
        try:
            image = _run_open3d_child(job, OPEN3D_TIMEOUT)
        except _Open3DFailed as error:
            if required:
                raise RuntimeError(f"{error}; use backend='matplotlib'") from None
            # Do not pay the time limit again on every later picture in this process.
            _OPEN3D_STATUS = Open3DStatus(False, False, str(error))
            warnings.warn(f"{error}; drawing with matplotlib from now on", RuntimeWarning, stacklevel=3)
            return None
        pictures.append(_whiten(image))
    return pictures
