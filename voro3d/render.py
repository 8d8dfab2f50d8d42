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

import math
import os
import re
import subprocess
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io import atomic_path, mesh_arrays, to_triangle_mesh, vertex_normals

BACKENDS = ("auto", "open3d", "matplotlib")
SHADINGS = ("flat", "smooth")
UP_AXES = ("x", "y", "z")
# (azimuth, elevation) in degrees. Azimuth turns about the up axis from the "right" axis
# (+x when up is z or y); elevation is the angle above the horizontal plane.
VIEWS = {"iso": (-55.0, 25.0), "front": (-90.0, 0.0), "side": (0.0, 0.0), "top": (-90.0, 90.0)}
DEFAULT_COLOR = "#9db9d6"
# The matplotlib backend draws every face as a polygon: inputs are decimated to this many faces,
# and splitting long faces for a correct back-to-front order may double it.
MAX_MATPLOTLIB_FACES = 40_000
SUPERSAMPLE = 2  # matplotlib panels are drawn this many times larger, then averaged down
SPLIT_FRACTION = 1.0 / 40.0  # split faces with an edge longer than this fraction of the scene diagonal
FIELD_OF_VIEW = 30.0  # vertical, degrees: mild perspective, little distortion
MARGIN = 0.08  # fraction of the image kept free around the fitted shapes (the corners stay background)
TITLE_BAND = 40  # pixels above the panels for titles
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


# --------------------------------------------------------------------------- validation


def _meshes_arg(meshes) -> list[tuple[np.ndarray, np.ndarray]]:
    if hasattr(meshes, "triangles") or hasattr(meshes, "triangle"):
        meshes = [meshes]
    if not isinstance(meshes, (list, tuple)):
        raise TypeError(f"meshes must be a TriangleMesh or a list of them, got {type(meshes).__name__}")
    if len(meshes) == 0:
        raise ValueError("meshes must hold at least one mesh, got 0")
    return [mesh_arrays(mesh, f"meshes[{i}]") for i, mesh in enumerate(meshes)]


def _size_arg(size) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in size)
        ok = all(float(v) == int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (width, height) in pixels, got {size!r}") from None
    if not ok or not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise ValueError(f"size must be (width, height) with whole pixels in [16, 8192], got {size!r}")
    return width, height


def _choice(value, name: str, choices) -> str:
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def _png_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"path must end in .png, got {str(path)!r}")
    return path


def _per_mesh(values, name: str, count: int) -> list:
    if isinstance(values, (str, bytes)) or not isinstance(values, (list, tuple)):
        raise ValueError(f"{name} must be a list with one entry per mesh ({count}), got {type(values).__name__}")
    if len(values) != count:
        raise ValueError(f"{name} must hold one entry per mesh ({count}), got {len(values)}")
    return list(values)


def _rgb(color, name: str) -> np.ndarray:
    from matplotlib.colors import to_rgb

    try:
        return np.array(to_rgb(color))
    except (ValueError, TypeError):
        raise ValueError(f"{name} must be a matplotlib colour (name, '#rrggbb' or RGB in [0, 1]), got {color!r}") from None


# --------------------------------------------------------------------------- camera


@dataclass(frozen=True)
class _Camera:
    """A perspective camera looking at ``center`` from ``eye``; ``right``/``up``/``back`` are orthonormal."""

    eye: np.ndarray
    center: np.ndarray
    right: np.ndarray
    up: np.ndarray
    back: np.ndarray  # from the scene towards the eye
    fov_y: float  # degrees
    width: int
    height: int

    @property
    def tan_y(self) -> float:
        return math.tan(math.radians(self.fov_y) / 2.0)

    @property
    def tan_x(self) -> float:
        return self.tan_y * self.width / self.height

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World ``(n, 3)`` -> ``(n, 3)`` columns x right, y up, depth in front of the eye."""
        rel = points - self.eye
        return np.stack([rel @ self.right, rel @ self.up, -(rel @ self.back)], axis=1)


def _view_arg(view) -> tuple[float, float]:
    if view is None:
        return VIEWS["iso"]
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"view must be one of {list(VIEWS)} or (azimuth, elevation) in degrees, got {view!r}")
        return VIEWS[view]
    try:
        azimuth, elevation = (float(v) for v in view)
    except (TypeError, ValueError):
        raise ValueError(f"view must be one of {list(VIEWS)} or (azimuth, elevation) in degrees, got {view!r}") from None
    if not (math.isfinite(azimuth) and -90.0 <= elevation <= 90.0):
        raise ValueError(f"view must have a finite azimuth and an elevation in [-90, 90], got {view!r}")
    return azimuth, elevation


def _fit_camera(points: np.ndarray, view, up: str, width: int, height: int) -> _Camera:
    """Camera for ``view`` whose frustum holds ``points`` ``(n, 3)`` with a margin, centred on screen.

    Fitting the points themselves rather than their bounding box frames round and diagonal
    shapes tightly; all panels of one picture share this camera, so they share scale.
    """
    azimuth, elevation = (math.radians(a) for a in _view_arg(view))
    # A right-handed (horizontal, depth, vertical) basis per up axis; with up="y" the front view
    # looks down -z, as in most y-up datasets.
    e1, e2, e3 = {"z": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
                  "y": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
                  "x": ((0, 1, 0), (0, 0, 1), (1, 0, 0))}[up]
    e1, e2, e3 = (np.array(e, dtype=np.float64) for e in (e1, e2, e3))
    back = math.cos(elevation) * (math.cos(azimuth) * e1 + math.sin(azimuth) * e2) + math.sin(elevation) * e3
    right = np.cross(-back, e3)
    if np.linalg.norm(right) < 1e-6:  # straight down or up: keep e1 pointing right on screen
        right = e1 if elevation > 0 else -e1
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, -back)

    low, high = points.min(axis=0), points.max(axis=0)
    center = (low + high) / 2.0
    # A shape of zero extent still needs a distance to be seen from.
    scale = max(float(np.linalg.norm(high - low)), 1e-9 * max(1.0, float(np.abs(center).max())), 1e-12)
    tan_y = math.tan(math.radians(FIELD_OF_VIEW) / 2.0) * (1.0 - 2.0 * MARGIN)
    tan_x = tan_y * width / height
    for _ in range(3):
        rel = points - center
        x, y, z = rel @ right, rel @ cam_up, rel @ back
        # A point at (x, y), z towards the eye, is inside the frustum when |x| <= tan_x * (distance - z).
        distance = max(float(np.max(z + np.maximum(np.abs(x) / tan_x, np.abs(y) / tan_y))), 1e-3 * scale)
        depth = distance - z
        sx, sy = x / depth, y / depth
        # Move the look-at point so the silhouette's screen extent is centred.
        shift_x, shift_y = (sx.max() + sx.min()) / 2.0, (sy.max() + sy.min()) / 2.0
        if max(abs(shift_x) / tan_x, abs(shift_y) / tan_y) < 1e-3:
            break
        center = center + distance * (shift_x * right + shift_y * cam_up)
    return _Camera(center + distance * back, center, right, cam_up, back, FIELD_OF_VIEW, width, height)


def _fit_points(arrays) -> np.ndarray:
    """The points the camera must frame: convex-hull vertices of all meshes' used vertices.

    The fit maximises linear and linear-fractional functions of the points, whose maxima lie on
    the hull, so the hull gives the same camera as every vertex, fast.
    """
    from scipy.spatial import ConvexHull, QhullError

    points = np.concatenate([v[np.unique(t)] for v, t in arrays])
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):  # flat or degenerate input: every point, it is small anyway
        return points


# --------------------------------------------------------------------------- shading helpers


def _triangle_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted (unnormalised) normals ``(t, 3)``."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return np.cross(b - a, c - a)


def _unit(vectors: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(length > 0, length, 1.0)


def _light_directions(camera: _Camera) -> tuple[np.ndarray, np.ndarray]:
    """Key light from the upper left behind the viewer, and a dim fill from the right."""
    key = _unit(-0.45 * camera.right + 0.65 * camera.up + 0.6 * camera.back)
    fill = _unit(0.7 * camera.right - 0.2 * camera.up + 0.7 * camera.back)
    return key, fill


def _lambert(normals: np.ndarray, camera: _Camera, ambient: float = 0.22) -> np.ndarray:
    """Brightness in [ambient, 1] for unit ``normals`` ``(n, 3)``; two-sided so flipped faces still read."""
    key, fill = _light_directions(camera)
    diffuse = np.clip(0.8 * np.abs(normals @ key) + 0.25 * np.abs(normals @ fill), 0.0, 1.0)
    return ambient + (1.0 - ambient) * diffuse


def _srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    """Matplotlib colours are sRGB; Filament shades in linear light and encodes sRGB on output."""
    rgb = np.asarray(rgb, dtype=np.float64)
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)


# --------------------------------------------------------------------------- matplotlib backend


def _decimate(vertices: np.ndarray, triangles: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``limit`` faces: quadric decimation, after a cheap first cut on huge meshes."""
    if len(triangles) <= limit:
        return vertices, triangles
    mesh = to_triangle_mesh(vertices, triangles)
    if len(triangles) > 4 * limit:
        # Quadric decimation takes seconds per few hundred thousand faces; vertex clustering is ten
        # times faster. Cells of this size leave about twice the budget on a smooth surface.
        area = float(np.linalg.norm(_triangle_normals(vertices, triangles), axis=1).sum()) / 2.0
        clustered = mesh.simplify_vertex_clustering(voxel_size=math.sqrt(area / limit))
        if len(clustered.triangles) >= limit:
            mesh = clustered
    simple = mesh.simplify_quadric_decimation(target_number_of_triangles=limit)
    return np.asarray(simple.vertices), np.asarray(simple.triangles)


def _split_long_faces(corners: np.ndarray, colors: np.ndarray, limit: float, budget: int):
    """Halve faces across their longest edge until no edge exceeds ``limit`` or ``budget`` faces exist.

    Sorting whole faces by mean depth misorders long thin faces (CAD meshes are full of them)
    against their neighbours; small pieces sort correctly. Longest-edge bisection also makes
    slivers rounder, where a split into four similar slivers leaves a sawtooth along edges.
    ``corners`` and the per-corner ``colors`` are ``(t, 3, 3)``; the pieces need not share
    vertices, so T-junctions are harmless.
    """
    rotations = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1]])
    for _ in range(32):
        lengths = np.linalg.norm(corners - corners[:, [1, 2, 0]], axis=2)  # edges 01, 12, 20
        longest = lengths.max(axis=1)
        room = budget - len(corners)
        split = np.flatnonzero(longest > limit)
        if len(split) == 0 or room <= 0:
            break
        if len(split) > room:
            split = split[np.argsort(-longest[split], kind="stable")[:room]]
        keep = np.ones(len(corners), dtype=bool)
        keep[split] = False
        # Rotate each face so its longest edge runs from corner 0 to corner 1; orientation is kept.
        order = rotations[lengths[split].argmax(axis=1)]
        pieces = []
        for values in (corners[split], colors[split]):
            values = np.take_along_axis(values, order[:, :, None], axis=1)
            mid = (values[:, 0] + values[:, 1]) / 2.0
            pieces.append(np.concatenate([np.stack([values[:, 0], mid, values[:, 2]], axis=1),
                                          np.stack([mid, values[:, 1], values[:, 2]], axis=1)]))
        corners = np.concatenate([corners[keep], pieces[0]])
        colors = np.concatenate([colors[keep], pieces[1]])
    return corners, colors


def _facing_sign(vertices: np.ndarray, triangles: np.ndarray) -> int:
    """+1 when triangles face outward on a closed, consistently oriented mesh, -1 inward, 0 otherwise.

    Only then may back faces be dropped: on an open or inconsistently oriented mesh a face seen
    from behind can be the visible one.
    """
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).astype(np.int64)
    count = np.int64(len(vertices))
    codes = directed[:, 0] * count + directed[:, 1]
    if len(np.unique(codes)) != len(codes) or not np.isin(directed[:, 1] * count + directed[:, 0], codes).all():
        return 0
    a, b, c = (vertices[triangles[:, i]] - vertices.mean(axis=0) for i in range(3))
    volume = float(np.einsum("ij,ij->", a, np.cross(b, c)))
    return 0 if volume == 0.0 else int(np.sign(volume))


def _matplotlib_panel(vertices, triangles, camera: _Camera, *, rgb, shading: str, split_limit: float,
                      ambient: float = 0.22) -> np.ndarray:
    """``(height, width, 3)`` uint8 picture.

    ``rgb`` is one colour ``(3,)`` or one per vertex ``(v, 3)``, in [0, 1]. A higher ``ambient``
    flattens the shading, for colours that have to be read off a colour bar.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    vertex_rgb = np.broadcast_to(np.asarray(rgb, dtype=np.float64), vertices.shape)
    sign = _facing_sign(vertices, triangles)
    if sign:
        # Hidden back faces would otherwise compete in the depth sort and poke through at edges.
        normals = _triangle_normals(vertices, triangles)
        toward_eye = camera.eye - vertices[triangles].mean(axis=1)
        triangles = triangles[sign * np.einsum("ij,ij->i", normals, toward_eye) > 0]
    if shading == "flat":
        brightness = np.repeat(_lambert(_unit(_triangle_normals(vertices, triangles)), camera, ambient)[:, None], 3, axis=1)
    else:
        brightness = _lambert(vertex_normals(vertices, triangles), camera, ambient)[triangles]
    corner_rgb = vertex_rgb[triangles] * brightness[:, :, None]
    corners, corner_rgb = _split_long_faces(vertices[triangles], corner_rgb, split_limit, 2 * MAX_MATPLOTLIB_FACES)

    cam = camera.to_camera(corners.reshape(-1, 3)).reshape(-1, 3, 3)
    depth = cam[:, :, 2]
    # A fitted camera has every face in front of it; the guard only protects the division.
    front = (depth > 1e-12).all(axis=1)
    cam, depth, corner_rgb = cam[front], depth[front], corner_rgb[front]
    order = np.argsort(-depth.mean(axis=1), kind="stable")  # far first: painter's algorithm
    polygons = (cam[:, :, :2] / depth[:, :, None])[order]
    colors = np.clip(corner_rgb.mean(axis=1), 0.0, 1.0)[order]

    # Polygons are drawn unantialiased (antialiased neighbours leave light seams), so the panel is
    # drawn at SUPERSAMPLE times the size and averaged down, which smooths the staircase edges.
    figure = Figure(figsize=(camera.width / 100.0, camera.height / 100.0), dpi=100 * SUPERSAMPLE, facecolor="white")
    canvas = FigureCanvasAgg(figure)
    axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
    axes.set_axis_off()
    axes.set_xlim(-camera.tan_x, camera.tan_x)
    axes.set_ylim(-camera.tan_y, camera.tan_y)
    # Edges in the face colour close the hairline cracks Agg leaves between abutting polygons.
    axes.add_collection(PolyCollection(polygons, facecolors=colors, edgecolors=colors, linewidths=0.3, antialiaseds=False))
    canvas.draw()
    image = np.asarray(canvas.buffer_rgba())[:, :, :3].astype(np.float64)
    image = image.reshape(camera.height, SUPERSAMPLE, camera.width, SUPERSAMPLE, 3).mean(axis=(1, 3))
    return np.rint(image).astype(np.uint8)


# --------------------------------------------------------------------------- open3d backend

# Run as ``python -c _CHILD job.npz out.npy``: one fresh renderer, one frame, then exit, so a stall
# or an abort costs only the child. (Reusing a renderer, or a second one in the same process, made
# stalls on llvmpipe far more likely, and two live renderers abort at exit.)
# With the single argument "device" it only starts the engine, which prints the device it chose.
_CHILD = """
import sys
import numpy as np
import open3d as o3d

rendering = o3d.visualization.rendering
if sys.argv[1] == "device":
    renderer = rendering.OffscreenRenderer(16, 16)
    del renderer
    print("VORO3D-PANEL-DONE", flush=True)
    sys.exit(0)
job = dict(np.load(sys.argv[1]))
o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
width, height = (int(x) for x in job["size"])
renderer = rendering.OffscreenRenderer(width, height)
scene = renderer.scene
scene.set_background([1.0, 1.0, 1.0, 1.0])
scene.show_skybox(False)
scene.set_lighting(rendering.Open3DScene.LightingProfile.NO_SHADOWS, job["light"].astype(np.float32))
scene.view.set_sample_count(4)
mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(job["vertices"]),
                                 o3d.utility.Vector3iVector(job["triangles"]))
mesh.vertex_normals = o3d.utility.Vector3dVector(job["normals"])
material = rendering.MaterialRecord()
material.shader = "defaultLit"
if "colors" in job:
    mesh.vertex_colors = o3d.utility.Vector3dVector(job["colors"])
    material.base_color = [1.0, 1.0, 1.0, 1.0]
else:
    material.base_color = [*job["base_color"].tolist(), 1.0]
material.base_roughness = 0.7
material.base_reflectance = 0.3
scene.add_geometry("mesh", mesh, material)
renderer.setup_camera(float(job["fov"]), job["center"].astype(np.float32), job["eye"].astype(np.float32),
                      job["up"].astype(np.float32))
image = np.asarray(renderer.render_to_image())[:, :, :3].copy()
scene.clear_geometry()  # geometry still attached when the engine goes away aborts the process
del scene, renderer
np.save(sys.argv[2], image)
print("VORO3D-PANEL-DONE", flush=True)
"""


class _Open3DFailed(RuntimeError):
    pass


def _child_environment() -> dict:
    env = dict(os.environ)
    if sys.platform.startswith("linux") and not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY")):
        # Headless builds that go through EGL need its surfaceless platform; Vulkan ignores it.
        env.setdefault("EGL_PLATFORM", "surfaceless")
    return env


def _run_child(arguments: list[str], timeout: float) -> str:
    """Run ``_CHILD`` with ``arguments``; return its output or raise ``_Open3DFailed``."""
    try:
        child = subprocess.run([sys.executable, "-c", _CHILD, *arguments], env=_child_environment(),
                               capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise _Open3DFailed(f"the Open3D renderer took longer than {timeout:.0f} s and was stopped") from None
    except OSError as error:
        raise _Open3DFailed(f"could not start the Open3D renderer: {error}") from None
    output = child.stdout + child.stderr
    if child.returncode != 0 or "VORO3D-PANEL-DONE" not in child.stdout:
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


# --------------------------------------------------------------------------- page layout


def _page(panels, titles, *, colorbar=None, dpi: int = 100):
    """A matplotlib Figure with ``panels`` side by side, ``titles`` above and an optional colour bar.

    ``colorbar`` is ``(ScalarMappable, label, extend)``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    height, width = panels[0].shape[:2]
    band = TITLE_BAND if any(titles) else 0
    bar = 110 if colorbar is not None else 0
    total_w, total_h = width * len(panels) + bar, height + band
    figure = Figure(figsize=(total_w / dpi, total_h / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(figure)
    for i, (panel, title) in enumerate(zip(panels, titles)):
        axes = figure.add_axes((i * width / total_w, 0.0, width / total_w, height / total_h))
        axes.imshow(panel, interpolation="nearest", aspect="auto")
        axes.set_axis_off()
        if title:
            figure.text((i + 0.5) * width / total_w, (height + band / 2) / total_h, title, ha="center", va="center",
                        fontsize=13, clip_on=True)
    if colorbar is not None:
        mappable, label, extend = colorbar
        axes = figure.add_axes(((width * len(panels) + 18) / total_w, 0.12 * height / total_h, 18 / total_w, 0.76 * height / total_h))
        figure.colorbar(mappable, cax=axes, label=label, extend=extend)
    return figure


def _save(figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=figure.dpi, facecolor="white")
    return path


# --------------------------------------------------------------------------- public API


def render_meshes(meshes, path, *, titles=None, colors=None, size=(640, 480), view=None, up="z",
                  shading="flat", backend="auto") -> Path:
    """Draw meshes side by side, seen by one camera, into a PNG file.

    Parameters
    ----------
    meshes : open3d.geometry.TriangleMesh or list of them
        Also ``open3d.t.geometry.TriangleMesh`` or ``(vertices, triangles)`` tuples. Each needs at
        least one triangle. Coordinates in any unit: the camera fits the union of the bounding
        boxes, so panels share scale and can be compared directly.
    path : str or os.PathLike
        Output file, ending in ``.png``; written atomically (a temporary file beside it, renamed).
    titles : list of str, optional
        One per mesh, drawn above its panel.
    colors : list of colour, optional
        One matplotlib colour per mesh (``"tab:orange"``, ``"#88aacc"``, ``(r, g, b)`` in [0, 1]);
        default a light blue for all.
    size : (int, int)
        ``(width, height)`` of each panel in pixels; the picture is ``len(meshes)`` panels wide
        plus a title band.
    view : str or (float, float), optional
        ``"iso"`` (default, a 3/4 view from the front right, above), ``"front"``, ``"side"``,
        ``"top"``, or ``(azimuth, elevation)`` in degrees.
    up : {"z", "y", "x"}
        World axis drawn pointing up.
    shading : {"flat", "smooth"}
        ``"flat"`` lights each triangle by its own normal, which shows the facets of a VoroMesh;
        ``"smooth"`` interpolates vertex normals.
    backend : {"auto", "open3d", "matplotlib"}
        See the module docstring. ``"open3d"`` raises ``RuntimeError`` where it does not work.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        No meshes, a mesh without triangles, or a bad option (the message names it).
    """
    arrays = _meshes_arg(meshes)
    path = _png_path(path)
    width, height = _size_arg(size)
    titles = [""] * len(arrays) if titles is None else [str(t) for t in _per_mesh(titles, "titles", len(arrays))]
    colors = [DEFAULT_COLOR] * len(arrays) if colors is None else _per_mesh(colors, "colors", len(arrays))
    rgb = [_rgb(c, f"colors[{i}]") for i, c in enumerate(colors)]
    _view_arg(view)
    _choice(up, "up", UP_AXES)
    _choice(shading, "shading", SHADINGS)

    points = _fit_points(arrays)
    camera = _fit_camera(points, view, up, width, height)
    chosen = _resolve_backend(backend)
    panels = None
    if chosen == "open3d":
        jobs = [_panel_job(v, t, camera, shading=shading, base_rgb=c) for (v, t), c in zip(arrays, rgb)]
        panels = _open3d_panels(jobs, required=backend == "open3d")
    if panels is None:
        split_limit = SPLIT_FRACTION * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        panels = []
        for (vertices, triangles), color in zip(arrays, rgb):
            vertices, triangles = _decimate(vertices, triangles, MAX_MATPLOTLIB_FACES)
            panels.append(_matplotlib_panel(vertices, triangles, camera, rgb=color, shading=shading, split_limit=split_limit))
    return _save(_page(panels, titles), path)


def render_error_map(mesh, reference, path, *, vmax=None, cmap="viridis", title=None, size=(640, 480), view=None,
                     up="z", shading="flat", backend="auto") -> Path:
    """Colour ``mesh`` by each vertex's distance to ``reference`` and write a PNG with a colour bar.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh
        The mesh to colour (for instance a reconstruction). Also ``open3d.t`` meshes or
        ``(vertices, triangles)``.
    reference : open3d.geometry.TriangleMesh
        The surface distances are measured to (for instance the ground truth); same kinds.
    path : str or os.PathLike
        Output file ending in ``.png``, written atomically.
    vmax : float, optional
        Distance drawn in the top colour, in mesh units; larger distances saturate (the colour bar
        then ends in an arrow). Default: the largest distance, so nothing saturates. Pass the same
        value to make several maps comparable.
    cmap : str
        Matplotlib colour map name.
    title : str, optional
        Text above the picture; default the mean and largest distance.
    size, view, up, shading, backend
        As in :func:`render_meshes`. The camera fits ``mesh`` alone.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        ``mesh`` or ``reference`` without triangles, ``vmax`` not finite and > 0, or a bad option.
    """
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    from .sampling import InsideOutside

    vertices, triangles = mesh_arrays(mesh, "mesh")
    ref_vertices, ref_triangles = mesh_arrays(reference, "reference")
    path = _png_path(path)
    width, height = _size_arg(size)
    _view_arg(view)
    _choice(up, "up", UP_AXES)
    _choice(shading, "shading", SHADINGS)
    if vmax is not None:
        if isinstance(vmax, bool) or not isinstance(vmax, (int, float, np.integer, np.floating)) or not (math.isfinite(vmax) and vmax > 0):
            raise ValueError(f"vmax must be a finite number > 0, got {vmax!r}")
        vmax = float(vmax)
    try:
        colormap = matplotlib.colormaps[cmap]
    except (KeyError, TypeError):
        raise ValueError(f"cmap must be a matplotlib colour map name, got {cmap!r}") from None

    # allow_open: only distances are asked, which need no inside.
    to_reference = InsideOutside((ref_vertices, ref_triangles), allow_open=True)
    distances = to_reference.unsigned_distance(vertices)
    largest = float(distances.max())
    if vmax is None:
        # An exact match has no scale of its own; borrow one from the mesh's size.
        diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
        vmax = largest if largest > 0 else max(1e-6 * diagonal, 1e-12)
    norm = Normalize(0.0, vmax, clip=True)

    points = _fit_points([(vertices, triangles)])
    camera = _fit_camera(points, view, up, width, height)
    chosen = _resolve_backend(backend)
    panel = None
    if chosen == "open3d":
        job = _panel_job(vertices, triangles, camera, shading=shading, vertex_rgb=colormap(norm(distances))[:, :3])
        panels = _open3d_panels([job], required=backend == "open3d")
        panel = None if panels is None else panels[0]
    if panel is None:
        small_vertices, small_triangles = _decimate(vertices, triangles, MAX_MATPLOTLIB_FACES)
        small_distances = distances if small_vertices is vertices else to_reference.unsigned_distance(small_vertices)
        panel = _matplotlib_panel(small_vertices, small_triangles, camera, rgb=colormap(norm(small_distances))[:, :3],
                                  shading=shading, ambient=0.5, split_limit=SPLIT_FRACTION * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))))

    if title is None:
        title = f"distance to reference: mean {distances.mean():.3g}, max {largest:.3g}"
    mappable = ScalarMappable(norm=Normalize(0.0, vmax), cmap=colormap)
    extend = "max" if largest > vmax else "neither"
    figure = _page([panel], [str(title)], colorbar=(mappable, "unsigned distance (mesh units)", extend))
    return _save(figure, path)


def _has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def show(meshes, *, colors=None) -> None:
    """Open an interactive Open3D window with the meshes laid out left to right.

    Parameters
    ----------
    meshes : open3d.geometry.TriangleMesh or list of them
        As in :func:`render_meshes`; copies are shown, the inputs are not modified.
    colors : list of colour, optional
        One matplotlib colour per mesh.

    Raises
    ------
    RuntimeError
        There is no display (neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set on Linux);
        use :func:`render_meshes` to write a picture instead.
    ValueError
        As in :func:`render_meshes`.
    """
    arrays = _meshes_arg(meshes)
    colors = [DEFAULT_COLOR] * len(arrays) if colors is None else _per_mesh(colors, "colors", len(arrays))
    rgb = [_rgb(c, f"colors[{i}]") for i, c in enumerate(colors)]
    if not _has_display():
        raise RuntimeError("show needs a display and none is set (DISPLAY / WAYLAND_DISPLAY); "
                           "use voro3d.render.render_meshes to write a PNG instead")
    import open3d as o3d

    step = 1.2 * max(float(np.ptp(v[:, 0])) for v, _ in arrays)
    geometries = []
    for i, ((vertices, triangles), color) in enumerate(zip(arrays, rgb)):
        mesh = to_triangle_mesh(vertices + [i * step, 0.0, 0.0], triangles)
        mesh.compute_vertex_normals()
        mesh.paint_uniform_color(color)
        geometries.append(mesh)
    o3d.visualization.draw_geometries(geometries, window_name="voro3d")
