import argparse
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from voro3d.batch import (EXIT_INTERRUPTED, EXIT_OK, EXIT_SOME_FAILED, RESULTS_NAME, ShapeTask, add_batch_parser,
                          process_shape, run_batch)
from voro3d.batch.local import _cpu_slots
from voro3d.batch.plan import _complete, _ResultsLog
from voro3d.infer import _cached_predictor as _predictor
from voro3d.infer import DEFAULT_MODEL
from voro3d.io import load_mesh, mesh_arrays, save_mesh
from voro3d.shapes import example_mesh
from voro3d.watertight import check_watertight

# Small enough that a shape takes well under a second: the tests are about the batch, not the fit.
FAST = dict(grid=16, steps=20)
CORRUPT = b"ply\nformat ascii 1.0\nelement vertex 3\nnot a number\n"
# The `voro3d batch` command exactly as the CLI runs it: parse, then `args.run(args)` is the exit code.
# Ctrl-C raises KeyboardInterrupt as at a terminal, even when the tests themselves were started in
# the background, where the shell hands every child an ignored SIGINT.
COMMAND = ("import argparse, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
           "from voro3d.batch import add_batch_parser; "
           "parser = argparse.ArgumentParser(); add_batch_parser(parser.add_subparsers()); "
           "args = parser.parse_args(sys.argv[1:]); sys.exit(args.run(args))")


def _inputs(folder: Path, names=("sphere", "torus", "knot"), *, corrupt: bool = False) -> Path:
    folder.mkdir(parents=True)
    suffixes = (".ply", ".obj", ".stl")
    for index, name in enumerate(names):
        # A subfolder and every suffix, to check that relative paths and formats carry over.
        sub = "parts/" if index % 2 else ""
        save_mesh(example_mesh(name.split("-")[0]), folder / f"{sub}{name}{suffixes[index % 3]}")
    if corrupt:
        (folder / "broken.ply").write_bytes(CORRUPT)
    return folder


def _open_sphere(path: Path) -> None:
    """A sphere with a hole: fitting needs a closed input."""
    vertices, triangles = mesh_arrays(example_mesh("sphere"))
    save_mesh((vertices, triangles[10:]), path)


def _rows(output: Path) -> list:
    """The rows of ``results.jsonl``; a last line still being written (no newline yet) is left out."""
    return [json.loads(line) for line in (output / RESULTS_NAME).read_text().split("\n")[:-1]]


def _files(output: Path) -> dict:
    """Every file under ``output`` (hidden ones too): relative path -> (bytes, mtime_ns)."""
    return {path.relative_to(output).as_posix(): (path.read_bytes(), path.stat().st_mtime_ns)
            for path in sorted(output.rglob("*")) if path.is_file()}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """Three shapes, a corrupt file and an open mesh on two local workers."""
    root = tmp_path_factory.mktemp("batch")
    inputs = _inputs(root / "in", corrupt=True)
    _open_sphere(inputs / "open.ply")
    summary = run_batch(inputs, root / "out", workers=2, **FAST)
    return inputs, root / "out", summary


def test_batch_writes_one_watertight_mesh_and_row_per_shape(first_run):
    _, output, summary = first_run
    rows = {row["input"]: row for row in _rows(output)}
    assert set(rows) == {"sphere.ply", "parts/torus.obj", "knot.stl", "broken.ply", "open.ply"}
    for name in ("sphere.ply", "parts/torus.obj", "knot.stl"):
        row = rows[name]
        assert row["status"] == "ok" and row["error"] is None
        assert row["output"] == str(Path(name).with_suffix(".ply"))
        mesh = load_mesh(output / row["output"], weld=False)
        assert check_watertight(mesh, self_intersection=False).watertight
        assert row["watertight"]["watertight"] and row["n_faces"] == len(mesh.triangles)
        assert row["output_bytes"] == (output / row["output"]).stat().st_size
        assert row["seconds"] > 0 and row["peak_memory_mb"] > 0
        assert row["metrics"] is None
        assert row["settings"] == {"method": "fit", "grid": 16, "steps": 20, "seed": 0, "model": None, "eval": False,
                                   "format": ".ply", "clean": True}
    assert summary.counts == {"ok": 3, "failed": 2, "timeout": 0}
    assert not [name for name in _files(output) if Path(name).name.startswith(".")]


def test_workers_are_pinned_to_one_cpu_each_by_default(first_run):
    _, output, _ = first_run
    cpus = sorted(os.sched_getaffinity(0))
    shares = {tuple(row["worker_cpus"]) for row in _rows(output) if row["status"] == "ok"}
    if len(cpus) < 2:
        assert shares == {tuple(cpus)}  # more workers than CPUs: left unpinned
        return
    assert all(len(share) == 1 for share in shares)
    assert all(set(a).isdisjoint(b) for a in shares for b in shares if a != b)


def test_threads_give_a_worker_that_many_cpus(tmp_path):
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        pytest.skip("needs two CPUs to give one worker two")
    inputs = _inputs(tmp_path / "in", names=("sphere",))
    summary = run_batch(inputs, tmp_path / "out", threads=2, **FAST)
    assert summary.workers == len(cpus) // 2
    assert [len(row["worker_cpus"]) for row in summary.rows] == [2]


def test_more_threads_than_cpus_warn(tmp_path):
    inputs = _inputs(tmp_path / "in", names=("sphere",))
    cpus = len(os.sched_getaffinity(0))
    with pytest.warns(UserWarning, match="exceed the"):
        summary = run_batch(inputs, tmp_path / "out", workers=1, threads=cpus + 1, **FAST)
    assert summary.counts["ok"] == 1 and summary.rows[0]["worker_cpus"] == sorted(os.sched_getaffinity(0))


def test_cpu_slots(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 5})
    assert _cpu_slots(2, 1) == [(0,), (1,)]
    assert _cpu_slots(2, 2) == [(0, 1), (2, 3)]
    assert _cpu_slots(5, 1) == [(0,), (1,), (2,), (3,), (5,)]
    assert _cpu_slots(1, 5) == [(0, 1, 2, 3, 5)]
    assert _cpu_slots(6, 1) == [None] * 6  # more workers than CPUs: the OS schedules them
    assert _cpu_slots(3, 2) == [None] * 3


# The thread count of row-wise numpy work and winding numbers follows the CPU affinity that
# voro3d is imported under (a local worker pins itself first), and a batch worker keeps them to its
# ``threads`` (one here) when it is not pinned (Ray's workers, or more workers x threads than CPUs).
_ROW_THREADS_IN_A_WORKER = """
import os, sys
if sys.argv[2] == "pinned":
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from voro3d import rowblocks
from voro3d.batch.worker import _prepare
before = rowblocks.ROW_THREADS
_prepare("learned", sys.argv[1], 1)
print(before, rowblocks.ROW_THREADS)
"""


@pytest.mark.parametrize("affinity", ["pinned", "free"])
def test_worker_threads_follow_the_worker_affinity_and_threads(affinity):
    cpus = min(4, len(os.sched_getaffinity(0)))
    if cpus < 2:
        pytest.skip("needs two CPUs for the winding number to use more than one thread")
    result = subprocess.run([sys.executable, "-c", _ROW_THREADS_IN_A_WORKER, str(DEFAULT_MODEL), affinity],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    before = "1" if affinity == "pinned" else str(cpus)
    assert result.stdout.split() == [before, "1"]


# Without fcntl, resource and msvcrt (as on a platform that lacks them) the CLI still starts; only
# memory_limit_mb, which needs RLIMIT_AS, is refused.
_WITHOUT_POSIX_MODULES = """
import sys

BLOCKED = {"fcntl", "resource", "msvcrt"}


class Missing:
    def find_spec(self, name, path=None, target=None):
        if name in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)


for name in BLOCKED:
    sys.modules.pop(name, None)
sys.meta_path.insert(0, Missing())
from voro3d.batch import run_batch
from voro3d.batch.worker import _cpu_seconds, _peak_memory_mb
from voro3d.cli import main

for argv in (["--help"], ["batch", "--help"]):
    try:
        main(argv)
    except SystemExit as done:
        assert done.code == 0, (argv, done.code)
assert _cpu_seconds() > 0 and _peak_memory_mb() > 0
try:
    run_batch(sys.argv[1], sys.argv[2], memory_limit_mb=64)
except ValueError as error:
    print(error)
"""


def test_cli_starts_without_fcntl_and_resource(tmp_path):
    inputs = _inputs(tmp_path / "in", names=("sphere",))
    result = subprocess.run([sys.executable, "-c", _WITHOUT_POSIX_MODULES, str(inputs), str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "usage: voro3d batch" in result.stdout
    assert "memory_limit_mb needs the resource module" in result.stdout
    assert not (tmp_path / "out").exists()


def test_corrupt_and_open_inputs_are_recorded_and_set_the_exit_code(first_run):
    _, output, summary = first_run
    rows = {row["input"]: row for row in _rows(output)}
    assert rows["broken.ply"]["status"] == rows["open.ply"]["status"] == "failed"
    assert "could not be read" in rows["broken.ply"]["error"]
    assert "edges not shared by exactly two triangles" in rows["open.ply"]["error"]
    assert not (output / "broken.ply").exists() and not (output / "open.ply").exists()
    assert summary.exit_code == EXIT_SOME_FAILED == 1
    failures = summary.table().split("failures:")[1]
    assert "broken.ply" in failures and "open.ply" in failures


def test_a_row_counts_only_for_the_same_settings_and_file(first_run):
    _, output, _ = first_run
    row = next(row for row in _rows(output) if row["input"] == "sphere.ply")
    assert _complete(row, row["settings"], output / row["output"])
    assert not _complete(row, {**row["settings"], "seed": 1}, output / row["output"])
    assert not _complete(row, row["settings"], output / "missing.ply")
    assert not _complete({**row, "output_bytes": row["output_bytes"] + 1}, row["settings"], output / row["output"])
    broken = next(row for row in _rows(output) if row["input"] == "broken.ply")
    assert not _complete(broken, broken["settings"], output / "broken.ply")  # failed shapes are retried


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def _start(inputs: Path, output: Path) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, "-c", COMMAND, "batch", str(inputs), str(output), "--grid", "16",
                                "--steps", "40", "--workers", "1", "--quiet"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not (output / RESULTS_NAME).is_file() or not _rows(output):
        assert process.poll() is None, process.communicate()[1].decode()
        assert time.monotonic() < deadline, "no shape finished within 60 s"
        time.sleep(0.02)
    return process


@pytest.mark.parametrize("how", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_killed_batch_keeps_finished_meshes_and_resumes(tmp_path, how):
    names = ("sphere", "torus", "knot", "sphere-2", "torus-2", "knot-2")
    inputs = _inputs(tmp_path / "in", names)
    output = tmp_path / "out"
    process = _start(inputs, output)
    process.send_signal(how)
    _, stderr = process.communicate(timeout=60)
    if how == signal.SIGINT:
        assert process.returncode == EXIT_INTERRUPTED, stderr.decode()
        assert b"rerun the same command to resume" in stderr
        # The batch cleaned up after itself: only finished meshes and the rows.
        assert not [name for name in _files(output) if Path(name).name.startswith(".")]
    else:
        assert process.returncode == -signal.SIGKILL
        # Its worker dies with it (PR_SET_PDEATHSIG) instead of writing on as an orphan...
        workers = {row["worker_pid"] for row in _rows(output)}
        deadline = time.monotonic() + 10
        while any(_running(pid) for pid in workers):
            assert time.monotonic() < deadline, "a worker outlived the killed batch"
            time.sleep(0.05)
        # ... but whatever it was writing stays behind; here is such a leftover, for the rerun to sweep.
        (output / ".sphere.abcd_123.ply").write_bytes(b"half a mesh")
        (output / ".keep").write_bytes(b"not ours")
    done = {row["output"] for row in _rows(output) if row["status"] == "ok"}
    assert done and len(done) < len(names), "kill the batch midway"
    kept = {name: stat for name, stat in _files(output).items() if name in done}

    summary = run_batch(inputs, output, workers=1, grid=16, steps=40)
    assert summary.exit_code == EXIT_OK
    assert len(summary.skipped) == len(done)
    files = _files(output)
    assert {name: files[name] for name in kept} == kept  # same bytes, same mtime
    ours = {name: stat for name, stat in files.items() if name != ".keep"}
    assert sorted(ours) == sorted([RESULTS_NAME] + [row["output"] for row in summary.rows])
    assert all(check_watertight(load_mesh(output / row["output"], weld=False), self_intersection=False).watertight
               for row in summary.rows)
    # A third run has nothing left to do: it starts no worker and writes nothing.
    again = run_batch(inputs, output, workers=1, grid=16, steps=40)
    assert len(again.skipped) == len(names) and again.rows_of_this_run == []
    assert _files(output) == files


def test_timeout_kills_the_shape_and_the_batch_goes_on(tmp_path):
    inputs = _inputs(tmp_path / "in", ("sphere",), corrupt=True)
    summary = run_batch(inputs, tmp_path / "out", workers=1, grid=16, steps=200_000, timeout=1.0)
    rows = {row["input"]: row for row in summary.rows}
    assert rows["sphere.ply"]["status"] == "timeout"
    assert "no result after 1 s" in rows["sphere.ply"]["error"]
    assert 1.0 <= rows["sphere.ply"]["seconds"] < 10
    # The biggest file goes first, so the corrupt one ran on the worker that replaced the killed one.
    assert rows["broken.ply"]["status"] == "failed"
    assert rows["broken.ply"]["worker_pid"] != rows["sphere.ply"]["worker_pid"]
    assert summary.exit_code == EXIT_SOME_FAILED
    assert sorted(_files(tmp_path / "out")) == [RESULTS_NAME]


def test_memory_limit_fails_the_shape_and_is_lifted_after_it_and_eval_adds_metrics(tmp_path):
    source = tmp_path / "sphere.ply"
    save_mesh(example_mesh("sphere"), source)
    # Grid 64: its samples and candidates (tens of MB) outgrow whatever memory the warm-up freed, which
    # a grid-32 fit on the compiled CPU loop (a few MB) could reuse without the cap noticing.
    capped = ShapeTask(str(source), str(tmp_path / "out" / "capped.ply"), "fit", 64, 1, 0, None, 1, False, 1)
    # In a fresh process: this one may already hold freed memory that the fit would reuse
    # without growing its address space, and then the cap never bites.
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        result = pool.apply(process_shape, (capped,))
    assert result["status"] == "failed"
    assert "memory" in result["error"].lower()
    free = ShapeTask(str(source), str(tmp_path / "out" / "free.ply"), "fit", 16, 20, 0, None, 1, True, None)
    result = process_shape(free)
    assert result["status"] == "ok"
    assert 0 < result["metrics"]["chamfer_x1e5"] < 50 and result["metrics"]["f1"] > 0.5
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["free.ply"]


def test_learned_method_loads_the_model_once_per_worker(tmp_path):
    inputs = _inputs(tmp_path / "in", ("sphere", "torus"))
    summary = run_batch(inputs, tmp_path / "out", method="learned", workers=1, grid=32)
    assert summary.exit_code == EXIT_OK, summary.table()
    for row in summary.rows:
        assert row["settings"]["model"] == str(DEFAULT_MODEL.resolve()) and row["settings"]["steps"] is None
        assert row["watertight"]["watertight"]
    # In one process, as in each worker: the session is built once, then reused.
    _predictor.cache_clear()
    for name in ("sphere.ply", "parts/torus.obj"):
        task = ShapeTask(str(inputs / name), str(tmp_path / "again" / f"{Path(name).stem}.ply"), "learned", 32, 1,
                         0, str(DEFAULT_MODEL.resolve()), 1, False, None)
        assert process_shape(task)["status"] == "ok"
    assert _predictor.cache_info().misses == 1


def test_ray_engine_gives_the_local_engine_bytes(first_run, tmp_path):
    pytest.importorskip("ray", reason="the Ray engine needs the optional dependency: pip install 'voro3d[ray]'")
    inputs, local, _ = first_run
    summary = run_batch(inputs, tmp_path / "ray", workers=2, engine="ray", **FAST)
    assert summary.counts == {"ok": 3, "failed": 2, "timeout": 0}
    assert summary.exit_code == EXIT_SOME_FAILED
    for row in summary.rows:
        if row["status"] == "ok":
            assert (tmp_path / "ray" / row["output"]).read_bytes() == (local / row["output"]).read_bytes()
            assert row["engine"] == "ray"


def test_command_line_parses_every_option(tmp_path):
    parser = argparse.ArgumentParser()
    add_batch_parser(parser.add_subparsers())
    args = parser.parse_args(["batch", "in", "out", "--method", "learned", "--grid", "64", "--workers", "3",
                              "--threads", "2", "--engine", "ray", "--ray-address", "auto", "--eval", "--timeout", "2.5",
                              "--memory-limit", "4096", "--steps", "10", "--format", "obj", "--quiet"])
    assert (args.method, args.grid, args.workers, args.threads, args.engine, args.ray_address, args.evaluate,
            args.timeout, args.memory_limit, args.steps, args.format, args.quiet) == (
        "learned", 64, 3, 2, "ray", "auto", True, 2.5, 4096, 10, "obj", True)
    assert callable(args.run)


@pytest.mark.parametrize("options, match", [
    (dict(method="poisson"), "method"),
    (dict(engine="dask"), "engine"),
    (dict(ray_address="auto"), "ray_address"),
    (dict(grid=1), "grid"),
    (dict(steps=0), "steps"),
    (dict(method="learned", steps=10), "method='learned' takes no steps"),
    (dict(model="voromesh.onnx"), "method='fit' takes no model"),
    (dict(workers=0), "workers"),
    (dict(threads=0), "threads"),
    (dict(timeout=0), "timeout"),
    (dict(memory_limit_mb=0), "memory_limit_mb"),
    (dict(suffix=".xyz"), "suffix"),
])
def test_bad_arguments_are_named(tmp_path, options, match):
    (tmp_path / "in").mkdir()
    with pytest.raises(ValueError, match=match):
        run_batch(tmp_path / "in", tmp_path / "out", **options)


def test_bad_folders_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="input_dir"):
        run_batch(tmp_path / "missing", tmp_path / "out")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no mesh file"):
        run_batch(empty, tmp_path / "out")
    with pytest.raises(ValueError, match="output_dir must differ"):
        run_batch(empty, empty)
    clash = tmp_path / "clash"
    clash.mkdir()
    (clash / "a.obj").write_bytes(CORRUPT)
    (clash / "a.stl").write_bytes(CORRUPT)
    with pytest.raises(ValueError, match="would both write"):
        run_batch(clash, tmp_path / "out")
    with pytest.raises(FileNotFoundError, match="ONNX model"):
        run_batch(clash, tmp_path / "out2", method="learned", model=tmp_path / "none.onnx")


def test_a_second_batch_on_the_same_output_is_refused(first_run):
    inputs, output, _ = first_run
    with _ResultsLog(output / RESULTS_NAME):
        with pytest.raises(ValueError, match="in use by another voro3d batch"):
            run_batch(inputs, output, **FAST)


def test_a_row_torn_by_a_crash_is_ignored_and_not_continued(tmp_path):
    path = tmp_path / RESULTS_NAME
    path.write_text('{"input": "a.ply", "status": "ok"}\n{"input": "b.ply", "sta')
    with _ResultsLog(path) as log:
        assert list(log.latest) == ["a.ply"]
        log.append({"input": "c.ply", "status": "failed"})
    lines = path.read_text().splitlines()
    assert json.loads(lines[-1]) == {"input": "c.ply", "status": "failed"}
    assert lines[1] == '{"input": "b.ply", "sta'
