"""Clouds sampled along scan lines far apart for their spacing along them (a LiDAR's): thinned along
the lines (plan thin), whose nearest neighbours otherwise all lie on their own line."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from voro3d.metrics import evaluate
from voro3d.pointcloud import cloud_mesh, reconstruct_points
from voro3d.pointcloud.scanlines import line_ratio, thin_lines
from voro3d.pointcloud.tuning import LINE_RATIO
from voro3d.sampling import sample_surface
from voro3d.shapes import example_mesh

R, TUBE = 1 / 1.35, 0.35 / 1.35  # the example torus's radii (major 1, minor 0.35, scaled to a unit box)


def _rings(rings=16, along=300):
    """A torus scanned in rings of constant tube angle: 300 points a ring, rings 6x as far apart."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, along, endpoint=False), np.linspace(0, 2 * np.pi, rings, endpoint=False))
    u, v = u.ravel() + 0.01 * v.ravel(), v.ravel()
    points = np.c_[(R + TUBE * np.cos(v)) * np.cos(u), (R + TUBE * np.cos(v)) * np.sin(u), TUBE * np.sin(v)]
    normals = np.c_[np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)]
    return points, normals


def test_line_ratio_tells_scan_lines_from_an_even_sampling():
    lines = _rings()[0]
    even = sample_surface(example_mesh("torus"), len(lines), seed=0)[0]
    assert line_ratio(lines, cKDTree(lines))[0] < 0.02 < 0.4 < line_ratio(even, cKDTree(even))[0]


def test_line_ratio_reads_noisy_lines_over_wider_neighbourhoods(monkeypatch):
    """Rings 26 steps apart with noise as wide as a step: the 9 nearest points spread across their
    ring (0.15 over them alone), the 25 nearest still lie along it."""
    import voro3d.pointcloud.scanlines as scanlines

    points = _rings(8, 600)[0] + 0.008 * np.random.default_rng(0).normal(size=(4800, 3))
    assert line_ratio(points, cKDTree(points))[0] < 0.05
    monkeypatch.setattr(scanlines, "NOISE_NEIGHBOURS", scanlines.SPACING_NEIGHBOURS)
    assert line_ratio(points, cKDTree(points))[0] > LINE_RATIO


def test_thinning_stops_once_the_neighbourhoods_are_two_dimensional():
    points, normals = _rings()
    thinned, averaged, rounds = thin_lines(points, normals, tree=cKDTree(points))
    assert rounds >= 1 and len(thinned) < 0.6 * len(points)
    assert line_ratio(thinned, cKDTree(thinned))[0] >= LINE_RATIO
    # Each point is the mean of the points it stands for: on the torus within a sag of its rings' chord.
    distance = np.abs(np.hypot(np.hypot(thinned[:, 0], thinned[:, 1]) - R, thinned[:, 2]) - TUBE)
    assert distance.max() < 0.01
    assert np.all(np.einsum("ij,ij->i", averaged, thinned - _on_axis(thinned)) > 0)  # outward, averaged alike
    even = sample_surface(example_mesh("torus"), 4000, seed=0)[0]
    same = thin_lines(even, None, tree=cKDTree(even))
    assert same[0] is even and same[2] == 0
    forced = thin_lines(even, None, tree=cKDTree(even), force=True)  # plan thin "on": one round at least
    assert forced[2] == 1 and len(forced[0]) < len(even)
    assert thin_lines(points, tree=cKDTree(points), min_points=len(points))[-1] == 0  # never under min_points


def _on_axis(points):
    """The nearest points of the torus's core circle."""
    radial = points[:, :2] / np.linalg.norm(points[:, :2], axis=1, keepdims=True)
    return np.c_[R * radial, np.zeros(len(points))]


@pytest.mark.parametrize("given", [False, True])
def test_a_cloud_on_scan_lines_is_thinned_and_comes_out_whole(given):
    """Unthinned, the plane fits turn about the rings and the surface comes apart along them."""
    points, normals = _rings()
    truth = example_mesh("torus")
    scores = {}
    for thin in ("auto", "off"):
        shape, target, info = reconstruct_points(points, normals if given else None, grid=32, steps=60,
                                                 plan={"thin": thin})
        scores[thin] = evaluate(cloud_mesh(shape, target), truth, n_samples=20000)
        assert info.plan.thin == ("on" if thin == "auto" else "off")
    assert scores["auto"]["nc"] > 0.97 and scores["auto"]["chamfer_x1e5"] < 20
    if not given:  # (given normals hold the surface together as it is)
        assert scores["auto"]["nc"] > scores["off"]["nc"] + 0.02
