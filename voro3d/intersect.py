"""Exact triangle-triangle intersection, to confirm what a floating-point test reports.

Open3D's self-intersection test is floating point: near-touching triangles (a Voronoi edge
of 1e-5 beside a face) come back as intersecting. Candidates are confirmed here with rational
arithmetic; a cheap float filter with an error bound settles most of them first.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np

# Relative error bound of a float64 3x3 determinant of coordinate differences (generous).
_ORIENT_BOUND = 1e-12


def confirm_intersections(vertices: np.ndarray, triangles: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Keep the triangle pairs that intersect exactly (closed triangles, touching counts).

    Parameters
    ----------
    vertices : (n, 3) float64
    triangles : (f, 3) int
    pairs : (p, 2) int
        Candidate pairs, e.g. from ``TriangleMesh.get_self_intersecting_triangles``.

    Returns
    -------
    (q, 2) int64, the pairs that intersect.
    """
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return pairs
    a = vertices[triangles[pairs[:, 0]]]
    b = vertices[triangles[pairs[:, 1]]]
    undecided = ~(_separated_by_plane(a, b) | _separated_by_plane(b, a))
    keep = [i for i in np.flatnonzero(undecided) if _triangles_intersect(a[i], b[i])]
    return pairs[np.asarray(keep, np.int64)]


def _separated_by_plane(a, b):
    """True where every vertex of ``b`` is certainly on one side of ``a``'s plane."""
    u, v = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
    normal = np.cross(u, v)
    scale = np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1)
    side = np.einsum("ij,ikj->ik", normal, b - a[:, None, 0])
    bound = _ORIENT_BOUND * scale[:, None] * np.linalg.norm(b - a[:, None, 0], axis=2) + 1e-300
    positive = (side > bound).all(axis=1)
    negative = (side < -bound).all(axis=1)
    return positive | negative


def _exact(point):
    return tuple(Fraction(float(x)) for x in point)


def _orient3d(a, b, c, d):
    ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    vx, vy, vz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    wx, wy, wz = d[0] - a[0], d[1] - a[1], d[2] - a[2]
    return ux * (vy * wz - vz * wy) - uy * (vx * wz - vz * wx) + uz * (vx * wy - vy * wx)


def _orient2d(a, b, c):
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _sign(x):
    return (x > 0) - (x < 0)


def _triangles_intersect(a, b) -> bool:
    a = [_exact(p) for p in a]
    b = [_exact(p) for p in b]
    return any(_segment_meets_triangle(a[i], a[(i + 1) % 3], b) for i in range(3)) or any(
        _segment_meets_triangle(b[i], b[(i + 1) % 3], a) for i in range(3)
    )


def _segment_meets_triangle(p, q, tri) -> bool:
    s1, s2 = _sign(_orient3d(*tri, p)), _sign(_orient3d(*tri, q))
    if s1 * s2 > 0:
        return False
    if s1 == 0 and s2 == 0:
        return _coplanar_segment_meets_triangle(p, q, tri)
    signs = {_sign(_orient3d(p, q, tri[i], tri[(i + 1) % 3])) for i in range(3)}
    return not ({1, -1} <= signs)


def _coplanar_segment_meets_triangle(p, q, tri) -> bool:
    u = [tri[1][i] - tri[0][i] for i in range(3)]
    v = [tri[2][i] - tri[0][i] for i in range(3)]
    normal = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    if not any(normal):  # a degenerate triangle: test against its edges as segments
        return any(_segments_meet_3d(p, q, tri[i], tri[(i + 1) % 3]) for i in range(3))
    drop = max(range(3), key=lambda i: abs(normal[i]))
    keep = [i for i in range(3) if i != drop]
    p2, q2 = [p[i] for i in keep], [q[i] for i in keep]
    t2 = [[t[i] for i in keep] for t in tri]
    if _point_in_triangle_2d(p2, t2) or _point_in_triangle_2d(q2, t2):
        return True
    return any(_segments_meet_2d(p2, q2, t2[i], t2[(i + 1) % 3]) for i in range(3))


def _point_in_triangle_2d(p, t) -> bool:
    signs = {_sign(_orient2d(t[i], t[(i + 1) % 3], p)) for i in range(3)}
    return not ({1, -1} <= signs)


def _segments_meet_2d(p, q, r, s) -> bool:
    d1, d2 = _sign(_orient2d(r, s, p)), _sign(_orient2d(r, s, q))
    d3, d4 = _sign(_orient2d(p, q, r)), _sign(_orient2d(p, q, s))
    if d1 * d2 < 0 and d3 * d4 < 0:
        return True

    def on(a, b, c):  # c on segment ab, given collinear
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    return (d1 == 0 and on(r, s, p)) or (d2 == 0 and on(r, s, q)) or (d3 == 0 and on(p, q, r)) or (
        d4 == 0 and on(p, q, s))


def _segments_meet_3d(p, q, r, s) -> bool:
    if _orient3d(p, q, r, s) != 0:
        return False
    for drop in range(3):
        keep = [i for i in range(3) if i != drop]
        project = lambda x: [x[i] for i in keep]  # noqa: E731
        if _segments_meet_2d(project(p), project(q), project(r), project(s)) is False:
            return False
    return True
