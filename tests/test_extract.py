"""VoroMesh extraction: closed, manifold, outward, intersection-free, exact volume."""
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial import ConvexHull, HalfspaceIntersection

from voro3d import VoroMesh, extract_mesh
from voro3d.cleaning import MAX_VOLUME_CHANGE, clean_surface
from voro3d.delaunay import bounding_generators, triangulate
from voro3d.extract import voronoi_polygons, voronoi_surface
from voro3d.watertight import check_watertight, signed_volume


def inside_cell_volume(generators, occupancy):
    """Summed volume of the inside Voronoi cells, each the intersection of its bisector
    half-spaces (independent of the Delaunay dual). Qhull's Voronoi diagram is off by up to
    2% next to generators 1e-6 apart, the half-space route agrees with ours to 1e-10."""
    triangulation = triangulate(np.asarray(generators, float))
    points = triangulation.points[: triangulation.n_sites]
    inside = triangulation.site_occupancy(np.asarray(occupancy, bool))[: triangulation.n_sites]
    everything = np.vstack([points, bounding_generators(points)])
    total = 0.0
    for index in np.flatnonzero(inside):
        others = np.delete(everything, index, axis=0)
        centre = everything[index]
        offsets = (np.einsum("ij,ij->i", others, others) - centre @ centre) / 2
        halfspaces = np.hstack([others - centre, -offsets[:, None]])
        total += ConvexHull(HalfspaceIntersection(halfspaces, centre).intersections).volume
    return total


def assert_valid_surface(generators, occupancy):
    """The Voronoi faces, then the cleaned surface (every case of the suite runs through clean)."""
    mesh = extract_mesh(generators, occupancy)
    report = check_watertight(mesh)
    assert report.closed and report.edge_manifold and report.vertex_manifold, report
    assert report.consistently_oriented and report.orientable, report
    assert report.self_intersecting_pairs == 0, report
    expected = inside_cell_volume(generators, occupancy)
    assert report.volume == pytest.approx(expected, rel=1e-6), (report.volume, expected)
    vertices, triangles, info = clean_surface(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    cleaned = check_watertight((vertices, triangles))
    assert cleaned.closed and cleaned.edge_manifold and cleaned.vertex_manifold, cleaned
    assert cleaned.consistently_oriented and cleaned.orientable, cleaned
    assert cleaned.self_intersecting_pairs == info.input_crossings == 0, cleaned
    assert abs(cleaned.volume / report.volume - 1) <= MAX_VOLUME_CHANGE * (1 + 1e-9)
    return mesh, report


def _ensure_both(occupancy):
    occupancy = np.asarray(occupancy, bool).copy()
    if occupancy.all():
        occupancy[0] = False
    if not occupancy.any():
        occupancy[-1] = True
    return occupancy


@st.composite
def occupancies(draw, points):
    kind = draw(st.sampled_from(["random", "sphere", "box"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = lo + (hi - lo) * rng.uniform(0.3, 0.7, 3)
    if kind == "random":
        occupancy = rng.random(len(points)) < rng.uniform(0.2, 0.8)
    elif kind == "sphere":
        radius = np.linalg.norm(hi - lo) * rng.uniform(0.1, 0.4)
        occupancy = np.linalg.norm(points - centre, axis=1) < radius
    else:
        half = (hi - lo) * rng.uniform(0.1, 0.4, 3)
        occupancy = (np.abs(points - centre) < half).all(axis=1)
    return _ensure_both(occupancy)


seeds = st.integers(0, 2**32 - 1)


@given(seed=seeds, n=st.integers(5, 300), data=st.data())
def test_uniform_random(seed, n, data):
    points = np.random.default_rng(seed).uniform(-1, 1, (n, 3))
    assert_valid_surface(points, data.draw(occupancies(points)))


@given(seed=seeds, k=st.integers(2, 6), spacing=st.sampled_from([1.0, 0.1, 0.37, 2.0 / 31]),
       jitter=st.sampled_from([0.0, 1e-9]), data=st.data())
def test_lattice(seed, k, spacing, jitter, data):
    """Exact and 1e-9-jittered lattices: co-spherical everywhere, sheets touching at edges."""
    rng = np.random.default_rng(seed)
    axis = np.arange(k) * spacing
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    points = points + rng.normal(size=points.shape) * jitter * spacing
    assert_valid_surface(points, data.draw(occupancies(points)))


@given(seed=seeds, n=st.integers(5, 200), shell=st.sampled_from([0.0, 1e-9, 1e-3]), data=st.data())
def test_sphere_shell(seed, n, shell, data):
    """Points on (co-spherical) or near a sphere, plus its centre so some cell is bounded inside."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    points = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    points = points * (1 + shell * rng.uniform(-1, 1, (n, 1)))
    points = np.vstack([points, np.zeros((1, 3))])
    assert_valid_surface(points, data.draw(occupancies(points)))


@given(seed=seeds, n=st.integers(4, 100), copies=st.integers(1, 4),
       offset=st.sampled_from([0.0, 1e-13, 1e-10, 1e-6, 1e-4]), data=st.data())
def test_clusters_with_near_duplicates(seed, n, copies, offset, data):
    """Copies of generators at 0 to 1e-4 (exact duplicates, merged, or kept as thin cells);
    a copy shares its original's occupancy so both labels survive merging."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1, 1, (n, 3))
    source = np.repeat(np.arange(max(1, n // 3)), copies)
    near = base[source] + rng.normal(size=(source.size, 3)) * offset
    occupancy = data.draw(occupancies(base))
    assert_valid_surface(np.vstack([base, near]), np.concatenate([occupancy, occupancy[source]]))


def test_conflicting_duplicates_are_inside():
    rng = np.random.default_rng(3)
    points = rng.uniform(-1, 1, (50, 3))
    inside = np.linalg.norm(points, axis=1) < 0.7
    outside_copy = points[np.flatnonzero(inside)[:1]]
    with_copy = np.vstack([points, outside_copy])
    merged, _ = assert_valid_surface(with_copy, np.r_[inside, False])
    reference = extract_mesh(points, inside)
    assert np.asarray(merged.vertices).shape == np.asarray(reference.vertices).shape


def test_sphere_area_and_volume():
    """A ball of lattice cells: volume is the count of inside cubes, area their exposed faces."""
    axis = np.arange(-6, 7) * 0.1
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    inside = np.linalg.norm(points, axis=1) < 0.45
    mesh, report = assert_valid_surface(points, inside)
    # Snapping to the tolerance grid moves generators by < 1e-7 of the diagonal.
    assert report.volume == pytest.approx(inside.sum() * 1e-3, rel=1e-6)
    grid = inside.reshape(13, 13, 13)
    exposed = sum(np.count_nonzero(np.diff(grid.astype(int), axis=a)) for a in range(3))
    assert mesh.get_surface_area() == pytest.approx(exposed * 1e-2, rel=1e-6)


def test_two_cells_meeting_at_a_corner_are_separate_sheets():
    axis = np.arange(4.0)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    inside = np.zeros(len(points), bool)
    inside[[np.ravel_multi_index((1, 1, 1), (4, 4, 4)), np.ravel_multi_index((2, 2, 2), (4, 4, 4))]] = True
    mesh, report = assert_valid_surface(points, inside)
    assert len(mesh.triangles) == 2 * 12
    assert report.touching_pairs > 0
    assert len(mesh.cluster_connected_triangles()[1]) == 2


def test_golden_tetrahedral_cell():
    """Tiny exact regression: the cell of the origin among the corners of a regular tetrahedron
    is the regular tetrahedron with vertices -1.5 p_i (edge 3 sqrt 2, volume 9)."""
    corners = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    points = np.vstack([[0, 0, 0], corners])
    vertices, triangles = voronoi_surface(points, [True, False, False, False, False])
    assert triangles.shape == (4, 3)
    np.testing.assert_allclose(sorted(map(tuple, vertices)), sorted(map(tuple, -1.5 * corners)), atol=1e-12)
    assert signed_volume(vertices, triangles) == pytest.approx(9.0, rel=1e-12)


def test_output_is_deterministic():
    rng = np.random.default_rng(1)
    points = rng.uniform(-1, 1, (500, 3))
    inside = np.linalg.norm(points, axis=1) < 0.6
    a, b = voronoi_surface(points, inside), voronoi_surface(points.copy(), inside.copy())
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize("generators, occupancy, match", [
    (np.zeros((10, 2)), np.ones(10, bool), "shape"),
    (np.array([["a", "b", "c"]] * 5), np.ones(5, bool), "numeric"),
    (np.full((5, 3), np.nan), np.ones(5, bool), "NaN"),
    (np.r_[np.eye(3), [[np.inf, 0, 0]], [[0, 0, 0]]], np.ones(5, bool), "inf"),
    (np.zeros((5, 3)), [True, False, True, False, True], "at least 4 distinct"),
    (np.eye(3), [True, False, True], "at least 4 distinct"),
    (np.random.default_rng(0).random((10, 3)), np.ones(10, bool), "no outside"),
    (np.random.default_rng(0).random((10, 3)), np.zeros(10, bool), "no inside"),
    (np.random.default_rng(0).random((10, 3)), np.ones(9, bool), "occupancy must have shape"),
    (np.random.default_rng(0).random((10, 3)), np.full(10, 0.5), "boolean"),
])
def test_bad_input_raises_value_error(generators, occupancy, match):
    with pytest.raises(ValueError, match=match):
        extract_mesh(generators, occupancy)


def test_voronoi_polygons_are_the_faces_the_surface_triangulates():
    """One polygon per face, in the triangles' orientation; a fan of each gives the surface."""
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (300, 3))
    inside = np.linalg.norm(points, axis=1) < 0.6
    vertices, polygons = voronoi_polygons(points, inside)
    surface_vertices, triangles = voronoi_surface(points, inside)
    np.testing.assert_array_equal(vertices, surface_vertices)  # no merged vertices here: nothing split
    fans = np.array([[polygon[0], a, b] for polygon in polygons for a, b in zip(polygon[1:-1], polygon[2:])])
    assert sorted(map(tuple, fans)) == sorted(map(tuple, triangles))
    for polygon in polygons:  # planar: every corner on the plane of the first three
        corners = vertices[polygon]
        normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        assert np.abs((corners - corners[0]) @ normal).max() <= 1e-9 * np.linalg.norm(normal)
    assert VoroMesh(points, inside).to_polygons()[1][0].tolist() == polygons[0].tolist()


def test_voronoi_polygons_of_a_lattice_are_squares():
    """Co-spherical corners merge: each face of a ball of cubes is one square."""
    axis = np.arange(-4, 5) * 0.1
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    inside = np.linalg.norm(points, axis=1) < 0.25
    vertices, polygons = voronoi_polygons(points, inside)
    grid = inside.reshape(9, 9, 9)
    assert len(polygons) == sum(np.count_nonzero(np.diff(grid.astype(int), axis=a)) for a in range(3))
    assert {len(polygon) for polygon in polygons} == {4}
    areas = [np.linalg.norm(np.cross(vertices[p[1]] - vertices[p[0]], vertices[p[3]] - vertices[p[0]])) for p in polygons]
    np.testing.assert_allclose(areas, 0.01, rtol=1e-6)


def test_voronoi_polygons_bad_input():
    with pytest.raises(ValueError, match="no outside"):
        voronoi_polygons(np.random.default_rng(0).random((10, 3)), np.ones(10, bool))
