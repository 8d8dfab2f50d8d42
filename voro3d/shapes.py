"""Example shapes built by the project itself: watertight, deterministic, nothing downloaded.

Every shape is centred on the origin, scaled so its largest half-extent is 1 (it fits the cube
``[-1, 1]^3``), has outward-facing triangles and at most 50k of them.
"""
from __future__ import annotations

import functools

import numpy as np

from .io import to_triangle_mesh

__all__ = ["example_mesh", "example_names"]


def _sphere() -> tuple[np.ndarray, np.ndarray]:
    """Icosphere of radius 1 (5120 triangles)."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces)


def _tube(curve: np.ndarray, radius: float, sides: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube of circular cross-section swept along the closed polyline ``curve`` ``(n, 3)``.

    Frames are parallel-transported along the curve; the twist they pick up over one loop (the
    holonomy) is spread evenly back out, so the last ring meets the first without a skewed seam.
    """
    n = len(curve)
    tangent = np.roll(curve, -1, axis=0) - np.roll(curve, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.empty_like(curve)
    seed = np.cross(tangent[0], [0.0, 0.0, 1.0])
    if np.linalg.norm(seed) < 1e-6:
        seed = np.cross(tangent[0], [1.0, 0.0, 0.0])
    normal[0] = seed / np.linalg.norm(seed)
    for i in range(1, n):
        projected = normal[i - 1] - tangent[i] * (normal[i - 1] @ tangent[i])
        normal[i] = projected / np.linalg.norm(projected)
    # Transport once more onto the first tangent to measure the twist accumulated around the loop.
    closing = normal[-1] - tangent[0] * (normal[-1] @ tangent[0])
    closing /= np.linalg.norm(closing)
    twist = np.arctan2(np.cross(closing, normal[0]) @ tangent[0], closing @ normal[0])
    binormal = np.cross(tangent, normal)
    angle = twist * np.arange(n) / n
    normal, binormal = (np.cos(angle)[:, None] * normal + np.sin(angle)[:, None] * binormal,
                        -np.sin(angle)[:, None] * normal + np.cos(angle)[:, None] * binormal)

    theta = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.cos(theta)[None, :, None] * normal[:, None, :] + np.sin(theta)[None, :, None] * binormal[:, None, :]
    vertices = (curve[:, None, :] + radius * ring).reshape(-1, 3)

    i, j = np.meshgrid(np.arange(n), np.arange(sides), indexing="ij")
    a = i * sides + j
    b = ((i + 1) % n) * sides + j
    c = ((i + 1) % n) * sides + (j + 1) % sides
    d = i * sides + (j + 1) % sides
    # Rings run anticlockwise about the tangent, so (a, c, b) faces away from the curve.
    triangles = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return vertices, triangles


def _torus() -> tuple[np.ndarray, np.ndarray]:
    """Ring torus, major radius 1, minor radius 0.35 (96 x 32 quads)."""
    t = 2.0 * np.pi * np.arange(96) / 96
    circle = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], axis=1)
    return _tube(circle, 0.35, 32)


def _knot() -> tuple[np.ndarray, np.ndarray]:
    """Trefoil knot tube (300 x 24 quads); the radius stays clear of the closest strands."""
    t = 2.0 * np.pi * np.arange(300) / 300
    curve = np.stack([np.sin(t) + 2.0 * np.sin(2.0 * t), np.cos(t) - 2.0 * np.cos(2.0 * t), -np.sin(3.0 * t)], axis=1)
    return _tube(curve, 0.45, 24)


def _from_manifold(solid) -> tuple[np.ndarray, np.ndarray]:
    if solid.status().name != "NoError" or solid.is_empty():
        raise RuntimeError(f"manifold3d failed to build an example shape: {solid.status()}")
    mesh = solid.to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _bracket() -> tuple[np.ndarray, np.ndarray]:
    """An L-shaped mounting bracket in millimetres: two plates, two ribs, three holes, a counterbore."""
    from manifold3d import CrossSection, Manifold, OpType

    segments = 48
    base = Manifold.cube([80.0, 50.0, 8.0])
    wall = Manifold.cube([8.0, 50.0, 60.0])
    # A right-triangle rib drawn in x-z, extruded 6 mm along y (rotate maps the sketch's y to z).
    rib_sketch = CrossSection([[[8.0, 0.0], [40.0, 0.0], [8.0, 32.0]]])
    rib = rib_sketch.extrude(6.0).rotate([90.0, 0.0, 0.0]).translate([0.0, 6.0, 8.0])
    ribs = rib.translate([0.0, 2.0, 0.0]) + rib.translate([0.0, 42.0, 0.0])
    body = Manifold.batch_boolean([base, wall, ribs], OpType.Add)

    floor_hole = Manifold.cylinder(20.0, 5.0, circular_segments=segments).translate([0.0, 0.0, -5.0])
    counterbore = Manifold.cylinder(4.0, 8.5, circular_segments=segments).translate([0.0, 0.0, 5.0])
    holes = [floor_hole.translate([60.0, 15.0, 0.0]), floor_hole.translate([60.0, 35.0, 0.0]),
             counterbore.translate([60.0, 15.0, 0.0]), counterbore.translate([60.0, 35.0, 0.0])]
    # A horizontal hole through the wall, along x.
    holes.append(Manifold.cylinder(20.0, 9.0, circular_segments=segments).rotate([0.0, 90.0, 0.0]).translate([-5.0, 25.0, 40.0]))
    return _from_manifold(body - Manifold.batch_boolean(holes, OpType.Add))


def _blob() -> tuple[np.ndarray, np.ndarray]:
    """An organic metaball blob: the smooth level set of five summed inverse-square fields."""
    from manifold3d import Manifold

    centres = np.array([[0.0, 0.0, 0.0], [0.9, 0.3, 0.1], [-0.7, 0.5, -0.2], [0.1, -0.8, 0.4], [0.2, 0.2, 0.9]])
    weights = np.array([0.55, 0.35, 0.4, 0.33, 0.3]) ** 2

    def field(x: float, y: float, z: float) -> float:
        squared = ((centres - (x, y, z)) ** 2).sum(axis=1)
        return float((weights / np.maximum(squared, 1e-12)).sum() - 1.0)

    return _from_manifold(Manifold.level_set(field, [-1.8, -1.8, -1.5, 1.8, 1.5, 1.8], 0.06))


_BUILDERS = {
    "sphere": _sphere,
    "torus": _torus,
    "bracket": _bracket,
    "knot": _knot,
    "blob": _blob,
}


def example_names() -> list[str]:
    """Names accepted by :func:`example_mesh`, in a fixed order."""
    return list(_BUILDERS)


@functools.lru_cache(maxsize=None)
def _normalised(name: str) -> tuple[np.ndarray, np.ndarray]:
    vertices, triangles = _BUILDERS[name]()
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - (low + high) / 2.0) / ((high - low).max() / 2.0)
    vertices.setflags(write=False)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    triangles.setflags(write=False)
    return vertices, triangles


def example_mesh(name: str = "bracket"):
    """A bundled watertight example shape.

    Parameters
    ----------
    name : str
        One of :func:`example_names`: ``"sphere"`` (icosphere, 5120 triangles), ``"torus"``,
        ``"bracket"`` (a CAD-like part: plates, ribs, through-holes, counterbores), ``"knot"``
        (trefoil tube) or ``"blob"`` (smooth metaballs).

    Returns
    -------
    open3d.geometry.TriangleMesh
        A new mesh on every call (safe to modify), centred on the origin with its largest
        half-extent equal to 1, outward-facing triangles, at most 50k triangles. Identical
        vertices and triangles on every call and every machine run.

    Raises
    ------
    ValueError
        ``name`` is not one of :func:`example_names`.
    """
    if not isinstance(name, str) or name not in _BUILDERS:
        raise ValueError(f"name must be one of {example_names()}, got {name!r}")
    vertices, triangles = _normalised(name)
    return to_triangle_mesh(vertices.copy(), triangles.copy())
