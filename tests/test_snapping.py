"""Snapping a surface onto its target: closer to it, and no move that breaks a guarantee."""
import numpy as np
import open3d as o3d
import pytest

from voro3d.cleaning import clean_surface
from voro3d.extract import voronoi_surface
from voro3d.io import mesh_arrays
from voro3d.sampling import sample_surface
from voro3d.snapping import snap_to_surface
from voro3d.watertight import check_watertight, self_intersections


def box(low, high):
    """(vertices, triangles) of an axis-aligned box, outward."""
    mesh = o3d.geometry.TriangleMesh.create_box(*(np.subtract(high, low)))
    vertices, triangles = mesh_arrays(mesh)
    return vertices + low, triangles


def two_boxes(gap, overhang):
    """Box A, [0, 1]^3, and box B ``gap`` to its right, ``overhang`` wider on each side in y and z."""
    (a, ta) = box((0, 0, 0), (1, 1, 1))
    (b, tb) = box((1 + gap, -overhang, -overhang), (2, 1 + overhang, 1 + overhang))
    return (np.vstack([a, b]), np.vstack([ta, tb + len(a)])), (b, tb)


def sphere(radius=0.6):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=40)
    return mesh_arrays(mesh)


def distance_to(surface, points):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(surface[0].astype(np.float32)), o3d.core.Tensor(surface[1].astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_a_voromesh_ball_moves_onto_the_sphere_and_stays_watertight():
    rng = np.random.default_rng(0)
    generators = rng.uniform(-1, 1, (3000, 3))
    vertices, triangles, _ = clean_surface(*voronoi_surface(generators, np.linalg.norm(generators, axis=1) < 0.6))
    voxel = 0.15
    snapped, info = snap_to_surface(vertices, triangles, sphere(), voxel=voxel)
    samples = [sample_surface((v, triangles), 20_000, seed=0)[0] for v in (vertices, snapped)]
    before, after = (distance_to(sphere(), points) for points in samples)
    assert np.linalg.norm(snapped - vertices, axis=1).max() <= 0.25 * voxel * (1 + 1e-9)
    assert info.moved > 0.5 * len(vertices) and info.max_move <= 0.25 * voxel * (1 + 1e-9)
    assert after.mean() < 0.7 * before.mean()
    report = check_watertight((snapped, triangles))
    assert report.watertight and report.self_intersecting_pairs == 0


@pytest.mark.parametrize("overhang", [0.0, 0.5])
def test_a_move_that_would_touch_another_part_is_held(overhang):
    # B is the target: A's right face (0.0625 away, under the cap) would land on B's left face,
    # corner on corner (overhang 0: A's moved corners would share B's positions) or inside it.
    (vertices, triangles), target = two_boxes(0.0625, overhang)
    snapped, info = snap_to_surface(vertices, triangles, target, voxel=1.0, max_move=0.1)
    right_face = np.flatnonzero(vertices[:8, 0] == 1.0)
    assert np.array_equal(snapped[right_face], vertices[right_face])
    assert info.held >= len(right_face) and info.rounds >= 2
    crossing, touching = self_intersections(snapped, triangles)
    assert not len(crossing) and not len(touching)
    assert check_watertight((snapped, triangles)).watertight


def test_moves_that_flatten_triangles_are_held():
    octahedron = o3d.geometry.TriangleMesh.create_octahedron(1.0)
    vertices, triangles = mesh_arrays(octahedron)
    plane = (np.array([[-2, -2, -0.5], [2, -2, -0.5], [2, 2, -0.5], [-2, 2, -0.5]]), np.array([[0, 1, 2], [0, 2, 3]]))
    snapped, info = snap_to_surface(vertices, triangles, plane, voxel=1.0, max_move=5.0)
    # The fit would flatten it onto the plane, the two halves folded onto each other: no triangle
    # turns 90 degrees, but the stars of the equator stop being graphs.
    assert np.array_equal(snapped, vertices)
    assert info.moved == 0 and info.held == 6


def test_shared_positions_stay_and_bad_parameters_are_named():
    vertices, triangles = sphere()
    touching = np.vstack([vertices, vertices[:1]])  # a second vertex at vertex 0's position
    faces = triangles.copy()
    faces[tuple(np.argwhere(faces == 0)[0])] = len(vertices)
    snapped, _ = snap_to_surface(touching, faces, sphere(0.5), voxel=1.0)
    assert np.array_equal(snapped[[0, -1]], touching[[0, -1]])
    with pytest.raises(ValueError, match="voxel"):
        snap_to_surface(vertices, triangles, sphere(), voxel=0.0)
    with pytest.raises(ValueError, match="max_move"):
        snap_to_surface(vertices, triangles, sphere(), voxel=1.0, max_move=-1)
    with pytest.raises(ValueError, match="smoothing"):
        snap_to_surface(vertices, triangles, sphere(), voxel=1.0, smoothing=np.nan)
    with pytest.raises(ValueError, match="surface has no triangles"):
        snap_to_surface(vertices, triangles, (np.zeros((0, 3)), np.zeros((0, 3), int)), voxel=1.0)
    with pytest.raises(ValueError, match="surface"):
        snap_to_surface(vertices, triangles, (np.full((3, 3), np.nan), np.array([[0, 1, 2]])), voxel=1.0)
    with pytest.raises(ValueError, match="max_turn"):
        snap_to_surface(vertices, triangles, sphere(), voxel=1.0, max_turn=91)
    with pytest.raises(ValueError, match="fit must be"):
        snap_to_surface(vertices, triangles, sphere(), voxel=1.0, fit="points")


def voromesh_ball(count=3000, radius=0.6, seed=0):
    generators = np.random.default_rng(seed).uniform(-1, 1, (count, 3))
    return clean_surface(*voronoi_surface(generators, np.linalg.norm(generators, axis=1) < radius))[:2]


def test_fit_vertices_puts_each_moved_vertex_on_the_surface():
    from voro3d.geometry import split_triangles

    vertices, triangles, _ = split_triangles(*voromesh_ball(), 2)
    snapped, info = snap_to_surface(vertices, triangles, sphere(), voxel=0.6, fit="vertices")
    move = np.linalg.norm(snapped - vertices, axis=1)
    moved = (move > 0) & (move < 0.25 * 0.6 * (1 - 1e-9))  # not stopped by max_move
    assert info.moved >= moved.sum() > 0.5 * len(vertices)
    # float32, as Open3D finds nearest points; the sphere's own chords are about 1e-3 deep.
    assert distance_to(sphere(), snapped[moved]).max() < 1e-5
    assert distance_to(sphere(), vertices[moved]).mean() > 100 * distance_to(sphere(), snapped[moved]).mean()
    report = check_watertight((snapped, triangles))
    assert report.watertight and report.self_intersecting_pairs == 0


@pytest.mark.parametrize("fit", ["faces", "vertices"])
def test_no_triangle_a_snap_moves_turns_or_unfolds_a_star_and_faces_keep_their_shapes(fit):
    # A target with bumps finer than the ball's facets: about half the vertices are held, in chains.
    from voro3d.geometry import smallest_angles, split_triangles
    from voro3d.snapping import MIN_ANGLE, _graph_stars, _normals

    vertices, triangles, _ = split_triangles(*voromesh_ball(), 1)
    bumpy = sphere()
    bumpy = (bumpy[0] * (1 + 0.05 * np.sin(25 * bumpy[0][:, :1]) * np.cos(21 * bumpy[0][:, 1:2])), bumpy[1])
    snapped, info = snap_to_surface(vertices, triangles, bumpy, voxel=0.15, max_turn=70.0, fit=fit)
    assert info.held > 0.3 * len(vertices) and info.moved > 0.3 * len(vertices)
    before, after = _normals(vertices, triangles), _normals(snapped, triangles)
    cosine = np.einsum("ij,ij->i", before, after) / np.linalg.norm(before, axis=1) / np.linalg.norm(after, axis=1)
    assert cosine.min() > np.cos(np.radians(70.0))
    thinned = smallest_angles(snapped, triangles) < np.minimum(smallest_angles(vertices, triangles), MIN_ANGLE)
    assert not thinned.any() if fit == "faces" else thinned.any()  # fitted by its vertices, it follows the surface
    assert np.all(_graph_stars(snapped, triangles) | ~_graph_stars(vertices, triangles))
    report = check_watertight((snapped, triangles))
    assert report.watertight and report.self_intersecting_pairs == 0


@pytest.fixture(scope="module")
def torus_fit():
    """The torus example and its VoroMesh at 20^3 (150 steps, seed 0): two tests fit it."""
    import voro3d
    from voro3d.shapes import example_mesh

    source = example_mesh("torus")
    return source, voro3d.fit(source, grid=20, steps=150, seed=0)[0]


def test_snap_takes_open3d_meshes_and_fits_a_voromesh_to_its_input(torus_fit):
    import voro3d
    from voro3d.metrics import evaluate, triangle_quality

    source, shape = torus_fit
    cleaned = shape.to_open3d()
    fitted = voro3d.snap(cleaned, source)
    assert isinstance(fitted, o3d.geometry.TriangleMesh) and fitted.has_vertex_normals()
    assert np.array_equal(np.asarray(fitted.triangles), np.asarray(cleaned.triangles))
    report = check_watertight(fitted)
    assert report.watertight and report.self_intersecting_pairs == 0
    before, after = evaluate(cleaned, source, n_samples=20000), evaluate(fitted, source, n_samples=20000)
    # Measured: CD 3.07 -> 3.02, NC 0.982 -> 0.987, off-normal triangles 6.9% -> 2.6%.
    assert after["nc"] > before["nc"] and after["chamfer_x1e5"] < before["chamfer_x1e5"]
    assert triangle_quality(fitted, source)["off_normal_share"] < 0.7 * triangle_quality(cleaned, source)["off_normal_share"]


def test_smoothing_pulls_a_bumpy_fit_flat():
    # A sphere fitted to a bumpy one (bumps 0.018 high, 0.25 apart): the smoothed fit is rounder.
    vertices, triangles = mesh_arrays(o3d.geometry.TriangleMesh.create_sphere(0.6, resolution=20))
    fine, fine_triangles = sphere()
    bumpy = fine * (1 + 0.03 * np.sin(25 * fine[:, :1]) * np.sin(25 * fine[:, 1:2]))
    spread = {}
    for smoothing in (0.0, 1.0):
        snapped, info = snap_to_surface(vertices, triangles, (bumpy, fine_triangles), voxel=1.0, smoothing=smoothing)
        assert info.moved > 0.9 * len(vertices)
        spread[smoothing] = np.linalg.norm(snapped, axis=1).std()
    assert spread[1.0] < 0.7 * spread[0.0]  # measured 0.0054 against 0.0110


def test_mesh_paths_return_the_surface_fitted_to_their_input(torus_fit):
    import voro3d
    from voro3d.metrics import triangle_quality

    source, shape = torus_fit
    cleaned, fitted = shape.to_open3d(), shape.to_open3d(surface=source)
    assert np.array_equal(np.asarray(fitted.triangles), np.asarray(cleaned.triangles))
    assert not np.array_equal(np.asarray(fitted.vertices), np.asarray(cleaned.vertices))
    report = check_watertight(fitted)
    assert report.watertight and report.self_intersecting_pairs == 0
    assert triangle_quality(fitted, source)["off_normal_share"] < 0.7 * triangle_quality(cleaned, source)["off_normal_share"]
    returned = voro3d.reconstruct(source, grid=20, steps=150, seed=0)
    assert np.array_equal(np.asarray(returned.vertices), np.asarray(fitted.vertices))
    # Unclean means the Voronoi faces as they are: no surface to fit them to.
    raw = voro3d.reconstruct(source, grid=20, steps=150, seed=0, clean=False)
    assert np.array_equal(np.asarray(raw.vertices), np.asarray(shape.to_open3d(clean=False).vertices))


def test_refine_splits_the_triangles_before_the_fit_and_keeps_every_guarantee(torus_fit):
    from voro3d.metrics import evaluate

    source, shape = torus_fit
    fitted, refined = shape.to_open3d(surface=source), shape.to_open3d(surface=source, refine=1)
    assert len(refined.triangles) == 4 * len(fitted.triangles)
    report = check_watertight(refined)
    assert report.watertight and report.self_intersecting_pairs == 0
    before, after = evaluate(fitted, source, n_samples=20000), evaluate(refined, source, n_samples=20000)
    # The split faces bend with the torus: measured CD 3.02 -> 2.91, NC 0.987 -> 0.993.
    assert after["chamfer_x1e5"] < before["chamfer_x1e5"] and after["nc"] > before["nc"]
    # Split twice, the vertices go onto the torus: measured CD 2.89, NC 0.996.
    twice = shape.to_open3d(surface=source, refine=2)
    assert len(twice.triangles) == 16 * len(fitted.triangles)
    report = check_watertight(twice)
    assert report.watertight and report.self_intersecting_pairs == 0
    finer = evaluate(twice, source, n_samples=20000)
    assert finer["chamfer_x1e5"] < before["chamfer_x1e5"] and finer["nc"] > after["nc"]
    for refine, error in ((1, "needs a surface"), (-1, "refine must be"), (True, "refine must be")):
        with pytest.raises(ValueError, match=error):
            shape.to_open3d(refine=refine)


def test_a_split_mesh_keeps_the_creases_its_smooth_target_rounds(monkeypatch):
    import open3d as o3d

    import voro3d
    from voro3d import snapping
    from voro3d.topology import creased_triangles

    box = o3d.geometry.TriangleMesh.create_box().translate((-0.5, -0.5, -0.5)).subdivide_midpoint(4)
    rounded = box.filter_smooth_taubin(number_of_iterations=20)  # its edges and corners rounded off
    shape = voro3d.fit(box, grid=16, steps=100, seed=0)[0]
    # The box's edges, sampled: how far the mesh lies from them says whether it kept them.
    t = np.linspace(-0.4, 0.4, 9)
    edges = np.vstack([np.stack(np.roll([t, np.full(9, a), np.full(9, b)], k, axis=0), axis=1)
                       for k in range(3) for a in (-0.5, 0.5) for b in (-0.5, 0.5)])

    def off_edges(mesh):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        return float(np.mean(scene.compute_distance(o3d.core.Tensor(edges.astype(np.float32))).numpy()))

    kept = shape.to_open3d(surface=rounded, refine=1)
    monkeypatch.setattr(snapping, "CREASE_DEGREES", 180.0)  # no side counts as a crease
    followed = shape.to_open3d(surface=rounded, refine=1)
    for mesh in (kept, followed):
        report = check_watertight(mesh)
        assert report.watertight and report.self_intersecting_pairs == 0
    assert off_edges(kept) < 0.5 * off_edges(followed)
    # A cube's sides between its faces turn by 90 degrees; the faces' own sides by none.
    vertices, triangles = np.asarray(box.vertices), np.asarray(box.triangles)
    creased = creased_triangles(vertices, triangles, 75.0)
    corners = vertices[triangles]
    # A side runs along an edge of the cube where its ends share two coordinates at +-0.5.
    along = [np.sum(np.isclose(np.abs(corners[:, i]), 0.5) & np.isclose(corners[:, i], corners[:, (i + 1) % 3]), axis=1) >= 2
             for i in range(3)]
    on_an_edge = np.sum(np.any(along, axis=0))
    assert creased.sum() == on_an_edge > 0 and not creased_triangles(vertices, triangles, 95.0).any()
    from voro3d.snapping import snap_to_surface

    cleaned = shape.to_open3d()
    vertices, triangles = np.asarray(cleaned.vertices), np.asarray(cleaned.triangles)
    still = np.zeros(len(vertices), bool)
    still[::2] = True
    moved, _ = snap_to_surface(vertices, triangles, rounded, voxel=shape.voxel, fixed=still)
    np.testing.assert_array_equal(moved[still], vertices[still])
    assert not np.array_equal(moved, vertices)
    with pytest.raises(ValueError, match="fixed must be one bool per vertex"):
        snap_to_surface(vertices, triangles, rounded, voxel=shape.voxel, fixed=still[:3])
