"""Many meshes to watertight VoroMeshes: a resumable batch over a folder, on local processes or Ray.

``voro3d batch INPUT_DIR OUTPUT_DIR`` reconstructs every mesh file under ``INPUT_DIR`` (suffixes
:data:`voro3d.io.MESH_SUFFIXES`, searched recursively; hidden files and folders are skipped) to the
same relative path under ``OUTPUT_DIR`` with the output format's suffix, and appends one JSON row
per shape to ``OUTPUT_DIR/results.jsonl`` (fields: :func:`run_batch`).

Safety and resuming
-------------------
* A shape's mesh is written only once it is known to be watertight, atomically
  (:func:`voro3d.io.save_mesh`: a temporary file beside it, then a rename), then fsynced; only
  then is its row appended to ``results.jsonl`` and fsynced. A row with ``"status": "ok"``
  therefore always stands for a complete mesh on disk.
* A rerun skips a shape when its latest row says ``ok``, was made with the same settings (method,
  grid, steps, seed, model, eval, format) and its output file still has the size that row
  recorded. Everything else is done again: failed and timed-out shapes, shapes never started,
  and shapes whose mesh was written but whose row was not (the rerun replaces that mesh, bit for
  bit the same). The latest row of a shape is the one that counts; older rows stay as history.
* A shape cut short (its worker killed on timeout or crashed, the batch interrupted) leaves no
  file: its temporary file is removed when the shape is abandoned, and, when the batch itself was
  killed and could not clean up, by the next run at its start. A row torn by a crash mid-write
  is ignored. One batch at a time may write to an output folder: it holds an exclusive lock on
  ``results.jsonl`` while it runs.

Isolation
---------
Every shape runs in a worker process, never in the batch's own, so that it can be stopped and so
that a crash (a segfault in a native library, the kernel's out-of-memory killer) costs only that
shape. The same function, :func:`process_shape`, runs every shape on both engines, which is why
their outputs are identical bit for bit.

* ``timeout``: the local engine runs a pool of worker processes that each take one shape at a
  time over a pipe; a worker whose shape overruns is killed (SIGKILL) and replaced by a fresh one.
  The Ray engine cancels the task with ``force=True``, which kills the Ray worker running it.
  The clock starts when the shape is handed to a worker; a local worker has already paid its
  imports (and loaded the ONNX model) by then, and Ray workers are warmed up the same way first.
* ``memory_limit_mb`` (POSIX only: it needs the ``resource`` module): for the length of each
  shape the worker lowers its soft ``RLIMIT_AS``
  (:func:`resource.setrlimit`) to its current address space plus the limit, so an allocation
  beyond it fails (``MemoryError``, or the native library's equivalent) and the shape is
  recorded as failed. It bounds the *virtual* memory a shape adds, which exceeds the resident
  memory it uses (thread stacks, allocator arenas), so leave room: two to four times the
  ``peak_memory_mb`` that rows report.

Exit codes of ``voro3d batch``: 0 every shape is ok (skipped ones included), 1 some shape failed or
timed out (:data:`EXIT_SOME_FAILED`), 2 bad arguments, 130 interrupted (finished shapes are kept;
rerun the same command to resume).
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import json
import logging
import math
import multiprocessing
import multiprocessing.connection
import os
import re
import signal
import sys
import threading
import time
import warnings
from collections import Counter, defaultdict, deque
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from ._system import available_cpus
from ._validate import positive_int
from .io import MESH_SUFFIXES

METHODS = ("fit", "learned")
ENGINES = ("local", "ray")
RESULTS_NAME = "results.jsonl"
EXIT_OK = 0
EXIT_SOME_FAILED = 1
EXIT_INTERRUPTED = 130

# The temporary files of voro3d.io.atomic_path: tempfile.mkstemp(prefix=".{stem}.", suffix) adds
# eight characters from this alphabet.
_PARTIAL = re.compile(r"\.(?P<stem>.+)\.[a-z0-9_]{8}(?P<suffix>\.[^.]+)")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# A local worker that dies this many times in a row before it is ready is not a shape's fault.
_STARTUP_ATTEMPTS = 3
# Seconds a force-cancelled Ray task gets to be reported dead before its files are swept anyway.
_RAY_CANCEL_WAIT = 30.0


@dataclass(frozen=True)
class ShapeTask:
    """One shape for a worker: everything :func:`process_shape` needs, picklable.

    Attributes
    ----------
    source, output : str
        Absolute paths of the input mesh and of the mesh to write.
    method : str
        ``"fit"`` or ``"learned"``.
    grid, steps, seed : int
        As for :func:`voro3d.fitting.fit` (``steps`` unused by ``"learned"``; ``seed`` also seeds the metrics).
    model : str or None
        Absolute path of the ONNX model for ``"learned"``.
    threads : int
        Threads of the worker (torch for ``"fit"``, onnxruntime for ``"learned"``).
    evaluate : bool
        Compute :func:`voro3d.metrics.evaluate` against the input.
    memory_limit_mb : int or None
        Address space the shape may add, in MiB (module docstring).
    """

    source: str
    output: str
    method: str
    grid: int
    steps: int
    seed: int
    model: str | None
    threads: int
    evaluate: bool
    memory_limit_mb: int | None


@dataclass(frozen=True)
class BatchSummary:
    """What :func:`run_batch` did.

    Attributes
    ----------
    rows : tuple of dict
        The latest ``results.jsonl`` row of every input, in input order: written by this run, or
        the earlier one that let the shape be skipped.
    skipped : tuple of str
        Inputs already done by an earlier run (relative paths, as in ``rows``).
    seconds : float
        Wall-clock time of the run.
    workers : int
    engine : str
    """

    rows: tuple
    skipped: tuple
    seconds: float
    workers: int
    engine: str

    @property
    def counts(self) -> dict:
        """Shapes per final status: ``{"ok": n, "failed": n, "timeout": n}``."""
        counts = Counter(row["status"] for row in self.rows)
        return {status: counts[status] for status in ("ok", "failed", "timeout")}

    @property
    def exit_code(self) -> int:
        """:data:`EXIT_OK` when every shape is ok, else :data:`EXIT_SOME_FAILED`."""
        return EXIT_OK if all(row["status"] == "ok" for row in self.rows) else EXIT_SOME_FAILED

    def table(self) -> str:
        """A plain-text summary: counts, mean time and peak memory of this run's shapes, failures."""
        fresh = self.rows_of_this_run
        ok = [row for row in fresh if row["status"] == "ok"]
        counts = self.counts
        lines = [f"voro3d batch: {len(self.rows)} shapes, {len(fresh)} processed in {self.seconds:.1f} s "
                 f"({self.engine}, {self.workers} workers)",
                 f"  ok        {counts['ok']:>6}" + (f"  ({len(self.skipped)} already done)" if self.skipped else ""),
                 f"  failed    {counts['failed']:>6}",
                 f"  timeout   {counts['timeout']:>6}"]
        if ok:
            seconds = sum(row["seconds"] for row in ok) / len(ok)
            lines.append(f"  mean time per ok shape  {seconds:.2f} s")
            memory = [row["peak_memory_mb"] for row in ok if row["peak_memory_mb"] is not None]
            if memory:
                lines.append(f"  mean peak memory        {sum(memory) / len(memory):.0f} MB")
        if fresh and self.seconds > 0:
            lines.append(f"  throughput              {len(fresh) / self.seconds:.3f} shapes/s")
        failures = [row for row in self.rows if row["status"] != "ok"]
        if failures:
            lines.append("failures:")
            width = max(len(row["input"]) for row in failures)
            lines += [f"  {row['input']:<{width}}  {row['status']:<7}  {row['error']}" for row in failures]
        return "\n".join(lines)

    @property
    def rows_of_this_run(self) -> list:
        """The rows this run wrote (the skipped shapes' rows left out)."""
        skipped = set(self.skipped)
        return [row for row in self.rows if row["input"] not in skipped]


def run_batch(input_dir, output_dir, *, method: str = "fit", grid: int = 32, steps: int = 400,
              seed: int = 0, model=None, workers: int | None = None, threads: int = 1, engine: str = "local",
              ray_address: str | None = None, evaluate: bool = False, timeout: float | None = None,
              memory_limit_mb: int | None = None, suffix: str = ".ply",
              progress: bool = True) -> BatchSummary:
    """Reconstruct every mesh under ``input_dir`` into ``output_dir``, resumably (module docstring).

    Parameters
    ----------
    input_dir, output_dir : str or os.PathLike
        Folders; ``output_dir`` is created. It may lie inside ``input_dir`` (it is then not
        searched for inputs) but may not be the same folder.
    method : str, keyword-only
        ``"fit"`` (:func:`voro3d.fitting.fit`) or ``"learned"`` (:class:`voro3d.infer.Predictor`,
        its ONNX session loaded once per worker process).
    grid : int
        Grid nodes per axis, ``>= 2`` for ``"fit"``, ``>= 4`` for ``"learned"``.
    steps : int
        Adam steps of ``"fit"``.
    seed : int
        Seeds the fit and the metrics' samples; the same seed gives the same output bytes.
    model : str or os.PathLike, optional
        ONNX model of ``"learned"``; default the shipped one (:data:`voro3d.infer.DEFAULT_MODEL`).
    workers : int, optional
        Shapes processed at once; default the CPUs this process may use divided by ``threads``.
        Local workers belong to the caller's session, so where Linux shares CPU between sessions
        first (``sched_autogroup``) and other sessions keep the CPUs busy, more workers do not get
        more CPU.
    threads : int
        CPUs (and threads) of each worker, default 1. Local workers are pinned to ``threads`` CPUs
        of their own while ``workers * threads`` CPUs are available; a Ray task asks Ray for
        ``threads`` CPUs. One thread per worker gives the most shapes per second: a shape gains
        little from a second thread (the fit is a loop of small steps), a second shape a whole core.
    engine : str
        ``"local"`` (a pool of worker processes) or ``"ray"`` (Ray tasks; needs ``voro3d[ray]``).
    ray_address : str, optional
        Address of a running Ray cluster for ``engine="ray"``; default a local Ray instance with
        ``workers`` CPUs, started and stopped by this call (no dashboard, works offline). An
        instance this process already initialised is used as it is.
    evaluate : bool
        Add :func:`voro3d.metrics.evaluate` of each output against its input to its row.
    timeout : float, optional
        Seconds one shape may take before its worker is killed and the shape recorded as ``timeout``.
    memory_limit_mb : int, optional
        Address space one shape may add to its worker, in MiB (module docstring).
    suffix : str
        Output format, one of :data:`voro3d.io.MESH_SUFFIXES`.
    progress : bool
        Show a tqdm progress bar over the shapes.

    Returns
    -------
    BatchSummary
        Each row of ``results.jsonl`` holds: ``input``, ``output`` (paths relative to the two
        folders), ``status`` (``"ok"``, ``"failed"`` or ``"timeout"``), ``error`` (the exception,
        or None), ``seconds`` (wall-clock time of the shape in its worker), ``cpu_seconds`` (CPU time
        of the worker, all threads, during the shape; None when it never answered), ``peak_memory_mb``
        (the worker's peak resident memory during the shape, its baseline of interpreter and
        libraries included; None when unknown), ``n_vertices``, ``n_faces``, ``watertight``
        (:meth:`voro3d.watertight.WatertightReport.as_dict`, no self-intersection test),
        ``metrics`` (or None), ``output_bytes``, ``settings``, ``engine``, ``worker_pid`` and
        ``finished`` (UTC, ISO 8601).

    Raises
    ------
    ValueError
        A bad argument (named in the message), no mesh file under ``input_dir``, two inputs
        mapping to one output, another batch writing to ``output_dir``, Ray not installed, or a
        worker unable to load the model.
    FileNotFoundError
        ``input_dir`` or ``model`` does not exist.
    KeyboardInterrupt
        After stopping the workers and removing the unfinished shapes' temporary files.
    """
    start = time.perf_counter()
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if ray_address is not None and engine != "ray":
        raise ValueError(f"ray_address is only used with engine='ray', got engine={engine!r}")
    grid = positive_int(grid, "grid", minimum=2 if method == "fit" else 4)
    steps = positive_int(steps, "steps")
    seed = positive_int(seed, "seed", minimum=0)
    threads = positive_int(threads, "threads")
    cpus = available_cpus()
    workers = max(1, cpus // threads) if workers is None else positive_int(workers, "workers")
    if workers * threads > cpus:
        warnings.warn(f"{workers} workers x {threads} threads exceed the {cpus} CPUs available: "
                      "the workers will take turns on them (fewer workers or threads run faster)", stacklevel=2)
    if timeout is not None and not (math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"timeout must be a finite number of seconds > 0, got {timeout}")
    if memory_limit_mb is not None:
        memory_limit_mb = positive_int(memory_limit_mb, "memory_limit_mb")
        try:
            import resource  # noqa: F401  (POSIX only)
        except ImportError:
            raise ValueError("memory_limit_mb needs the resource module's RLIMIT_AS, which this platform "
                             f"({sys.platform}) lacks; got memory_limit_mb={memory_limit_mb}") from None
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"suffix must be one of {MESH_SUFFIXES}, got {suffix!r}")
    input_dir, output_dir = Path(input_dir), Path(output_dir)
    if not input_dir.is_dir():
        raise FileNotFoundError(f"input_dir {input_dir} is not a folder")
    if output_dir.resolve() == input_dir.resolve():
        raise ValueError(f"output_dir must differ from input_dir, got {output_dir} for both")
    if method == "learned":
        from .infer import DEFAULT_MODEL

        model = Path(DEFAULT_MODEL if model is None else model).resolve()
        if not model.is_file():
            raise FileNotFoundError(f"no ONNX model at {model}")
        model = str(model)
    else:
        model = None

    jobs = _plan(input_dir, output_dir, suffix)
    settings = {"method": method, "grid": grid, "steps": steps if method == "fit" else None, "seed": seed,
                "model": model, "eval": bool(evaluate), "format": suffix}
    output_dir.mkdir(parents=True, exist_ok=True)
    with _ResultsLog(output_dir / RESULTS_NAME) as log:
        final = {job.input_name: log.latest[job.input_name] for job in jobs
                 if job.input_name in log.latest and _complete(log.latest[job.input_name], settings, job.output)}
        skipped = tuple(final)
        _remove_partials([job.output for job in jobs])
        # Biggest files first: a proxy for the longest shapes, so no worker is left with a long
        # shape while the others idle at the end.
        todo = sorted((job for job in jobs if job.input_name not in final), key=lambda job: -job.source.stat().st_size)
        tasks = [ShapeTask(str(job.source.resolve()), str(job.output.resolve()), method, grid, steps, seed, model,
                           threads, bool(evaluate), memory_limit_mb) for job in todo]
        job_of = {task.output: job for task, job in zip(tasks, todo)}

        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(final), unit="shape", desc="voro3d batch", disable=not progress)
        failed = 0

        def record(task: ShapeTask, result: dict) -> None:
            nonlocal failed
            job = job_of[task.output]
            row = {"input": job.input_name, "output": job.output_name, **result, "output_bytes": None,
                   "settings": settings, "engine": engine,
                   "finished": datetime.now(timezone.utc).isoformat(timespec="seconds")}
            if row["status"] == "ok":
                row["output_bytes"] = _fsync(task.output)
            else:
                failed += 1
            log.append(row)
            final[job.input_name] = row
            bar.update(1)
            if failed:
                bar.set_postfix(failed=failed)

        prepare = (method, model, threads)
        try:
            if tasks and engine == "local":
                _run_local(tasks, record, workers=workers, timeout=timeout, prepare=prepare)
            elif tasks:
                _run_ray(tasks, record, workers=workers, timeout=timeout, address=ray_address, prepare=prepare)
        finally:
            bar.close()
    return BatchSummary(tuple(final[job.input_name] for job in jobs), skipped=skipped,
                        seconds=time.perf_counter() - start, workers=workers, engine=engine)


def process_shape(task: ShapeTask) -> dict:
    """Reconstruct one shape and write its mesh: the unit of work of both engines.

    Never raises for a bad shape: the error goes into the returned dict.

    Parameters
    ----------
    task : ShapeTask

    Returns
    -------
    dict
        ``status`` (``"ok"`` or ``"failed"``), ``error``, ``seconds``, ``cpu_seconds``, ``peak_memory_mb``,
        ``n_vertices``, ``n_faces``, ``watertight``, ``metrics``, ``worker_pid``, ``worker_cpus`` (the
        CPUs the worker may run on, None where unknown): the shape's
        part of a ``results.jsonl`` row (:func:`run_batch`).
    """
    from .io import load_mesh, save_mesh
    from .metrics import evaluate
    from .watertight import check_watertight

    _prepare(task.method, task.model, task.threads)
    _reset_peak_memory()
    start, cpu_start = time.perf_counter(), _cpu_seconds()
    result = _result("failed", worker_pid=os.getpid())
    if hasattr(os, "sched_getaffinity"):
        result["worker_cpus"] = sorted(os.sched_getaffinity(0))
    try:
        with _memory_cap(task.memory_limit_mb):
            source = load_mesh(task.source)
            mesh = _reconstruct(source, task.method, grid=task.grid, steps=task.steps, seed=task.seed,
                                model=task.model, threads=task.threads).to_open3d()
            report = check_watertight(mesh, self_intersection=False).as_dict()
            result.update(n_vertices=report["n_vertices"], n_faces=report["n_triangles"], watertight=report)
            if not report["watertight"]:
                failing = [key for key, value in report.items() if value is False]
                result["error"] = f"the output mesh is not watertight (fails {', '.join(failing)})"
            else:
                if task.evaluate:
                    result["metrics"] = evaluate(mesh, source, seed=task.seed)
                save_mesh(mesh, task.output)
                result["status"] = "ok"
    except MemoryError:
        limit = f" within --memory-limit {task.memory_limit_mb} MB" if task.memory_limit_mb else ""
        result["error"] = f"MemoryError: out of memory{limit}"
    except Exception as error:  # one bad shape must not stop the batch: its row carries the reason
        # One line without terminal colours: Open3D's messages carry both.
        message = " ".join(_ANSI.sub("", str(error)).split())
        result["error"] = f"{type(error).__name__}: {message}"
    result["seconds"] = time.perf_counter() - start
    result["cpu_seconds"] = _cpu_seconds() - cpu_start
    result["peak_memory_mb"] = _peak_memory_mb()
    return result


def _cpu_seconds() -> float:
    """CPU time of this process, all its threads, user and system (portable, unlike ``resource``)."""
    return time.process_time()


def add_batch_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``batch`` command to the ``voro3d`` command's subparsers.

    Its handler is ``args.run(args)``, which returns the exit code (module docstring).

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``parser.add_subparsers()``.

    Returns
    -------
    argparse.ArgumentParser
        The ``batch`` subparser.
    """
    parser = subparsers.add_parser(
        "batch", help="reconstruct every mesh in a folder (resumable, parallel)",
        description="Reconstruct every mesh under INPUT_DIR as a watertight VoroMesh at the same relative "
                    f"path under OUTPUT_DIR, with one row per shape in OUTPUT_DIR/{RESULTS_NAME}. A rerun "
                    "skips the shapes already done with the same settings.",
        epilog="exit status: 0 all shapes ok, 1 some shape failed or timed out, 2 bad arguments, "
               "130 interrupted (rerun to resume)")
    parser.add_argument("input_dir", help="folder of meshes (" + " ".join(MESH_SUFFIXES) + "), searched recursively")
    parser.add_argument("output_dir", help="folder for the output meshes and " + RESULTS_NAME)
    parser.add_argument("--method", choices=METHODS, default="fit",
                        help="direct fit or learned inference (default fit)")
    parser.add_argument("--grid", type=int, default=32, help="grid resolution g (g^3 nodes), default 32")
    parser.add_argument("--steps", type=int, default=400, help="Adam steps of --method fit, default 400")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", help="ONNX model of --method learned (default: the shipped one)")
    parser.add_argument("--workers", type=int, help="shapes at once (default: the available CPUs / --threads)")
    parser.add_argument("--threads", type=int, default=1,
                        help="CPUs (threads) per worker, default 1: more shapes at once beat more threads per shape")
    parser.add_argument("--engine", choices=ENGINES, default="local",
                        help="local worker processes (default) or Ray tasks (pip install 'voro3d[ray]')")
    parser.add_argument("--ray-address", help="a running Ray cluster (default: start a local one)")
    parser.add_argument("--eval", dest="evaluate", action="store_true",
                        help="add Chamfer, F1 and normal consistency against the input to each row")
    parser.add_argument("--timeout", type=float, metavar="SECONDS", help="kill a shape that takes longer")
    parser.add_argument("--memory-limit", type=int, metavar="MB",
                        help="address space a shape may add to its worker (RLIMIT_AS), in MiB")
    parser.add_argument("--format", choices=[suffix[1:] for suffix in MESH_SUFFIXES], default="ply",
                        help="output format (default ply)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary table")
    parser.set_defaults(run=_run_command)
    return parser


def _run_command(args) -> int:
    try:
        summary = run_batch(args.input_dir, args.output_dir, method=args.method, grid=args.grid, steps=args.steps,
                            seed=args.seed, model=args.model, workers=args.workers, threads=args.threads,
                            engine=args.engine, ray_address=args.ray_address, evaluate=args.evaluate, timeout=args.timeout,
                            memory_limit_mb=args.memory_limit, suffix="." + args.format, progress=not args.quiet)
    except KeyboardInterrupt:
        print("voro3d batch: interrupted; finished shapes are kept, rerun the same command to resume",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if not args.quiet:
        print(summary.table())
    return summary.exit_code


class _Job(NamedTuple):
    source: Path
    output: Path
    input_name: str  # relative to the input folder, as rows name it
    output_name: str


def _plan(input_dir: Path, output_dir: Path, suffix: str) -> list:
    """A :class:`_Job` for every mesh under ``input_dir``, in sorted order."""
    skip = output_dir.resolve()
    jobs = []
    for root, folders, files in os.walk(input_dir):
        root = Path(root)
        folders[:] = sorted(name for name in folders if not name.startswith(".") and (root / name).resolve() != skip)
        for name in sorted(files):
            if name.startswith(".") or Path(name).suffix.lower() not in MESH_SUFFIXES:
                continue
            relative = (root / name).relative_to(input_dir)
            output = relative.with_suffix(suffix)
            jobs.append(_Job(root / name, output_dir / output, relative.as_posix(), output.as_posix()))
    if not jobs:
        raise ValueError(f"input_dir {input_dir} holds no mesh file ({', '.join(MESH_SUFFIXES)})")
    sources = {job.source.resolve() for job in jobs}
    taken = {}
    for job in jobs:
        if job.output.resolve() in sources:
            raise ValueError(f"output {job.output} would overwrite an input; choose another output_dir")
        if job.output in taken:
            raise ValueError(f"inputs {taken[job.output]} and {job.input_name} would both write {job.output}")
        taken[job.output] = job.input_name
    return jobs


def _complete(row: dict, settings: dict, output: Path) -> bool:
    return (row.get("status") == "ok" and row.get("settings") == settings and output.is_file()
            and output.stat().st_size == row.get("output_bytes"))


class _ResultsLog:
    """``results.jsonl``: read once, then appended one fsynced row at a time, locked against a second batch."""

    def __init__(self, path: Path):
        self.handle = open(path, "a+b")
        if not _lock_exclusive(self.handle):
            self.handle.close()
            raise ValueError(f"output_dir {path.parent} is in use by another voro3d batch")
        self.handle.seek(0)
        data = self.handle.read()
        self.latest = {}
        for line in data.splitlines():
            try:
                row = json.loads(line)
            except ValueError:
                continue  # a row torn by a crash mid-write: its shape is done again
            if isinstance(row, dict) and isinstance(row.get("input"), str):
                self.latest[row["input"]] = row
        self.torn = bool(data) and not data.endswith(b"\n")

    def append(self, row: dict) -> None:
        line = json.dumps(row) + "\n"
        if self.torn:  # start after the torn row, not inside it
            line, self.torn = "\n" + line, False
        self.handle.write(line.encode())
        self.handle.flush()
        os.fsync(self.handle.fileno())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.handle.close()


def _lock_exclusive(handle) -> bool:
    """Lock an open file for as long as it stays open; False when another process holds the lock.

    ``fcntl.flock`` on POSIX; on Windows ``msvcrt.locking`` of the file's first byte (a mandatory
    lock there: other programs cannot read that byte while the batch runs).
    """
    try:
        import fcntl
    except ImportError:
        import msvcrt

        handle.seek(0)
        try:
            msvcrt.locking(handle.fileno(), msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _fsync(path: str) -> int:
    """Flush a finished mesh to disk before its row says so; return its size in bytes."""
    with open(path, "rb") as handle:
        os.fsync(handle.fileno())
        return os.fstat(handle.fileno()).st_size


def _remove_partials(outputs) -> None:
    """Delete the temporary files :func:`voro3d.io.atomic_path` left for ``outputs`` when its process was killed."""
    wanted = defaultdict(set)
    for output in outputs:
        wanted[Path(output).parent].add(Path(output).name)
    for folder, names in wanted.items():
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            match = _PARTIAL.fullmatch(entry.name)
            if match and match["stem"] + match["suffix"] in names:
                entry.unlink(missing_ok=True)


def _result(status: str, error: str | None = None, seconds: float | None = None,
            peak_memory_mb: float | None = None, *, worker_pid: int | None = None) -> dict:
    """The shape's part of a row, for :func:`process_shape` and for shapes whose worker never answered."""
    return {"status": status, "error": error, "seconds": seconds, "cpu_seconds": None,
            "peak_memory_mb": peak_memory_mb, "n_vertices": None, "n_faces": None, "watertight": None,
            "metrics": None, "worker_pid": worker_pid, "worker_cpus": None}


# -- inside a worker ------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _predictor(model: str, threads: int):
    """One ONNX session per worker process; voro3d.infer's own cache has no thread count, and
    every worker taking all cores would oversubscribe them."""
    from .infer import Predictor

    return Predictor(model, threads=threads)


@functools.lru_cache(maxsize=None)
def _prepare(method: str, model: str | None, threads: int) -> None:
    """Pay a worker's one-time costs before its first shape is timed and memory-capped.

    A unit box goes through the reconstruction, and one Voronoi cell (an octahedron: the origin
    inside, the cube's corners outside) through extraction, checks and metrics. That imports
    torch, Open3D and what they import only on first use (torch's optimiser pulls in sympy), and
    loads the ONNX session; an import cut short by the memory cap would leave a half-initialised
    module behind for every later shape.
    """
    import itertools

    import numpy as np
    import open3d as o3d

    from . import sampling
    from .extract import VoroMesh
    from .metrics import evaluate
    from .watertight import check_watertight

    # Winding numbers run on up to sampling.WINDING_THREADS threads, a number set at import from
    # the whole machine; a worker has ``threads`` CPUs (its affinity, when pinned).
    sampling.WINDING_THREADS = max(1, min(sampling.WINDING_THREADS, threads, available_cpus()))
    box = o3d.geometry.TriangleMesh.create_box()
    _reconstruct(box, method, grid=8, steps=2, seed=0, model=model, threads=threads)
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    cell = VoroMesh(np.vstack([np.zeros(3), corners]), np.arange(9) == 0).to_open3d()
    check_watertight(cell, self_intersection=False)
    evaluate(cell, box, n_points=64)


def _reconstruct(source, method: str, *, grid: int, steps: int, seed: int, model: str | None, threads: int):
    """The VoroMesh of ``source`` by ``method``."""
    if method == "fit":
        from .fitting import fit

        import torch

        torch.set_num_threads(threads)
        return fit(source, grid, steps=steps, seed=seed, progress=False)
    return _predictor(model, threads).predict_mesh(source, grid)


def _proc_status_kb(field: str, pid="self") -> int | None:
    """A ``kB`` field of ``/proc/PID/status`` (Linux), or None."""
    try:
        with open(f"/proc/{pid}/status") as handle:
            for line in handle:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _reset_peak_memory() -> None:
    """Reset this process's peak resident memory (Linux >= 4.0), so that the next reading is one shape's."""
    with contextlib.suppress(OSError):
        with open("/proc/self/clear_refs", "w") as handle:
            handle.write("5")


def _peak_memory_mb() -> float | None:
    """Peak resident memory since :func:`_reset_peak_memory`, in MiB (the lifetime peak where it can't reset)."""
    peak = _proc_status_kb("VmHWM")
    if peak is None:
        try:
            import resource
        except ImportError:  # Windows
            return None
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        if sys.platform == "darwin":  # bytes there, kB elsewhere
            peak /= 1024
    return round(peak / 1024, 1)


@contextlib.contextmanager
def _memory_cap(limit_mb: int | None):
    """Lower the soft RLIMIT_AS to the current address space plus ``limit_mb`` MiB, for the block only.

    Relative to the current address space because a warmed-up worker already maps gigabytes it
    never touches (torch, Ray's object store), so an absolute cap would mean little. Only the soft
    limit moves, so the worker can lift it again for its next shape.
    """
    if limit_mb is None:
        yield
        return
    import resource  # run_batch has checked that it exists

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = (_proc_status_kb("VmSize") or 0) * 1024 + limit_mb * 2**20
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _worker_main(connection, parent_pid: int, cpus: tuple | None, method: str, model: str | None,
                 threads: int) -> None:
    """A local worker: warm up, say ready, then run shapes one at a time until told to stop."""
    # Before torch, Open3D and OpenMP load: their thread pools size themselves to these.
    if cpus:
        os.sched_setaffinity(0, cpus)
    os.environ["OMP_NUM_THREADS"] = str(threads)
    from tqdm import tqdm

    _die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group; the batch decides what stops, and kills its workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm's default lock is a multiprocessing semaphore; a worker killed holding one has the
    # resource tracker warn of a leak at exit. A worker's bars are off, so a thread lock will do.
    tqdm.set_lock(threading.RLock())
    try:
        _prepare(method, model, threads)
    except Exception as error:  # reported to the batch, which stops: no shape could succeed
        connection.send(("error", f"{type(error).__name__}: {error}"))
        return
    connection.send(("ready", None))
    while True:
        try:
            task = connection.recv()
        except EOFError:
            return
        if task is None:
            return
        connection.send(("done", process_shape(task)))


def _die_with_parent(parent_pid: int) -> None:
    """Have Linux kill this worker when the batch dies (even by SIGKILL), so no orphan keeps writing."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent_pid:  # the batch died before the request took hold
        os._exit(1)


# -- the local engine -----------------------------------------------------------------------


class _Worker:
    """One local worker process and its pipe; it runs one shape at a time so that it can be killed alone."""

    def __init__(self, context, prepare: tuple, cpus: tuple | None):
        self.cpus = cpus
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_worker_main, args=(child, os.getpid(), cpus, *prepare), daemon=True)
        self.process.start()
        child.close()
        self.ready = False
        self.task = None
        self.started = 0.0

    def give(self, task: ShapeTask) -> None:
        self.connection.send(task)
        self.task, self.started = task, time.perf_counter()

    def messages(self) -> list:
        """Everything the worker has sent so far (a dead worker's last result included)."""
        received = []
        with contextlib.suppress(EOFError, OSError):
            while self.connection.poll():
                received.append(self.connection.recv())
        return received

    def kill(self) -> None:
        self.process.kill()
        self.process.join()
        self.connection.close()

    def close(self) -> None:
        """Stop an idle worker: politely once it is ready (killed, it would leave its semaphores for the
        resource tracker to warn about), at once while it is still starting."""
        if self.ready:
            with contextlib.suppress(OSError):
                self.connection.send(None)
            self.process.join(timeout=10)
        self.kill()


def _run_local(tasks: list, record, *, workers: int, timeout: float | None, prepare: tuple) -> None:
    """Run ``tasks`` on a pool of worker processes, calling ``record(task, result)`` as each ends."""
    # spawn, not fork: a fork would copy the batch's threads and locks (tqdm's monitor, OpenMP)
    # into workers mid-state.
    context = multiprocessing.get_context("spawn")
    queue = deque(tasks)
    pool = [_Worker(context, prepare, cpus) for cpus in _cpu_slots(min(workers, len(queue)), prepare[2])]
    startup_deaths = 0
    try:
        while pool:
            for worker in [w for w in pool if w.task is None and not queue]:
                worker.close()
                pool.remove(worker)
            for worker in pool:
                if worker.ready and worker.task is None and queue:
                    worker.give(queue.popleft())
            if not pool:
                break
            busy = [worker.started for worker in pool if worker.task is not None]
            wait = None if timeout is None or not busy else max(0.0, min(busy) + timeout - time.perf_counter())
            multiprocessing.connection.wait([w.connection for w in pool] + [w.process.sentinel for w in pool], wait)

            for index, worker in enumerate(pool):
                for kind, payload in worker.messages():
                    if kind == "ready":
                        worker.ready, startup_deaths = True, 0
                    elif kind == "error":
                        raise ValueError(f"a worker could not start: {payload}")
                    else:
                        task, worker.task = worker.task, None
                        record(task, payload)
                elapsed = time.perf_counter() - worker.started
                if worker.process.exitcode is not None:
                    worker.kill()
                    if worker.task is not None:
                        _remove_partials([worker.task.output])
                        record(worker.task, _result("failed", f"worker process {_exit_reason(worker.process.exitcode)}",
                                                    elapsed, worker_pid=worker.process.pid))
                    elif not worker.ready:
                        startup_deaths += 1
                        if startup_deaths >= _STARTUP_ATTEMPTS:
                            raise RuntimeError(f"worker processes die while starting: the last one "
                                               f"{_exit_reason(worker.process.exitcode)}")
                    pool[index] = _Worker(context, prepare, worker.cpus) if queue else None
                elif worker.task is not None and timeout is not None and elapsed > timeout:
                    peak = _proc_status_kb("VmHWM", worker.process.pid)
                    worker.kill()
                    _remove_partials([worker.task.output])
                    record(worker.task, _result("timeout", f"no result after {timeout:g} s; worker killed", elapsed,
                                                None if peak is None else round(peak / 1024, 1),
                                                worker_pid=worker.process.pid))
                    pool[index] = _Worker(context, prepare, worker.cpus) if queue else None
            pool = [worker for worker in pool if worker is not None]
    finally:
        for worker in pool:
            if worker.task is None:
                worker.close()
            else:
                worker.kill()
                _remove_partials([worker.task.output])


def _cpu_slots(workers: int, threads: int) -> list:
    """The CPUs each local worker is pinned to: ``threads`` of this process's, or None (unpinned).

    Pinned, a worker's thread pools (OpenMP, TBB, torch) size themselves to its CPUs instead of to
    the whole machine, and no two workers take turns on a core. When ``workers * threads`` exceeds
    the CPUs there is no fair split: the OS schedules the workers.
    """
    if not hasattr(os, "sched_getaffinity"):
        return [None] * workers
    cpus = sorted(os.sched_getaffinity(0))
    if workers * threads > len(cpus):
        return [None] * workers
    return [tuple(cpus[i * threads:(i + 1) * threads]) for i in range(workers)]


def _exit_reason(exitcode: int) -> str:
    if exitcode < 0:
        name = signal.Signals(-exitcode).name
        hint = " (out of memory?)" if -exitcode == signal.SIGKILL else ""
        return f"was killed by {name}{hint}"
    return f"exited with status {exitcode}"


# -- the Ray engine -------------------------------------------------------------------------


def _run_ray(tasks: list, record, *, workers: int, timeout: float | None, address: str | None,
             prepare: tuple) -> None:
    """Run ``tasks`` as Ray tasks of :func:`process_shape`, calling ``record(task, result)`` as each ends."""
    try:
        import ray
    except ImportError:
        raise ValueError("engine='ray' needs Ray: pip install 'voro3d[ray]'") from None

    threads = prepare[2]
    started_here = not ray.is_initialized()
    if started_here:
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report: batches run offline
        options = {"address": address} if address else {"num_cpus": workers * threads, "include_dashboard": False}
        ray.init(**options, log_to_driver=False, logging_level=logging.WARNING)
    # Ray sets OMP_NUM_THREADS of a task's worker to the task's num_cpus.
    shape = ray.remote(num_cpus=threads, max_retries=0)(process_shape)
    # Warm-up tasks do for Ray workers what a local worker does before it says it is ready, so
    # that a timeout, which runs from submission, never counts imports. (A lambda, because Ray's
    # decorator does not take the lru_cache wrapper.)
    warm_up = ray.remote(num_cpus=threads, max_retries=0)(lambda: _prepare(*prepare))
    queue = deque(tasks)
    in_flight = {}  # ref -> (task, submitted); task None for a warm-up
    cold = min(workers, len(queue))  # free slots whose worker may be new: warm one up first
    try:
        while queue or in_flight:
            while queue and len(in_flight) < workers:
                if cold:
                    cold -= 1
                    in_flight[warm_up.remote()] = (None, time.perf_counter())
                else:
                    task = queue.popleft()
                    in_flight[shape.remote(task)] = (task, time.perf_counter())
            running = [submitted for task, submitted in in_flight.values() if task is not None]
            wait = None
            if timeout is not None and running:
                wait = max(0.0, min(running) + timeout - time.perf_counter())
            done, _ = ray.wait(list(in_flight), num_returns=1, timeout=wait)
            for ref in done:
                task, submitted = in_flight.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as error:
                    reason = f"{type(error).__name__}: {str(error).strip().splitlines()[0]}"
                    if task is None:
                        raise ValueError(f"a Ray worker could not start: {reason}") from None
                    cold += 1  # the task's worker may have died with it
                    _remove_partials([task.output])
                    result = _result("failed", f"Ray task failed: {reason}", time.perf_counter() - submitted)
                if task is not None:
                    record(task, result)
            for ref, (task, submitted) in list(in_flight.items()):
                elapsed = time.perf_counter() - submitted
                if task is not None and timeout is not None and elapsed > timeout:
                    _cancel(ray, ref, task)
                    del in_flight[ref]
                    cold += 1
                    record(task, _result("timeout", f"no result after {timeout:g} s; Ray task cancelled", elapsed))
    finally:
        for ref, (task, _) in in_flight.items():
            ray.cancel(ref, force=True)
            if task is not None:
                ray.wait([ref], timeout=_RAY_CANCEL_WAIT)
                _remove_partials([task.output])
        if started_here:
            ray.shutdown()


def _cancel(ray, ref, task: ShapeTask) -> None:
    """Kill the Ray worker running ``ref``, wait until it is gone, then sweep the shape's temporary file."""
    ray.cancel(ref, force=True)
    ray.wait([ref], timeout=_RAY_CANCEL_WAIT)
    _remove_partials([task.output])
