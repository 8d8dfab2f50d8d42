"""Inside a worker process: one shape from mesh file to watertight mesh file, and its row.

:func:`process_shape` is the unit of work of both engines; :func:`_worker_main` is a local
worker's loop. Limits (memory cap, threads, CPU affinity) are applied here.
"""
from __future__ import annotations

import contextlib
import functools
import os
import re
import signal
import sys
import threading
import time

from .plan import ShapeTask, _result

__all__ = ["process_shape"]

_ANSI = re.compile(r"\x1b\[[0-9;]*m")


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
    from ..io import load_mesh, save_mesh
    from ..metrics import evaluate
    from ..watertight import check_watertight

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
                                model=task.model, threads=task.threads, clean=task.clean)
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


@functools.lru_cache(maxsize=None)
def _prepare(method: str, model: str | None, threads: int) -> None:
    """Pay a worker's one-time costs before its first shape is timed and memory-capped.

    A unit box goes through the reconstruction, and one Voronoi cell (an octahedron: the origin
    inside, the cube's corners outside) through extraction, checks and metrics. That imports
    Open3D and what it imports only on first use, and loads the ONNX session; an import cut short
    by the memory cap would leave a half-initialised module behind for every later shape.
    """
    import itertools

    import numpy as np
    import open3d as o3d

    from .. import rowblocks
    from ..voromesh import VoroMesh
    from ..metrics import evaluate
    from ..watertight import check_watertight

    # rowblocks.ROW_THREADS (numpy row blocks, winding numbers) follows the affinity this worker was
    # pinned to before the import; an unpinned worker (Ray's, or more workers x threads than CPUs)
    # must still keep to ``threads``.
    rowblocks.ROW_THREADS = max(1, min(rowblocks.ROW_THREADS, threads))
    box = o3d.geometry.TriangleMesh.create_box()
    _reconstruct(box, method, grid=8, steps=2, seed=0, model=model, threads=threads)
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    cell = VoroMesh(np.vstack([np.zeros(3), corners]), np.arange(9) == 0).to_open3d()
    check_watertight(cell, self_intersection=False)
    evaluate(cell, box, n_samples=64)


def _reconstruct(source, method: str, *, grid: int, steps: int | None, seed: int, model: str | None, threads: int,
                 clean: bool = True):
    """The watertight mesh of ``source`` by ``method``: :func:`voro3d.reconstruct`, as a single shape gets it.

    The fit kernel and onnxruntime run on ``threads`` threads (the engines also set OMP_NUM_THREADS
    to it: a local worker before its first import, Ray to the task's CPUs).
    """
    from ..reconstruction import reconstruct

    options = dict(steps=steps, seed=seed) if method == "fit" else dict(model=model)
    return reconstruct(source, grid, method=method, threads=threads, clean=clean, **options)


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
    # Before Open3D, OpenMP and the fit kernel load: their thread pools size themselves to these.
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
