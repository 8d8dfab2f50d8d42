"""The public pictures: side-by-side panels, distance-error maps, and an interactive window."""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from ..io import mesh_arrays, to_triangle_mesh
from .camera import (DEFAULT_COLOR, MAX_MATPLOTLIB_FACES, SHADINGS, SPLIT_FRACTION, UP_AXES, _choice, _fit_camera,
                     _fit_points, _meshes_arg, _per_mesh, _png_path, _rgb, _size_arg, _view_arg)
from .open3d_backend import _open3d_panels, _panel_job, _resolve_backend
from .painter import _decimate, _matplotlib_panel, _page, _save

__all__ = ["render_error_map", "render_meshes", "show"]


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
        default each mesh's own vertex colours where it has them (a coloured cloud's
        reconstruction), else a light blue.
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
    vertex_rgb = _vertex_colors(meshes, arrays) if colors is None else [None] * len(arrays)
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
        jobs = [_panel_job(v, t, camera, shading=shading, base_rgb=c, vertex_rgb=own)
                for (v, t), c, own in zip(arrays, rgb, vertex_rgb)]
        panels = _open3d_panels(jobs, required=backend == "open3d")
    if panels is None:
        split_limit = SPLIT_FRACTION * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        panels = []
        for (vertices, triangles), color, own in zip(arrays, rgb, vertex_rgb):
            vertices, triangles, own = _decimate(vertices, triangles, MAX_MATPLOTLIB_FACES, own)
            panels.append(_matplotlib_panel(vertices, triangles, camera, rgb=color if own is None else own,
                                            shading=shading, split_limit=split_limit))
    return _save(_page(panels, titles), path)


def _vertex_colors(meshes, arrays) -> list:
    """Each mesh's own vertex colours, ``(v, 3)`` in [0, 1], where it has them; else None.

    All-black colours are none: Open3D fills them so where its input had no colours (Poisson's mesh of an
    uncoloured cloud), and drawn they would hide the shape in a black silhouette.
    """
    if hasattr(meshes, "triangles") or hasattr(meshes, "triangle"):  # one mesh, as _meshes_arg reads it
        meshes = [meshes]
    found = []
    for mesh, (vertices, _) in zip(meshes, arrays):
        rgb = None
        if hasattr(mesh, "has_vertex_colors") and mesh.has_vertex_colors():
            rgb = np.asarray(mesh.vertex_colors, np.float64)
        elif hasattr(mesh, "vertex") and "colors" in mesh.vertex:
            rgb = mesh.vertex.colors.numpy().astype(np.float64)
        if rgb is None or rgb.shape != vertices.shape or not rgb.any():
            found.append(None)
        else:
            found.append(np.clip(rgb, 0.0, 1.0))
    return found


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

    from ..queries import InsideOutside

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
        small_vertices, small_triangles, _ = _decimate(vertices, triangles, MAX_MATPLOTLIB_FACES)
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
