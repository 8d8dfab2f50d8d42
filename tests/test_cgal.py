"""The compiled extension voro3d._cgal: its answers, every input check, and the GIL released around CGAL."""

import numpy as np
import pytest

from voro3d import _cgal

RNG = np.random.default_rng(0)
POINTS = RNG.random((30, 3))


def test_delaunay_of_a_cube_and_its_cospherical_cells():
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    tets, cospherical = _cgal.delaunay_tetrahedra(corners)
    a, b, c, d = (corners[tets[:, i]] for i in range(4))
    volumes = np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6
    assert (volumes > 0).all() and volumes.sum() == pytest.approx(1.0)
    # All eight corners lie on one sphere: every face-adjacent pair of cells shares it.
    assert len(cospherical) > 0 and set(np.unique(cospherical)) == set(range(len(tets)))


def test_exact_circumcenters_are_equidistant():
    tets, _ = _cgal.delaunay_tetrahedra(POINTS)
    centres = _cgal.exact_circumcenters(POINTS, tets)
    distances = np.linalg.norm(POINTS[tets] - centres[:, None, :], axis=2)
    np.testing.assert_allclose(distances, distances[:, :1].repeat(4, axis=1), rtol=1e-9)


def rational_circumcenter(corners):
    """The circumcentre of four float corners in exact rational arithmetic."""
    from fractions import Fraction

    a, *others = [[Fraction(float(x)) for x in corner] for corner in corners]
    u, v, w = ([p[k] - a[k] for k in range(3)] for p in others)

    def cross(x, y):
        return [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]

    def dot(x, y):
        return sum(p * q for p, q in zip(x, y))

    vw, wu, uv = cross(v, w), cross(w, u), cross(u, v)
    det = dot(u, vw)
    return [a[k] + (dot(u, u) * vw[k] + dot(v, v) * wu[k] + dot(w, w) * uv[k]) / (2 * det) for k in range(3)]


def clustered_points():
    """Clusters of three generators 1e-6 apart among spread ones: the test suite's case whose
    thin cells' faces crossed while their vertices were 1e-11 off."""
    rng = np.random.default_rng(106764551)
    base = rng.uniform(-1, 1, (98, 3))
    source = np.repeat(np.arange(32), 3)
    return np.vstack([base, base[source] + rng.normal(size=(source.size, 3)) * 1e-6])


def test_exact_circumcenters_are_the_rational_ones_rounded():
    points = clustered_points()
    tets, _ = _cgal.delaunay_tetrahedra(points)
    # Tetrahedra with a cluster edge are the ill-conditioned ones.
    edges = np.linalg.norm(points[tets][:, :, None] - points[tets][:, None], axis=3)
    picked = tets[np.flatnonzero((edges + np.eye(4) > 1e-5).sum(axis=(1, 2)) < 12)[:20]]
    assert len(picked) == 20
    centres = _cgal.exact_circumcenters(points, picked)
    for corners, centre in zip(points[picked], centres):
        exact = rational_circumcenter(corners)
        assert all(abs(centre[k] - float(exact[k])) <= np.spacing(abs(float(exact[k]))) for k in range(3))


def test_circumcenters_of_clustered_generators_are_accurate():
    from voro3d.delaunay import circumcenters

    points = clustered_points()
    tets, _ = _cgal.delaunay_tetrahedra(points)
    centres = circumcenters(points, tets)
    exact = _cgal.exact_circumcenters(points, tets)
    assert np.abs(centres - exact).max() <= 1e-14 * np.ptp(points, axis=0).max()


def test_circumcenters_far_from_the_origin_stay_on_the_float_path(monkeypatch):
    # Survey coordinates: a 64 m object 5e6 m out. Rounding a centre there costs eps |centre| on either path,
    # so it must not send more tetrahedra down the exact one than at the origin (it sent all: reconstruct 7.3 -> 5.1 s).
    import voro3d.delaunay as delaunay

    sent, original = [], _cgal.exact_circumcenters
    monkeypatch.setattr(_cgal, "exact_circumcenters", lambda p, t: sent.append(len(t)) or original(p, t))
    near = 64.0 * POINTS
    far = np.array([512345.0, 5412345.0, 250.0]) + near
    tets, _ = _cgal.delaunay_tetrahedra(far)
    delaunay.circumcenters(near, tets)
    at_origin, sent[:] = sum(sent), []
    centres = delaunay.circumcenters(far, tets)
    assert sum(sent) <= at_origin < len(tets) // 2
    exact = original(far, tets)
    assert np.abs(centres - exact).max() <= 1e-14 * np.ptp(far, axis=0).max() + 2 * np.spacing(np.abs(exact).max())


@pytest.mark.parametrize("points, error, match", [
    (np.zeros((5, 2)), ValueError, r"points must have shape \(n, 3\), got \(5, 2\)"),
    (np.zeros(3), ValueError, r"points must have shape \(n, 3\), got \(3,\)"),
    (POINTS[:3], ValueError, "points must hold at least 4 points, got 3"),
    (np.vstack([POINTS, [[0.5, np.nan, 0.5]]]), ValueError, "points holds NaN or inf at row 30"),
    (np.vstack([POINTS, [[np.inf, 0, 0]]]), ValueError, "points holds NaN or inf at row 30"),
    (np.c_[POINTS[:, :2], np.zeros(30)], ValueError, "points are coplanar"),
    (np.outer(np.arange(6), [1.0, 2.0, 3.0]), ValueError, "points are collinear"),
    (np.ones((6, 3)), ValueError, "points all coincide"),
    (POINTS > 0.5, TypeError, "points must be a real-valued array, got dtype bool"),
    ("points", TypeError, "points must be a real-valued array, got dtype <U6"),
    ([[0, 0, 0], [1, 0]], TypeError, "points must be an array, got list"),
])
def test_delaunay_rejects_bad_points(points, error, match):
    with pytest.raises(error, match=match):
        _cgal.delaunay_tetrahedra(points)


@pytest.mark.parametrize("points, tets, error, match", [
    (POINTS, np.array([[0, 1, 2, 30]]), ValueError, r"tets holds index 30 at row 0, outside \[0, 30\)"),
    (POINTS, np.array([[0, 1, 2, 3], [0, -1, 2, 3]]), ValueError, r"tets holds index -1 at row 1, outside \[0, 30\)"),
    (POINTS, np.array([[0, 1, 2]]), ValueError, r"tets must have shape \(m, 4\), got \(1, 3\)"),
    (POINTS, np.array([[0.0, 1, 2, 3]]), TypeError, "tets must be an integer array of indices, got dtype float64"),
    (POINTS, np.array([[0, 1, 2, 2]]), ValueError, "tets row 0 is flat"),
    (np.c_[POINTS[:, :2], np.zeros(30)], np.array([[0, 1, 2, 3]]), ValueError, "tets row 0 is flat"),
    (POINTS[:, :2], np.array([[0, 1, 2, 3]]), ValueError, r"points must have shape \(n, 3\), got \(30, 2\)"),
    (np.where(np.eye(30, 3, dtype=bool), np.nan, POINTS), np.array([[0, 1, 2, 3]]), ValueError,
     "points holds NaN or inf at row 0"),
])
def test_exact_circumcenters_rejects_bad_input(points, tets, error, match):
    with pytest.raises(error, match=match):
        _cgal.exact_circumcenters(points, tets)


TRIANGLES = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])


def test_self_intersecting_pairs_are_sorted_and_skip_neighbours():
    # Triangle 2 pierces 0 and 1, which share vertex 1 by index (neighbours, never tested).
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 0, 0],
                         [0.6, 0.1, -1], [0.6, 0.1, 1], [1.2, 0.4, 0.0]], float)
    pairs = _cgal.self_intersecting_pairs(vertices, np.array([[0, 1, 2], [1, 4, 3], [5, 6, 7]]))
    assert pairs.dtype == np.int64 and pairs.tolist() == [[0, 2], [1, 2]]
    assert _cgal.self_intersecting_pairs(vertices, np.zeros((0, 3), int)).shape == (0, 2)


@pytest.mark.parametrize("seed", range(3))
def test_self_intersecting_pairs_in_parallel_are_the_serial_ones(seed):
    # 3000 small random triangles (over the 2048 from which the work is split over two threads),
    # some sharing vertices, and a slab of them with one lower x (all on one side of the split).
    rng = np.random.default_rng(seed)
    corners = rng.uniform(0, 1, (3000, 1, 3)) + rng.uniform(-0.04, 0.04, (3000, 3, 3))
    corners[:500, :, 0] = np.maximum(corners[:500, :, 0], 0.5)
    corners[:500, 0, 0] = 0.5
    vertices, triangles = corners.reshape(-1, 3), np.arange(9000).reshape(-1, 3)
    triangles[1::7, 0] = triangles[0::7, 1][:len(triangles[1::7])]
    serial = _cgal.self_intersecting_pairs(vertices, triangles, parallel=False)
    assert len(serial) > 100
    assert np.array_equal(_cgal.self_intersecting_pairs(vertices, triangles), serial)
    changed = rng.random(3000) < 0.3
    part = _cgal.self_intersecting_pairs(vertices, triangles, changed, parallel=False)
    assert np.array_equal(part, serial[changed[serial].any(axis=1)])
    assert np.array_equal(_cgal.self_intersecting_pairs(vertices, triangles, changed), part)


@pytest.mark.parametrize("vertices, triangles, error, match", [
    (POINTS, TRIANGLES + 22, ValueError, r"triangles holds index 30 at row 2, outside \[0, 30\) for the 30 rows of vertices"),
    (POINTS, -TRIANGLES, ValueError, r"triangles holds index -1 at row 0"),
    (POINTS, TRIANGLES[:, :2], ValueError, r"triangles must have shape \(t, 3\), got \(3, 2\)"),
    (POINTS, TRIANGLES.astype(float), TypeError, "triangles must be an integer array of indices, got dtype float64"),
    (POINTS[:, :2], TRIANGLES, ValueError, r"vertices must have shape \(n, 3\), got \(30, 2\)"),
    (np.where(np.arange(30)[:, None] == 7, np.inf, POINTS), TRIANGLES, ValueError, "vertices holds NaN or inf at row 7"),
    (None, TRIANGLES, TypeError, "vertices must be a real-valued array, got dtype object"),
])
def test_self_intersecting_pairs_rejects_bad_input(vertices, triangles, error, match):
    with pytest.raises(error, match=match):
        _cgal.self_intersecting_pairs(vertices, triangles)


def test_delaunay_releases_the_gil(gil_free):
    points = RNG.random((100_000, 3))
    elapsed, longest = gil_free(lambda: _cgal.delaunay_tetrahedra(points))
    assert elapsed > 0.2 and longest < 0.5 * elapsed, (longest, elapsed)
