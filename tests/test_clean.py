"""Cleaning VoroMesh surfaces: fewer and better triangles, every guarantee kept."""
import numpy as np
import open3d as o3d
import pytest

from voro3d import _cgal
from voro3d.cleaning import (MAX_DISTANCE, MAX_VOLUME_CHANGE, _changed_triangles, shared_positions, clean,
                              clean_surface, voxel_size)
from voro3d.metrics import triangle_quality
from voro3d.extract import voronoi_surface
from voro3d.sampling import sample_surface
from voro3d.watertight import check_watertight, self_intersections, signed_volume


def random_surface(seed, kind, n=400):
    """A VoroMesh surface of uniform random generators: a ball, a thin plate or random cells."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (n, 3))
    occupancy = {"ball": np.linalg.norm(points, axis=1) < 0.7, "plate": np.abs(points[:, 2]) < 0.15,
                 "random": rng.random(n) < 0.5}[kind]
    return voronoi_surface(points, occupancy)


def lattice_ball(jitter=0.02, seed=0):
    """A ball of jittered lattice cells, 0.1 apart: many tiny faces and nearly coincident vertices."""
    axis = np.arange(-8, 9) * 0.1
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    points = points + np.random.default_rng(seed).normal(size=points.shape) * jitter * 0.1
    return voronoi_surface(points, np.linalg.norm(points, axis=1) < 0.55)


def distances(a, b):
    """Distances from 20k samples of surface ``a`` to surface ``b``, both (vertices, triangles)."""
    points, _ = sample_surface(a, 20_000, seed=0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(b[0].astype(np.float32)), o3d.core.Tensor(b[1].astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def assert_clean(vertices, triangles, **options):
    """Clean, then check every guarantee; returns the result and its report."""
    new_vertices, new_triangles, info = clean_surface(vertices, triangles, **options)
    report = check_watertight((new_vertices, new_triangles))
    assert report.watertight and report.vertex_manifold and report.edge_manifold, report
    assert report.self_intersecting_pairs == 0 and report.consistently_oriented, report
    volume = signed_volume(vertices, triangles)
    limit = options.get("max_volume_change", MAX_VOLUME_CHANGE)
    assert abs(report.volume / volume - 1) <= limit * (1 + 1e-9)
    assert info.volume_change == pytest.approx(report.volume / volume - 1, abs=1e-12)
    # Open3D's float32 ray casting, near slivers: 2e-5 of the size off on identical meshes.
    slack = 1e-4 * np.linalg.norm(np.ptp(vertices, axis=0))
    assert distances((new_vertices, new_triangles), (vertices, triangles)).max() <= info.max_distance + slack
    assert distances((vertices, triangles), (new_vertices, new_triangles)).max() <= info.max_distance + slack
    assert info.n_triangles_after == len(new_triangles) <= len(triangles) == info.n_triangles_before
    return new_vertices, new_triangles, info


@pytest.mark.parametrize("surface", [lattice_ball(), lattice_ball(jitter=0.0), random_surface(0, "ball"),
                                     random_surface(3, "plate"), random_surface(2, "random")],
                         ids=["jittered lattice", "exact lattice", "ball", "thin plate", "random cells"])
def test_clean_keeps_every_guarantee(surface):
    """An exact lattice's squares have nothing to clean; the others lose triangles."""
    _, triangles, _ = assert_clean(*surface)
    assert len(triangles) < len(surface[1]) or len(np.unique(surface[0].round(12), axis=0)) == len(surface[0])


@pytest.fixture(scope="module")
def fitted_sphere():
    """A VoroMesh fitted to a sphere at 16^3 (a short fit): its surface and the grid's voxel."""
    from voro3d import fit
    from voro3d.frames import fit_frame
    from voro3d.shapes import example_mesh

    sphere = example_mesh("sphere")
    shape, _ = fit(sphere, 16, steps=100)
    return voronoi_surface(shape.generators, shape.occupancy), 2.0 / 15 / fit_frame(sphere).scale, sphere


def test_clean_removes_slivers_and_tiny_faces(fitted_sphere):
    (vertices, triangles), voxel, sphere = fitted_sphere
    new_vertices, new_triangles, info = assert_clean(vertices, triangles, voxel=voxel)
    assert len(new_triangles) * 2 <= len(triangles)
    before = triangle_quality((vertices, triangles), sphere)
    after = triangle_quality((new_vertices, new_triangles), sphere)
    assert after["sliver_share"] < 0.1 < before["sliver_share"]
    assert after["off_normal_share"] < 0.5 * before["off_normal_share"]
    shortest = np.linalg.norm(new_vertices[new_triangles] - new_vertices[np.roll(new_triangles, 1, axis=1)], axis=2)
    assert shortest.min() > 1e-3 * voxel


def test_crossings_freeze_a_patch_and_clean_again():
    """Thin plates and random cells cross themselves after a first pass: the loop freezes there."""
    _, _, plate = assert_clean(*random_surface(3, "plate"))
    _, _, cells = assert_clean(*random_surface(2, "random"))
    assert plate.rounds > 1 and cells.rounds > 1
    assert cells.frozen_vertices > 0


def test_a_round_after_a_replay_tests_the_triangles_it_changed():
    """Triangles with the corner positions of the last round's are not tested again, unless they
    crossed then or touch a duplicated position; moved ones are."""
    vertices, triangles, _ = clean_surface(*random_surface(0, "ball"))
    none = np.zeros(0, np.int64)
    rng = np.random.default_rng(0)
    # The same surface, triangles shuffled and their corners rotated: nothing changed.
    order = rng.permutation(len(triangles))
    again = np.roll(triangles[order], 1, axis=1)
    assert not _changed_triangles(vertices, again, vertices, triangles, np.zeros((0, 2), np.int64), none).any()
    moved = vertices.copy()
    moved[5] += 1e-9
    crossing = np.array([[0, 1]])
    changed = _changed_triangles(moved, triangles, vertices, triangles, crossing, np.array([7]))
    expected = (triangles == 5).any(axis=1) | (triangles == 7).any(axis=1)
    expected[[0, 1]] = True
    assert np.array_equal(changed, expected)
    assert _changed_triangles(vertices, triangles, vertices, triangles[:0], np.zeros((0, 2), np.int64), none).all()


def testshared_positions_match_unique_rows():
    rng = np.random.default_rng(1)
    vertices = rng.normal(size=(500, 3))
    vertices[rng.integers(0, 500, 40)] = vertices[rng.integers(0, 500, 40)]
    vertices[:20, 0] = 0.5  # equal x, different points
    _, first, counts = np.unique(vertices, axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(shared_positions(vertices), counts[first.reshape(-1)] > 1)
    assert not shared_positions(vertices[:0]).size


def test_sheets_touching_at_a_vertex_stay_touching():
    """Two cells meeting at a corner: the duplicated corner vertices do not move."""
    axis = np.arange(4.0)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    inside = np.zeros(len(points), bool)
    inside[[np.ravel_multi_index((1, 1, 1), (4, 4, 4)), np.ravel_multi_index((2, 2, 2), (4, 4, 4))]] = True
    vertices, triangles = voronoi_surface(points, inside)
    _, first, counts = np.unique(vertices, axis=0, return_inverse=True, return_counts=True)
    shared = vertices[counts[first.reshape(-1)] > 1]
    new_vertices, new_triangles, _ = assert_clean(vertices, triangles, voxel=2.0)
    for point in shared:
        assert (new_vertices == point).all(axis=1).sum() == 2
    assert check_watertight((new_vertices, new_triangles)).touching_pairs > 0


def test_zero_distance_changes_nothing_that_moves_the_surface():
    vertices, triangles = lattice_ball()
    new_vertices, new_triangles, info = assert_clean(vertices, triangles, max_distance=0.0)
    assert info.volume_change == pytest.approx(0, abs=1e-12)


def test_clean_returns_an_open3d_mesh_with_normals_and_is_deterministic():
    import voro3d

    assert voro3d.clean is clean
    vertices, triangles = lattice_ball()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    a, b = clean(mesh), clean((vertices.copy(), triangles.copy()))
    assert isinstance(a, o3d.geometry.TriangleMesh) and a.has_vertex_normals()
    np.testing.assert_array_equal(np.asarray(a.vertices), np.asarray(b.vertices))
    np.testing.assert_array_equal(np.asarray(a.triangles), np.asarray(b.triangles))


def test_voxel_size_of_a_fitted_surface(fitted_sphere):
    """The estimate is the grid's voxel within the spread measured on the dev meshes."""
    (vertices, triangles), voxel, _ = fitted_sphere
    assert voxel_size(vertices, triangles) == pytest.approx(voxel, rel=0.2)


def tetrahedron(offset=0.0):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + offset
    return vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_triangles_that_already_crossed_are_left_as_they_were():
    """Two overlapping tetrahedra, and a lattice jittered at the snapping quantum whose rounded
    Voronoi vertices 1e-17 apart make triangles touch: the input's crossing pairs stay, no new one."""
    a, b = tetrahedron(), tetrahedron(0.25)
    vertices, triangles = np.vstack([a[0], b[0]]), np.vstack([a[1], b[1] + 4])
    new_vertices, new_triangles, info = clean_surface(vertices, triangles, voxel=1.0)
    np.testing.assert_array_equal(new_vertices, vertices)
    assert len(self_intersections(new_vertices, new_triangles)[0]) == info.input_crossings > 0
    vertices, triangles = lattice_ball(jitter=1e-6)
    crossing = self_intersections(vertices, triangles)[0]
    new_vertices, new_triangles, info = clean_surface(vertices, triangles)
    after = self_intersections(new_vertices, new_triangles)[0]
    assert len(after) == info.input_crossings <= len(crossing)
    assert {tuple(sorted(map(tuple, new_vertices[new_triangles[pair]].reshape(-1, 3)))) for pair in after} <= \
        {tuple(sorted(map(tuple, vertices[triangles[pair]].reshape(-1, 3)))) for pair in crossing}


@pytest.mark.parametrize("mesh, options, match", [
    (tetrahedron(), {"max_distance": -0.1}, "max_distance must be finite and >= 0"),
    (tetrahedron(), {"collapse_length": np.nan}, "collapse_length"),
    (tetrahedron(), {"merge_length": np.inf}, "merge_length"),
    (tetrahedron(), {"min_angle_gain": -1}, "min_angle_gain"),
    (tetrahedron(), {"max_volume_change": -1e-3}, "max_volume_change"),
    (tetrahedron(), {"voxel": 0.0}, "voxel must be finite and > 0"),
    (tetrahedron(), {"voxel": np.nan}, "voxel"),
    ((tetrahedron()[0], tetrahedron()[1][:, ::-1]), {}, "positive volume with outward normals"),
    ((tetrahedron()[0], tetrahedron()[1][:3]), {}, "closed surface"),
    ((np.vstack([tetrahedron()[0], [[2, 2, 2]]]), np.vstack([tetrahedron()[1], [[0, 1, 4]]])), {},
     "non-manifold|closed surface"),
    ((np.zeros((4, 2)), tetrahedron()[1]), {}, "vertices must have shape"),
    ((tetrahedron()[0], tetrahedron()[1] + 1), {}, "outside"),
])
def test_bad_input_raises_value_error(mesh, options, match):
    with pytest.raises(ValueError, match=match):
        clean_surface(*mesh, **options)


def test_voxel_size_bad_input():
    with pytest.raises(ValueError, match="zero area"):
        voxel_size(np.zeros((4, 3)), tetrahedron()[1])
    with pytest.raises(ValueError, match="triangles"):
        voxel_size(tetrahedron()[0], np.zeros((0, 3), int))


def test_bad_mesh_type_raises_type_error():
    with pytest.raises(TypeError, match="mesh must be"):
        clean("mesh.ply")


@pytest.mark.parametrize("change, match", [
    ({"frozen": np.zeros(3, bool)}, r"frozen must have shape \(4,\)"),
    ({"frozen": np.zeros(4)}, "frozen must be a boolean array"),
    ({"merge_length": -1.0}, "merge_length"),
    ({"collapse_length": np.inf}, "collapse_length"),
    ({"max_distance": np.nan}, "max_distance"),
    ({"max_volume_change": -1.0}, "max_volume_change"),
    ({"flip_margin": -1.0}, "flip_margin"),
    ({"passes": 0}, "passes must be >= 1"),
    ({"triangles": tetrahedron()[1][:3]}, "at least 4 rows"),
    ({"triangles": np.array([[0, 1, 2], [0, 1, 2], [0, 1, 3], [1, 2, 3]])}, "non-manifold"),
])
def test_extension_checks_its_arguments(change, match):
    vertices, triangles = tetrahedron()
    arguments = dict(vertices=vertices, triangles=triangles, frozen=np.zeros(4, bool), merge_length=0.1,
                     collapse_length=0.1, max_distance=0.1, max_volume_change=0.1, flip_margin=0.01, passes=1)
    arguments.update(change)
    with pytest.raises((ValueError, TypeError), match=match):
        _cgal.clean_surface(**arguments)


def test_defaults_are_the_documented_ones():
    import inspect

    parameters = inspect.signature(clean).parameters
    assert parameters["max_distance"].default == MAX_DISTANCE
    assert parameters["max_volume_change"].default == MAX_VOLUME_CHANGE


def test_every_path_that_returns_a_mesh_cleans_by_default(tmp_path):
    from voro3d import VoroMesh, VoroMeshStage, extract_mesh, reconstruct
    from voro3d.shapes import example_mesh

    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (400, 3))
    shape = VoroMesh(points, np.linalg.norm(points, axis=1) < 0.7)
    raw = voronoi_surface(shape.generators, shape.occupancy)
    cleaned, _, _ = clean_surface(*raw)
    assert len(shape.to_open3d().vertices) == len(cleaned) < len(raw[0])
    np.testing.assert_array_equal(np.asarray(shape.to_open3d(clean=False).vertices), raw[0])
    assert len(extract_mesh(points, shape.occupancy).triangles) == len(raw[1])
    sphere = example_mesh("sphere")
    assert len(reconstruct(sphere, 8, steps=5).triangles) < len(reconstruct(sphere, 8, steps=5, clean=False).triangles)
    assert VoroMeshStage(8, clean=False).options["clean"] is False


def test_cli_no_clean_and_polygons(tmp_path, capsys):
    from voro3d import VoroMesh
    from voro3d.cli import main
    from voro3d.io import load_mesh

    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (400, 3))
    shape = VoroMesh(points, np.linalg.norm(points, axis=1) < 0.7)
    shape.save(tmp_path / "g.npz")
    assert main(["extract", str(tmp_path / "g.npz"), "-o", str(tmp_path / "clean.ply"), "-q"]) == 0
    assert main(["extract", str(tmp_path / "g.npz"), "-o", str(tmp_path / "raw.ply"), "--no-clean", "-q",
                 "--polygons", str(tmp_path / "cells.obj")]) == 0
    raw = voronoi_surface(shape.generators, shape.occupancy)
    assert len(load_mesh(tmp_path / "raw.ply", weld=False).triangles) == len(raw[1])
    assert len(load_mesh(tmp_path / "clean.ply", weld=False).triangles) == len(clean(raw).triangles)
    faces = [line for line in (tmp_path / "cells.obj").read_text().splitlines() if line.startswith("f ")]
    assert len(faces) == len(shape.to_polygons()[1])
    with pytest.raises(SystemExit):  # argparse refuses the suffix before anything is written
        main(["extract", str(tmp_path / "g.npz"), "-o", str(tmp_path / "x.ply"), "--polygons", str(tmp_path / "c.stl")])
    assert "must end in one of .ply .obj .off" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


def test_batch_no_clean(tmp_path):
    from voro3d.batch import run_batch
    from voro3d.io import load_mesh, save_mesh
    from voro3d.shapes import example_mesh

    (tmp_path / "in").mkdir()
    save_mesh(example_mesh("sphere"), tmp_path / "in" / "sphere.ply")
    counts = {}
    for clean_option in (True, False):
        out = tmp_path / f"out_{clean_option}"
        summary = run_batch(tmp_path / "in", out, method="learned", grid=16, workers=1, clean=clean_option)
        assert summary.rows[0]["settings"]["clean"] is clean_option and summary.rows[0]["status"] == "ok"
        counts[clean_option] = len(load_mesh(out / "sphere.ply", weld=False).triangles)
    assert counts[True] < counts[False]


def test_replay_makes_the_same_changes_and_spares_frozen_vertices():
    vertices, triangles = random_surface(0, "ball")
    frozen = np.zeros(len(vertices), bool)
    arguments = (0.05 * 0.2, 0.4 * 0.2, 0.2 * 0.2, 1e-3, np.radians(1.0), 2)
    first = _cgal.clean_surface(vertices, triangles, frozen, *arguments)
    log = first[-1]
    assert len(log) >= first[3] + first[4]  # every collapse and flip, and the passes
    again = _cgal.replay_clean(vertices, triangles, frozen, log)
    for a, b in zip(first[:5], again):
        np.testing.assert_array_equal(a, b)
    frozen[::7] = True
    spared = _cgal.replay_clean(vertices, triangles, frozen, log)
    new_vertices, _, label = spared[:3]
    np.testing.assert_array_equal(new_vertices[label[frozen]], vertices[frozen])  # not moved
    assert np.bincount(label[label >= 0])[label[frozen]].max() == 1  # nothing merged into them
    assert check_watertight(spared[:2], self_intersection=False).closed
    # The log keeps the surface it was made on, built; other arrays of the same size are built anew.
    everything = np.ones(len(vertices), bool)
    for given in (vertices * 2, vertices.copy()):
        kept = _cgal.replay_clean(given, triangles, everything, log)
        np.testing.assert_array_equal(kept[0], given)
        assert sorted(map(tuple, np.sort(kept[1], axis=1).tolist())) == sorted(map(tuple, np.sort(triangles, axis=1).tolist()))


def test_replay_checks_its_arguments():
    vertices, triangles = tetrahedron()
    frozen = np.zeros(4, bool)
    log = _cgal.clean_surface(vertices, triangles, frozen, 0.1, 0.1, 0.1, 0.1, 0.01, 1)[-1]
    with pytest.raises(TypeError):
        _cgal.replay_clean(vertices, triangles, frozen, None)
    with pytest.raises(ValueError, match="log is of a surface of 4 vertices and 4 triangles"):
        _cgal.replay_clean(*random_surface(0, "ball"), np.zeros(len(random_surface(0, "ball")[0]), bool), log)
    with pytest.raises(ValueError, match="frozen must have shape"):
        _cgal.replay_clean(vertices, triangles, np.zeros(3, bool), log)


@pytest.mark.parametrize("name", ["bracket", "knot", "blob"])
def test_collapse_rules_decide_as_cgal_edge_collapse(name):
    """src/clean/rules.h rewrites CGAL's collapse tests (link condition, topological and geometric
    validity); run CGAL's own edge_collapse with the clean's placement and, at every edge it takes up,
    ask ours too: the same answer on every edge."""
    from voro3d.fitting import fit
    from voro3d.shapes import example_mesh

    shape, _ = fit(example_mesh(name), 24, steps=50)
    decisions = _cgal.collapse_decisions(*voronoi_surface(shape.generators, shape.occupancy), 0.5)
    ours, cgal = decisions[:, 0], decisions[:, 1]
    assert len(decisions) > 1000 and 0 < cgal.sum() < len(cgal)  # both answers occur
    np.testing.assert_array_equal(ours, cgal)
