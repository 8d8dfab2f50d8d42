"""The matplotlib backend, a painter's-algorithm renderer, and the page every picture is laid out on."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..geometry import face_area_vectors as _triangle_normals, vertex_normals
from ..io import atomic_path, to_triangle_mesh
from .camera import MAX_MATPLOTLIB_FACES, SUPERSAMPLE, TITLE_BAND, TITLE_FILL, TITLE_SIZE, _Camera, _lambert, _unit

__all__: list[str] = []

# -- matplotlib backend


def _decimate(vertices: np.ndarray, triangles: np.ndarray, limit: int, colors=None):
    """At most about ``limit`` faces: quadric decimation, after a cheap first cut on huge meshes.

    Returns vertices, triangles and the vertex ``colors`` ((v, 3), carried along; None stays None).
    """
    if len(triangles) <= limit:
        return vertices, triangles, colors
    import open3d as o3d

    mesh = to_triangle_mesh(vertices, triangles)
    if colors is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(colors)
    if len(triangles) > 4 * limit:
        # Quadric decimation takes seconds per few hundred thousand faces; vertex clustering is ten
        # times faster. Cells of this size leave about twice the budget on a smooth surface.
        area = float(np.linalg.norm(_triangle_normals(vertices, triangles), axis=1).sum()) / 2.0
        clustered = mesh.simplify_vertex_clustering(voxel_size=math.sqrt(area / limit))
        if len(clustered.triangles) >= limit:
            mesh = clustered
    simple = mesh.simplify_quadric_decimation(target_number_of_triangles=limit)
    return (np.asarray(simple.vertices), np.asarray(simple.triangles),
            np.asarray(simple.vertex_colors) if colors is not None else None)


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


# -- page layout


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
            text = figure.text((i + 0.5) * width / total_w, (height + band / 2) / total_h, title, ha="center",
                               va="center", fontsize=TITLE_SIZE, clip_on=True)
            # A title wider than its panel is set smaller, not cut at the panel's edges (measured
            # again each time: small type is wider than its size says).
            renderer = figure.canvas.get_renderer()
            for _ in range(4):
                wide = text.get_window_extent(renderer=renderer).width
                if wide <= TITLE_FILL * width:
                    break
                text.set_fontsize(text.get_fontsize() * 0.97 * TITLE_FILL * width / wide)
    if colorbar is not None:
        mappable, label, extend = colorbar
        axes = figure.add_axes(((width * len(panels) + 18) / total_w, 0.12 * height / total_h, 18 / total_w, 0.76 * height / total_h))
        figure.colorbar(mappable, cax=axes, label=label, extend=extend)
    return figure


def _save(figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=figure.dpi, facecolor="white")
    return path
