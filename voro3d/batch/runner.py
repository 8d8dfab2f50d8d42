"""The public entry points of a batch: :func:`run_batch` and the ``voro3d batch`` command."""
from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from datetime import datetime, timezone
from pathlib import Path

from .._system import available_cpus
from .._validate import mesh_grid, method_options, positive_int
from ..io import MESH_SUFFIXES
from .local import run_local
from .plan import (ENGINES, EXIT_INTERRUPTED, METHODS, RESULTS_NAME, BatchSummary, ShapeTask, _complete, _fsync,
                   _plan, _remove_partials, _ResultsLog)
from .ray_engine import run_ray

__all__ = ["add_batch_parser", "run_batch"]

# voro3d.fit's default steps, written out because the batch's own process never imports torch
# (fitting's module) to read it; tests/test_api.py checks that the two agree.
FIT_STEPS = 400


def run_batch(input_dir, output_dir, *, method: str = "fit", grid: int = 32, steps: int | None = None,
              seed: int = 0, model=None, workers: int | None = None, threads: int = 1, engine: str = "local",
              ray_address: str | None = None, evaluate: bool = False, timeout: float | None = None,
              memory_limit_mb: int | None = None, suffix: str = ".ply", clean: bool = True,
              progress: bool = False) -> BatchSummary:
    """Reconstruct every mesh under ``input_dir`` into ``output_dir``, resumably (:mod:`voro3d.batch`).

    Parameters
    ----------
    input_dir, output_dir : str or os.PathLike
        Folders; ``output_dir`` is created. It may lie inside ``input_dir`` (it is then not
        searched for inputs) but may not be the same folder.
    method : str, keyword-only
        ``"fit"`` (:func:`voro3d.fitting.fit`) or ``"learned"`` (:class:`voro3d.infer.Predictor`,
        its ONNX session loaded once per worker process).
    grid : int or "auto"
        Grid nodes per axis, ``>= 4``; ``"auto"`` is 32, as for a mesh in :func:`voro3d.reconstruct`.
    steps : int, optional
        Adam steps of ``"fit"``, default 400 (:func:`voro3d.fit`'s); refused with ``"learned"``.
    seed : int
        Seeds the fit and the metrics' samples; the same seed gives the same output bytes.
    model : str or os.PathLike, optional
        ONNX model of ``"learned"``; default the shipped one (:data:`voro3d.infer.DEFAULT_MODEL`).
        Refused with ``"fit"``.
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
        Address space one shape may add to its worker, in MiB (:mod:`voro3d.batch`).
    suffix : str
        Output format, one of :data:`voro3d.io.MESH_SUFFIXES`.
    clean : bool
        Clean each surface (:func:`voro3d.cleaning.clean`) before writing it; a rerun with another
        value redoes the shapes.
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
        A bad argument (named in the message), an option the method does not use (``steps``
        with ``"learned"``, ``model`` with ``"fit"``), no mesh file under ``input_dir``, two inputs
        mapping to one output, another batch writing to ``output_dir``, or a worker unable to load
        the model.
    MissingExtra
        ``engine="ray"`` without Ray installed (an ``ImportError``: ``pip install 'voro3d[ray]'``).
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
    method_options(method, "fit", steps=steps)
    method_options(method, "learned", model=model)
    grid = mesh_grid(grid)
    steps = positive_int(FIT_STEPS if steps is None else steps, "steps") if method == "fit" else None
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
        from ..infer import DEFAULT_MODEL

        model = Path(DEFAULT_MODEL if model is None else model).resolve()
        if not model.is_file():
            raise FileNotFoundError(f"no ONNX model at {model}")
        model = str(model)

    jobs = _plan(input_dir, output_dir, suffix)
    settings = {"method": method, "grid": grid, "steps": steps, "seed": seed,
                "model": model, "eval": bool(evaluate), "format": suffix, "clean": bool(clean)}
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
                           threads, bool(evaluate), memory_limit_mb, bool(clean)) for job in todo]
        job_of = {task.output: job for task, job in zip(tasks, todo)}

        from tqdm import tqdm

        bar = tqdm(total=len(jobs), initial=len(final), unit="shape", desc="voro3d batch",
                   disable=None if progress else True)  # None: on a terminal only, not a line per update in a log
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
                run_local(tasks, record, workers=workers, timeout=timeout, prepare=prepare)
            elif tasks:
                run_ray(tasks, record, workers=workers, timeout=timeout, address=ray_address, prepare=prepare)
        finally:
            bar.close()
    return BatchSummary(tuple(final[job.input_name] for job in jobs), skipped=skipped,
                        seconds=time.perf_counter() - start, workers=workers, engine=engine)


def add_batch_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``batch`` command to the ``voro3d`` command's subparsers.

    Its handler is ``args.run(args)``, which returns the exit code (:mod:`voro3d.batch`).

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
               "130 interrupted (rerun to resume)\n\nexample:\n  mkdir shapes && voro3d example knot -o shapes/knot.ply "
               "&& voro3d example torus -o shapes/torus.ply && voro3d batch shapes meshes --eval",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input_dir", help="folder of meshes (" + " ".join(MESH_SUFFIXES) + "), searched recursively")
    parser.add_argument("output_dir", help="folder for the output meshes and " + RESULTS_NAME)
    parser.add_argument("--method", choices=METHODS, default="fit",
                        help="direct fit or learned inference (default fit)")
    from ..cli import grid_argument, positive_argument

    parser.add_argument("--grid", type=grid_argument, default="auto",
                        help="grid resolution g (g^3 nodes), an integer >= 4, or 'auto' (default: 32)")
    parser.add_argument("--steps", type=positive_argument, help="Adam steps of --method fit, default 400")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fit and the metrics, default 0")
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
    parser.add_argument("--no-clean", action="store_true",
                        help="keep the Voronoi faces as they are (default: cleaned, see voro3d.cleaning, then "
                        "fitted to the input mesh, see voro3d.snapping)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary table")
    parser.set_defaults(run=_run_command)
    return parser


def _run_command(args) -> int:
    try:
        summary = run_batch(args.input_dir, args.output_dir, method=args.method, grid=args.grid, steps=args.steps,
                            seed=args.seed, model=args.model, workers=args.workers, threads=args.threads,
                            engine=args.engine, ray_address=args.ray_address, evaluate=args.evaluate, timeout=args.timeout,
                            memory_limit_mb=args.memory_limit, suffix="." + args.format, clean=not args.no_clean,
                            progress=not args.quiet)
    except KeyboardInterrupt:
        print("voro3d batch: interrupted; finished shapes are kept, rerun the same command to resume",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if not args.quiet:
        print(summary.table())
    return summary.exit_code
