"""Bundled example shapes: closed, outward, small, deterministic."""
import hashlib
import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from voro3d.shapes import example_mesh, example_names


def _digest(mesh) -> str:
    vertices = np.ascontiguousarray(np.asarray(mesh.vertices), dtype=np.float64)
    triangles = np.ascontiguousarray(np.asarray(mesh.triangles), dtype=np.int64)
    return hashlib.sha256(vertices.tobytes() + triangles.tobytes()).hexdigest()


def test_names_cover_the_promised_shapes():
    names = example_names()
    assert {"sphere", "torus", "bracket"} <= set(names)
    assert {"knot", "blob"} & set(names)
    assert example_names() == names  # fixed order


@pytest.mark.parametrize("name", example_names())
def test_example_is_watertight_outward_and_small(name):
    mesh = example_mesh(name)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    solid = trimesh.Trimesh(vertices, triangles, process=False)
    assert solid.is_watertight
    assert solid.is_winding_consistent
    assert solid.volume > 0  # outward normals
    assert 0 < len(triangles) <= 50_000
    # Centred on the origin, largest half-extent 1.
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    np.testing.assert_allclose((low + high) / 2, 0.0, atol=1e-12)
    assert (high - low).max() / 2 == pytest.approx(1.0)


def test_default_is_the_bracket():
    assert _digest(example_mesh()) == _digest(example_mesh("bracket"))


def test_bracket_has_holes():
    # Three through-holes make genus 3: Euler characteristic V - E + F = 2 - 2g.
    solid = trimesh.Trimesh(np.asarray(example_mesh("bracket").vertices), np.asarray(example_mesh("bracket").triangles),
                            process=False)
    assert solid.euler_number == 2 - 2 * 3


def test_sphere_matches_analytic_volume_and_area():
    solid = trimesh.Trimesh(np.asarray(example_mesh("sphere").vertices), np.asarray(example_mesh("sphere").triangles),
                            process=False)
    assert len(solid.faces) == 5120
    assert solid.volume == pytest.approx(4 / 3 * math.pi, rel=0.01)
    assert solid.area == pytest.approx(4 * math.pi, rel=0.01)


def test_torus_genus_one():
    solid = trimesh.Trimesh(np.asarray(example_mesh("torus").vertices), np.asarray(example_mesh("torus").triangles),
                            process=False)
    assert solid.euler_number == 0


def test_calls_return_independent_copies():
    first = example_mesh("torus")
    before = _digest(example_mesh("torus"))
    np.asarray(first.vertices)[:] = 0.0  # scribbling on one copy must not reach the next
    assert _digest(example_mesh("torus")) == before


def test_deterministic_across_processes():
    names = example_names()
    code = ("import hashlib, numpy as np\n"
            "from voro3d.shapes import example_mesh\n"
            f"for name in {names!r}:\n"
            "    m = example_mesh(name)\n"
            "    v = np.ascontiguousarray(np.asarray(m.vertices), dtype=np.float64)\n"
            "    t = np.ascontiguousarray(np.asarray(m.triangles), dtype=np.int64)\n"
            "    print(hashlib.sha256(v.tobytes() + t.tobytes()).hexdigest())\n")
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert child.stdout.split() == [_digest(example_mesh(name)) for name in names]


@pytest.mark.parametrize("name", ["teapot", "", "Sphere", None, 3])
def test_unknown_name_lists_valid_names(name):
    with pytest.raises(ValueError, match=r"name must be one of \[.*'sphere'.*'bracket'.*\]"):
        example_mesh(name)
