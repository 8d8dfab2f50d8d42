"""voro3d.pointcloud.hull: a target's solid is cut back to the points' convex hull."""
import numpy as np
import open3d as o3d
import pytest

from voro3d.pointcloud import cloud_mesh, reconstruct_points
from voro3d.pointcloud.hull import clip_to_hull, rim_facing
from voro3d.pointcloud.tuning import HULL_MARGIN_NODES
from voro3d.watertight import check_watertight


class Ball:
    """A closed target in the fit frame: the sphere of radius 0.6."""

    resolution = 64
    dense = False

    def __init__(self):
        mesh = o3d.geometry.TriangleMesh.create_sphere(radius=0.6, resolution=40)
        self.vertices, self.triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles, np.int64)

    def inside(self, queries):
        return np.linalg.norm(queries, axis=1) < 0.6

    def project(self, queries):
        return np.asarray(queries, np.float64)


def _cap(low: float, n: int = 20_000):
    """Points of the sphere of radius 0.6 above z = ``low``."""
    directions = np.random.default_rng(0).normal(size=(n, 3))
    points = 0.6 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return points[points[:, 2] > low]


def test_the_solid_past_the_hull_is_cut_away_and_the_rest_kept():
    ball, node = Ball(), 2.0 / 63
    margin = HULL_MARGIN_NODES * node
    clipped = clip_to_hull(ball, _cap(0.1), 64)
    assert clipped.carves == ["cut back to the points' hull"]
    probes = np.array([[0.0, 0.0, 0.4], [0.3, 0.0, 0.2], [0.0, 0.0, 0.1 - 0.5 * margin], [0.0, 0.0, 0.1 - 2 * margin],
                       [0.0, 0.0, -0.4], [0.0, 0.0, 0.7]])
    assert clipped.inside(probes).tolist() == [True, True, True, False, False, False]
    # The soup it is sampled from ends at the cut: none of it further out than the margin and the
    # Marching Cubes step.
    assert clipped.vertices[:, 2].min() > 0.1 - margin - 1.5 * node
    assert clipped.vertices[:, 2].max() == pytest.approx(ball.vertices[:, 2].max())


def test_a_slanted_cut_is_meshed_flat_where_the_hull_s_face_lies():
    # Marching Cubes over the carved nodes alone put a shallow cut in terraces a quarter node high.
    ball, node = Ball(), 2.0 / 63
    axis = np.array([1.0, 0.0, 4.0]) / np.sqrt(17.0)
    points = _cap(-1.0)
    points = points[points @ axis > 0.1]
    clipped = clip_to_hull(ball, points, 64)
    height = clipped.vertices @ axis - (0.1 - HULL_MARGIN_NODES * node)
    across = np.linalg.norm(clipped.vertices - np.outer(clipped.vertices @ axis, axis), axis=1)
    cut = (np.abs(height) < 2 * node) & (across < 0.4)
    assert cut.sum() > 100 and np.abs(height[cut]).max() < 0.05 * node


def test_a_target_within_the_hull_is_returned_as_it_is():
    ball = Ball()
    assert clip_to_hull(ball, ball.vertices * 1.001, 64) is ball


def _plate(n: int = 20_000, half: float = 0.6, wall: float = 0.03):
    """A plate seen from above: points on its top (z = 0) and on its sides down to z = -``wall``."""
    rng = np.random.default_rng(0)
    top = np.c_[rng.uniform(-half, half, (n, 2)), np.zeros(n)]
    along, depth, side = rng.uniform(-half, half, n // 8), rng.uniform(-wall, 0.0, n // 8), rng.integers(0, 4, n // 8)
    edge = np.where(side % 2 == 0, half, -half)
    sides = np.where((side < 2)[:, None], np.c_[along, edge, depth], np.c_[edge, along, depth])
    return np.vstack([top, sides])


@pytest.mark.parametrize("hull", ["auto", "off"])
def test_an_open_cloud_s_solid_ends_at_the_points_hull_unless_the_plan_says_off(hull):
    # One-sided: its solid behind the top is a guess, a shell's depth (SHELL_DEPTH) deep, three times the
    # seen sides; auto cuts it back to the hull, which the sides' lower edge bounds.
    points = _plate()
    shape, target, info = reconstruct_points(points, grid=48, steps=40, plan={"hull": hull})
    mesh = cloud_mesh(shape, target)
    check_watertight(mesh)
    assert info.level < 0.25 and info.plan.hull == ("on" if hull == "auto" else "off")
    below = (np.asarray(mesh.vertices)[:, 2].min() - points[:, 2].min()) / info.voxel
    assert below > -2.0 if hull == "auto" else below < -2.5


@pytest.mark.parametrize("hull", ["on", "auto"])
def test_with_the_plan_s_hull_a_closure_does_not_swell_past_the_points(hull):
    # A sphere seen down to z = -0.3 of its radius 0.6: Poisson's closure of the missing cap bulges
    # below the cut, past everything the points bound, unless the plan cuts it (auto, for a closed
    # cloud: it does not).
    points = _cap(-0.3, 12_000)
    shape, target, info = reconstruct_points(points, grid=32, steps=60, plan={"target": "poisson", "hull": hull})
    mesh = cloud_mesh(shape, target)
    check_watertight(mesh)
    assert info.plan.hull == ("on" if hull == "on" else "off")
    below = (np.asarray(mesh.vertices)[:, 2].min() - points[:, 2].min()) / info.voxel
    assert below > -1.5 if hull == "on" else below < -2.0


def test_the_report_says_what_the_hull_would_cut(capsys):
    # Printed only where the plan left the hull off and its cut would take something.
    cap, ball = _cap(-0.3, 12_000), _cap(-1.0, 12_000)
    for points, hull, said in ((cap, "auto", True), (cap, "on", False), (ball, "auto", False)):
        reconstruct_points(points, grid=32, steps=5, plan={"target": "poisson", "hull": hull}, progress=True)
        err = capsys.readouterr().err
        assert ("past the points' convex hull (plan hull on cuts it back" in err) is said, err
        assert ("and target imls with it closes it flat: scans from a few viewpoints" in err) is said, err


def test_a_dome_seen_from_above_is_solid_down_to_its_rim_not_a_shell_under_its_top():
    # The cut bounds an open cloud's solid, so no shell depth holds it: the solid fills the hull, a voxel
    # out (1.19 of the cap's volume; with the depth limit as well, 0.66: the measurement beside SHELL_DEPTH).
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(60_000, 3))
    points = (directions / np.linalg.norm(directions, axis=1, keepdims=True))
    points = points[points[:, 2] > 0.5][:20_000]  # a cap of a unit sphere, half a radius high
    shape, target, info = reconstruct_points(points, grid=48, steps=40)
    mesh = cloud_mesh(shape, target)
    check_watertight(mesh)
    assert info.level < 0.25 and info.plan.hull == "on"
    assert 0.85 < mesh.get_volume() / (np.pi * 0.5**2 * (3.0 - 0.5) / 3.0) < 1.3


def test_the_bounded_height_matches_every_plane_s_within_its_range():
    # A noisy flat scan is all hull; the bounded height must give every plane's answer where it matters.
    from voro3d.pointcloud.hull import _height, _height_within, _hull

    rng = np.random.default_rng(2)
    points = np.c_[rng.uniform(-0.8, 0.8, (3000, 2)), 0.002 * rng.normal(size=3000)]
    hull, scene = _hull(points)
    queries = rng.uniform(-1.0, 1.0, (20_000, 3)).astype(np.float32)
    exact = _height(queries, hull.equations)
    bounded = _height_within(queries, scene, hull.equations, 0.02, 0.05)
    within = (exact >= 0.02) & (exact <= 0.05)
    assert within.sum() > 100
    np.testing.assert_array_equal(bounded[within], exact[within])
    np.testing.assert_array_equal(bounded[~within] > 0.05, exact[~within] > 0.05)
    assert np.all((bounded[~within] < 0.02) | (bounded[~within] > 0.05))


def test_a_rim_where_the_surface_turned_away_reads_as_a_silhouette_and_one_where_it_stops_as_a_crop():
    cap = _cap(0.1)
    disc = np.c_[np.random.default_rng(1).uniform(-0.6, 0.6, (20_000, 2)), np.zeros(20_000)]
    disc = disc[np.linalg.norm(disc, axis=1) < 0.6]
    assert rim_facing(cap, cap / 0.6) < 0.3
    assert rim_facing(disc, np.tile([0.0, 0.0, -1.0], (len(disc), 1))) > 0.99


def _valley(n: int = 8000, seed: int = 0):
    """A shallow dish seen from above (a valley, z = 0.15 r^2 on [-1, 1]^2, with bumps): its rim is where the
    data ends."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1.0, 1.0, (n, 2))
    return np.c_[xy, 0.15 * (xy ** 2).sum(axis=1) + 0.03 * np.sin(6.0 * xy[:, 0])]


def test_a_valley_seen_from_above_is_not_filled_up_to_its_rim():
    # Its bending says its outside is below (a surface bends away from its outside), so the closure lies
    # above it; held by the hull alone it filled the valley up to the plane of its corners, 0.3 over its floor (a
    # flat lid seen from above). A crop is held a thin shell deep: the air 0.2 over the valley floor stays outside.
    points = _valley()
    shape, target, info = reconstruct_points(points, grid=48, steps=60)
    mesh = cloud_mesh(shape, target)
    assert check_watertight(mesh).watertight and info.level < 0.25
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    over_floor = np.array([[0.0, 0.0, 0.2], [0.3, -0.2, 0.22]], np.float32)
    assert not scene.compute_occupancy(o3d.core.Tensor(over_floor)).numpy().any()
    distance = scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
    assert np.mean(distance) < 0.25 * info.voxel
