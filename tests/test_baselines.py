"""Tests for voro3d.baselines: Marching Cubes and Dual Contouring from SDF grids."""

import numpy as np
import open3d as o3d
import pytest

from voro3d.baselines import dual_contouring, marching_cubes
from voro3d.frames import fit_frame
from voro3d.io import load_mesh
from voro3d.metrics import evaluate
from voro3d.queries import sdf_grid
from voro3d.sampling import grid_nodes
from voro3d.topology import open_edge_count
from voro3d.watertight import check_watertight, signed_volume


RADIUS = 0.6
GRID = 32


def area(vertices, triangles):
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()


def box_sdf(half):
    """Exact SDF of the axis-aligned box [-half, half]^3 at the grid nodes."""
    q = np.abs(grid_nodes(GRID)) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return (outside + np.minimum(q.max(axis=1), 0)).reshape((GRID,) * 3)


@pytest.fixture(scope="module")
def sphere_sdf():
    return (np.linalg.norm(grid_nodes(GRID), axis=1) - RADIUS).reshape((GRID,) * 3)


@pytest.fixture(scope="module")
def sphere_mesh():
    return o3d.geometry.TriangleMesh.create_sphere(RADIUS, 80)


@pytest.fixture(scope="module")
def results(sphere_sdf, sphere_mesh):
    return {"mc": marching_cubes(sphere_sdf), "dc": dual_contouring(sphere_sdf, sphere_mesh)}


@pytest.mark.parametrize("method", ["mc", "dc"])
def test_sphere_is_closed_outward_and_accurate(results, method):
    vertices, triangles = results[method]
    assert vertices.dtype == np.float64 and triangles.dtype == np.int64
    assert vertices.shape[1] == triangles.shape[1] == 3
    assert (np.abs(vertices) <= 1).all()
    report = check_watertight((vertices, triangles), self_intersection=False)
    assert report.closed and report.consistently_oriented
    assert signed_volume(vertices, triangles) > 0
    assert signed_volume(vertices, triangles) == pytest.approx(4 / 3 * np.pi * RADIUS**3, rel=0.02)
    assert area(vertices, triangles) == pytest.approx(4 * np.pi * RADIUS**2, rel=0.02)


def test_vertices_are_close_to_the_sphere(results):
    step = 2 / (GRID - 1)
    for method, tolerance in (("mc", 0.05 * step), ("dc", 0.1 * step)):
        vertices, _ = results[method]
        assert np.abs(np.linalg.norm(vertices, axis=1) - RADIUS).max() < tolerance, method


def test_dual_contouring_keeps_sharp_corners_that_marching_cubes_cuts():
    half = 0.53  # off the grid nodes, so every face crosses edges at a fractional parameter
    sdf = box_sdf(half)
    box = o3d.geometry.TriangleMesh.create_box(2 * half, 2 * half, 2 * half).translate([-half] * 3)
    corners = np.array([[sx, sy, sz] for sx in (-half, half) for sy in (-half, half) for sz in (-half, half)])
    dc_vertices, dc_triangles = dual_contouring(sdf, box)
    mc_vertices, mc_triangles = marching_cubes(sdf)
    dc_gap = np.linalg.norm(dc_vertices[None] - corners[:, None], axis=2).min(axis=1)
    mc_gap = np.linalg.norm(mc_vertices[None] - corners[:, None], axis=2).min(axis=1)
    # The regulariser pulls corners towards the cell's mass point by about 1% of the gap.
    assert dc_gap.max() < 2e-3
    assert mc_gap.min() > 10 * dc_gap.max()
    volume = (2 * half) ** 3
    assert signed_volume(dc_vertices, dc_triangles) == pytest.approx(volume, rel=1e-3)
    assert signed_volume(mc_vertices, mc_triangles) < (1 - 1e-2) * volume


def test_outside_in_sdf_gives_the_opposite_orientation(sphere_sdf, sphere_mesh):
    # Negating the SDF swaps inside and outside: the same surface, facing the other way.
    for method in (marching_cubes, lambda s: dual_contouring(s, sphere_mesh)):
        vertices, triangles = method(-sphere_sdf)
        assert signed_volume(vertices, triangles) < 0


def test_deterministic(sphere_sdf, sphere_mesh):
    first = dual_contouring(sphere_sdf, sphere_mesh)
    again = dual_contouring(sphere_sdf, sphere_mesh)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])


@pytest.mark.parametrize("sdf, match", [
    (np.ones((8, 8, 8)), r"no zero crossing: values span \[1, 1\]"),
    (-np.ones((8, 8, 8)), r"no zero crossing: values span \[-1, -1\]"),
    (np.zeros((8, 8, 8)), "no zero crossing"),
    (np.minimum(np.arange(8.0) - 3, 0)[:, None, None] * np.ones((8, 8, 8)), "no zero crossing"),
    (np.ones((8, 8)), r"shape \(g, g, g\)"),
    (np.ones((8, 8, 9)), r"shape \(g, g, g\)"),
    (np.ones((1, 1, 1)), r"g >= 2"),
    (np.full((4, 4, 4), np.nan), "NaN or inf"),
    (np.full((4, 4, 4), "a"), "floating-point or integer"),
    (np.ones((4, 4, 4), bool), "floating-point or integer"),
])
def test_sdf_errors(sdf, match, sphere_mesh):
    with pytest.raises(ValueError, match=match):
        marching_cubes(sdf)
    with pytest.raises(ValueError, match=match):
        dual_contouring(sdf, sphere_mesh)


def test_dual_contouring_mesh_errors(sphere_sdf):
    with pytest.raises(ValueError, match="no triangles"):
        dual_contouring(sphere_sdf, (np.zeros((3, 3)), np.zeros((0, 3), int)))
    with pytest.raises(TypeError, match="mesh must be"):
        dual_contouring(sphere_sdf, "sphere.ply")


@pytest.mark.parametrize("name", ["organic_bunny.off", "cad_fandisk.obj"])
def test_dev_meshes(dev_meshes, name):
    gt = load_mesh(dev_meshes / name)
    gt = fit_frame(gt).apply_mesh(gt)
    sdf = sdf_grid(gt, GRID)
    mc = marching_cubes(sdf)
    dc = dual_contouring(sdf, gt)
    assert check_watertight(mc, self_intersection=False).watertight
    # DC joins the two sheets of thin parts in one cell: a few non-manifold edges are allowed.
    assert open_edge_count(*dc) < 0.01 * dc[1].shape[0]
    assert signed_volume(*mc) > 0 and signed_volume(*dc) > 0
    mc_scores = evaluate(mc, gt, n_samples=30_000)
    dc_scores = evaluate(dc, gt, n_samples=30_000)
    # Hermite normals let DC follow the surface between nodes better than MC at the same grid.
    assert dc_scores["chamfer"] < mc_scores["chamfer"]
    assert dc_scores["nc"] > mc_scores["nc"] > 0.9
