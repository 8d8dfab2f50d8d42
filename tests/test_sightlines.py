"""Lines of sight: a closed target is carved where it buries points that were seen."""
import numpy as np
import open3d as o3d
import pytest
import trimesh

from voro3d.pointcloud import cloud_mesh, reconstruct_points
from voro3d.pointcloud.poisson import PoissonSurface
from voro3d.pointcloud.sightlines import CarvedSurface, carve_sightlines, sight_directions
from voro3d.queries import InsideOutside
from voro3d.shapes import example_mesh


def _scan(vertices, triangles, directions, pixels=160):
    """Points an orthographic scanner sees along each of ``directions`` (hits beyond 75 degrees dropped)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    reach = 1.5 * np.abs(vertices).max()
    found = []
    for direction in directions:
        helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(direction, helper)
        u /= np.linalg.norm(u)
        v = np.cross(direction, u)
        grid = np.linspace(-reach, reach, pixels)
        a, b = (x.ravel() for x in np.meshgrid(grid, grid))
        origins = a[:, None] * u + b[:, None] * v - 3 * reach * direction
        rays = np.hstack([origins, np.broadcast_to(direction, origins.shape)]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        depth, normal = hit["t_hit"].numpy(), hit["primitive_normals"].numpy()
        seen = np.isfinite(depth) & (np.abs(normal @ direction) > np.cos(np.radians(75.0)))
        found.append(origins[seen] + depth[seen, None] * direction)
    return np.vstack(found)


@pytest.fixture(scope="module")
def cup_scan():
    # A thin-walled cup (radius 0.4, wall 0.04, height 2) scanned from the six directions of a turned
    # cube: one view looks into its mouth at a slant and sees one side of its inner wall, none its
    # bottom. Poisson closes the mouth and fills the cup.
    wall = trimesh.creation.annulus(r_min=0.36, r_max=0.4, height=2.0, sections=96)
    base = trimesh.creation.cylinder(radius=0.4, height=0.04, sections=96)
    base.apply_translation([0, 0, -0.98])
    vertices = np.vstack([wall.vertices, base.vertices])
    triangles = np.vstack([wall.faces, base.faces + len(wall.vertices)])
    turn = trimesh.transformations.rotation_matrix(0.7, [1.0, 0.3, 0.0])[:3, :3]
    directions = np.vstack([np.eye(3), -np.eye(3)]) @ turn.T
    return _scan(vertices, triangles, directions)


def test_sight_directions_fill_the_cone():
    directions = sight_directions(32, 70.0)
    assert np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    angle = np.degrees(np.arccos(directions[:, 2]))
    assert angle.max() <= 70.0 and angle.min() < 10.0 and angle.max() > 60.0
    assert np.array_equal(directions, sight_directions(32, 70.0))


def test_a_cups_filled_mouth_is_carved_open(cup_scan):
    shape, target, info = reconstruct_points(cup_scan, grid=48, progress=False)
    assert info.plan.target == "poisson"
    mesh = cloud_mesh(shape, target)
    axis = [[0.0, 0.0, z] for z in np.linspace(-0.8, 0.8, 5)]
    inside = InsideOutside(mesh).occupancy(np.array(axis + [[0.0, 0.38, 0.0], [0.38, 0.0, -0.5]]))
    # The cavity is empty down to the bottom no view saw; the walls stay.
    assert inside.tolist() == [False] * 5 + [True, True]


def test_a_closed_target_that_hides_no_point_is_kept():
    from scipy.spatial import cKDTree

    from voro3d.pointcloud import estimate_normals

    mesh = example_mesh("blob")
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    turn = trimesh.transformations.rotation_matrix(0.7, [1.0, 0.3, 0.0])[:3, :3]
    points = _scan(vertices, triangles, np.vstack([np.eye(3), -np.eye(3)]) @ turn.T, pixels=100)
    target = PoissonSurface(vertices, triangles, resolution=256)
    spacing = float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))
    assert carve_sightlines(target, points, estimate_normals(points), spacing, 96) == (target, "")


def test_the_carved_target_is_the_base_less_the_carved_nodes():
    mesh = example_mesh("sphere")
    base = PoissonSurface(np.asarray(mesh.vertices) * 0.8, np.asarray(mesh.triangles), resolution=128)
    carved = np.zeros((33, 33, 33), bool)
    carved[17:] = True  # x > 0
    target = CarvedSurface(base, base.vertices, base.triangles, carved)
    queries = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [-0.9, 0.0, 0.0], [0.9, 0.0, 0.0], [-0.2, 0.3, 0.1]])
    assert target.inside(queries).tolist() == [True, False, False, False, True]
    assert np.allclose(target.distance(queries), base.distance(queries), atol=1e-6)


def test_a_carve_that_parts_the_solid_says_so():
    from voro3d.pointcloud.fields import supported_regions
    from voro3d.pointcloud.sightlines import _parted, _solid

    # A capsule along z with points on both round ends: carved through its middle it is two
    # supported pieces, an end carved off leaves one.
    capsule = trimesh.creation.capsule(height=1.2, radius=0.3, count=[24, 24])
    base = PoissonSurface(np.asarray(capsule.vertices), np.asarray(capsule.faces), resolution=128)
    points = base.vertices[np.abs(base.vertices[:, 2]) > 0.7]
    z = np.linspace(-1.0, 1.0, 49)[None, None, :] + np.zeros((49, 49, 1))
    solid = _solid(base, 49)
    assert _parted(solid, np.abs(z) < 0.1, points)
    assert not _parted(solid, z > 0.8, points)
    assert not _parted(solid, np.zeros_like(z, bool), points)
    labels, supported = supported_regions(np.abs(z) > 2.0, points)  # no solid: nothing supported
    assert not supported.any() and labels.max() == 0


def test_a_carve_left_out_is_reported(cup_scan, monkeypatch, capsys):
    import voro3d.pointcloud.sightlines as sightlines

    # The cup's carve, as if it parted the solid: the target stays Poisson, uncarved, and says so.
    monkeypatch.setattr(sightlines, "_parted", lambda target, carved, points: True)
    _, target, info = reconstruct_points(cup_scan, grid=48, steps=5, progress=True)
    line = next(line for line in capsys.readouterr().err.splitlines() if line.startswith("voro3d target"))
    assert info.plan.target == "poisson" and "not carved where it hid points, as that would part it" in line
    assert line.count("carved where it hid points") == 1  # no carve made beside the note
