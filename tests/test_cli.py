"""The ``voro3d`` command as a person meets it: paths checked first, flags in errors, one grid rule."""
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from voro3d.cli import build_parser, flag_names, main
from voro3d.io import load_points, save_mesh
from voro3d.shapes import example_mesh


@pytest.fixture
def knot(tmp_path):
    path = tmp_path / "knot.ply"
    save_mesh(example_mesh("knot"), path)
    return path


@pytest.fixture
def cloud(tmp_path):
    path = tmp_path / "cloud.ply"
    assert main(["example", "bracket", "--points", "3000", "-o", str(path), "-q"]) == 0
    return path


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    return err[-1]


@pytest.mark.parametrize("arguments, match", [
    (["-o", "{tmp}/out.xyz"], "must end in one of .ply"),
    (["-o", "{tmp}/missing/out.ply"], "does not exist"),
    (["-o", "{tmp}/out.ply", "--png", "{tmp}/x.jpg"], "must end in .png"),
    (["-o", "{tmp}/out.ply", "--grid", "3"], "must be 'auto' or an integer >= 4, got '3'"),
    (["-o", "{tmp}/out.ply", "--grid", "fine"], "must be 'auto' or an integer >= 4"),
    (["-o", "{tmp}/out.ply", "--steps", "0"], "must be an integer >= 1"),
    (["-o", "{tmp}/out.ply", "--engine", "dask"], "invalid choice: 'dask'"),
    (["-o", "{tmp}/out.ply", "--workers", "0"], "must be an integer >= 1"),
])
def test_bad_options_are_refused_before_any_work(tmp_path, cloud, capsys, arguments, match):
    start = time.perf_counter()
    with pytest.raises(SystemExit) as stopped:
        main(["reconstruct", str(cloud)] + [a.format(tmp=tmp_path) for a in arguments])
    assert stopped.value.code == 2 and match in _error(capsys)
    assert time.perf_counter() - start < 2.0  # no reconstruction ran
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cloud.ply"]


def test_fit_takes_the_same_grid_rule(tmp_path, knot, capsys):
    with pytest.raises(SystemExit):
        main(["fit", str(knot), "-o", str(tmp_path / "a.ply"), "--grid", "3"])
    assert "--grid" in _error(capsys)
    assert main(["fit", str(knot), "-o", str(tmp_path / "a.ply"), "--grid", "auto", "--steps", "5", "-q"]) == 0


@pytest.mark.parametrize("extra, match", [
    (["--denoise", "on"], "--normals, --denoise, --filter, --target and --hull apply to point clouds only"),
    (["--hull", "on"], "--normals, --denoise, --filter, --target and --hull apply to point clouds only"),
    (["--method", "learned", "--steps", "5"], "--method learned takes no --steps (only --method fit uses it)"),
])
def test_errors_name_the_flags(tmp_path, knot, capsys, extra, match):
    assert main(["reconstruct", str(knot), "-o", str(tmp_path / "a.ply")] + extra) == 2
    assert _error(capsys) == f"voro3d reconstruct: error: {match}"
    assert not (tmp_path / "a.ply").exists()


def test_an_open_mesh_has_a_way_through(tmp_path, capsys):
    mesh = example_mesh("knot")
    mesh.triangles = type(mesh.triangles)(np.asarray(mesh.triangles)[40:])
    source = tmp_path / "open.ply"
    save_mesh(mesh, source)
    out = tmp_path / "a.ply"
    assert main(["reconstruct", str(source), "-o", str(out), "--grid", "16", "--steps", "5", "-q"]) == 2
    message = _error(capsys)
    assert "pass --allow-open" in message and "(--sample N)" in message and "allow_open" not in message
    assert main(["reconstruct", str(source), "-o", str(out), "--grid", "16", "--steps", "5", "-q",
                 "--allow-open"]) == 0
    assert out.exists()
    sampled = tmp_path / "b.ply"
    assert main(["reconstruct", str(source), "-o", str(sampled), "--grid", "16", "--steps", "5", "-q",
                 "--sample", "5000"]) == 0
    assert sampled.exists()


def test_example_writes_a_mesh_and_a_cloud(tmp_path):
    assert main(["example", "torus", "-o", str(tmp_path / "torus.obj"), "-q"]) == 0
    assert main(["example", "torus", "--points", "500", "-o", str(tmp_path / "torus.xyz"), "-q"]) == 0
    read = load_points(tmp_path / "torus.xyz")
    assert np.asarray(read.points).shape == (500, 3) and read.has_normals()
    assert main(["example", "torus", "--points", "500", "--no-normals", "-o", str(tmp_path / "t.npy"), "-q"]) == 0
    assert np.load(tmp_path / "t.npy").shape == (500, 3)


def test_every_subcommand_has_help_and_an_example():
    parser = build_parser()
    commands = parser._subparsers._group_actions[0]
    assert len(commands.choices) >= 10
    for name, sub in commands.choices.items():
        text = sub.format_help()
        assert "example:\n  " in text, name
        for action in sub._actions:
            if action.option_strings and action.dest != "help":
                assert action.help, f"{name} {action.option_strings} has no help"


def test_the_step_defaults_people_read_are_the_fits():
    # The CLI keeps its imports light, so its help states the cloud fit's default steps as a literal,
    # as do the two docstrings a user reads first: each must say what CLOUD_STEPS is.
    import voro3d
    from voro3d.pointcloud.reconstruct import reconstruct_points
    from voro3d.pointcloud.tuning import CLOUD_STEPS

    steps = build_parser()._subparsers._group_actions[0].choices["reconstruct"]._option_string_actions["--steps"]
    assert f"400 for a mesh, {CLOUD_STEPS} for a point cloud" in steps.help
    assert f"400 steps for a mesh, {CLOUD_STEPS} for a" in " ".join(voro3d.reconstruct.__doc__.split())
    assert f"(400 steps, {CLOUD_STEPS} for a cloud," in voro3d.__doc__
    assert f"``CLOUD_STEPS`` = {CLOUD_STEPS}," in reconstruct_points.__doc__


def test_python_dash_m_runs_the_command():
    done = subprocess.run([sys.executable, "-m", "voro3d", "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "reconstruct" in done.stdout and "start here" in done.stdout


def test_progress_in_a_log_is_phase_lines_not_a_bar(tmp_path, cloud):
    """stderr not a terminal (a log): the phase lines, and no tqdm bar printing a line per update."""
    done = subprocess.run([sys.executable, "-m", "voro3d", "reconstruct", str(cloud), "-o", str(tmp_path / "a.ply"),
                           "--grid", "16", "--steps", "20"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert any(line.startswith("voro3d fit") for line in lines) and "VoroMesh fit:" not in done.stderr
    # A closed cloud's Poisson target names its octree depth (what a user compares Poisson at).
    assert any(re.match(r"voro3d target +poisson depth \d+, closed", line) for line in lines), done.stderr
    assert len(lines) <= 8


def test_warnings_are_one_line_each(tmp_path, cloud, capsys):
    """An organized scan's NaN points are left out with a warning: one line naming the command, not
    a Python source location."""
    points = np.asarray(load_points(cloud).points).copy()
    points[::30] = np.nan
    np.save(tmp_path / "organized.npy", points)
    assert main(["reconstruct", str(tmp_path / "organized.npy"), "-o", str(tmp_path / "a.ply"), "--grid", "16",
                 "--steps", "5", "-q"]) == 0
    err = capsys.readouterr().err
    assert "voro3d reconstruct: warning: " in err and "100 of 3,000 points have NaN or inf coordinates" in err
    assert "UserWarning" not in err and ".py:" not in err


def test_flag_names():
    assert flag_names("grid must be 'auto' or an integer >= 4, got 3") == "--grid must be 'auto' or an integer >= 4, got 3"
    assert flag_names("method='learned' takes no steps or seed (only method='fit' uses them)") == \
        "--method learned takes no --steps or --seed (only --method fit uses them)"
    assert flag_names("pass allow_open=True to decide it") == "pass --allow-open to decide it"
    assert flag_names("the points fill a volume") == "the points fill a volume"


@pytest.mark.parametrize("arguments, match", [
    (["--points", "100", "-o", "{tmp}/s.xyzrgb"], "must end in one of"),
    (["--points", "100", "-o", "{tmp}/s.obj"], "--points is written as one of .ply .pcd .xyz .xyzn .pwn .npy"),
    (["-o", "{tmp}/s.xyz"], "a mesh is written as one of"),
])
def test_example_refuses_formats_it_cannot_write(tmp_path, capsys, arguments, match):
    try:
        status = main(["example", "torus"] + [a.format(tmp=tmp_path) for a in arguments])
    except SystemExit as stopped:
        status = stopped.code
    assert status == 2 and match in _error(capsys) and not list(tmp_path.iterdir())
