"""What every picture shares: the arguments it takes, its perspective camera and its lights.

Both backends (:mod:`voro3d.render.painter`, :mod:`voro3d.render.open3d_backend`) draw with the
camera :func:`_fit_camera` places around all the meshes of one picture.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import mesh_arrays

__all__ = ["BACKENDS", "DEFAULT_COLOR", "FIELD_OF_VIEW", "MARGIN", "MAX_MATPLOTLIB_FACES", "SHADINGS",
           "SPLIT_FRACTION", "SUPERSAMPLE", "TITLE_BAND", "TITLE_FILL", "TITLE_SIZE", "UP_AXES", "VIEWS"]

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
TITLE_SIZE = 13  # points; a title wider than TITLE_FILL of its panel is set smaller to fit
TITLE_FILL = 0.96


# -- validation


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


# -- camera


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


# -- shading helpers




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
