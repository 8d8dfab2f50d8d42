"""The plan and the record of a batch: shapes to do, rows of ``results.jsonl``, the summary.

Nothing here runs a shape: :mod:`voro3d.batch.worker` does, on the pools of
:mod:`voro3d.batch.local` and :mod:`voro3d.batch.ray_engine`.
"""
from __future__ import annotations

import json
import os
import re
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from ..io import MESH_SUFFIXES

__all__ = ["BatchSummary", "ENGINES", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_SOME_FAILED", "METHODS", "RESULTS_NAME",
           "ShapeTask"]

METHODS = ("fit", "learned")
ENGINES = ("local", "ray")
RESULTS_NAME = "results.jsonl"
EXIT_OK = 0
EXIT_SOME_FAILED = 1
EXIT_INTERRUPTED = 130

# The temporary files of voro3d.io.atomic_path: tempfile.mkstemp(prefix=".{stem}.", suffix) adds
# eight characters from this alphabet.
_PARTIAL = re.compile(r"\.(?P<stem>.+)\.[a-z0-9_]{8}(?P<suffix>\.[^.]+)")


@dataclass(frozen=True)
class ShapeTask:
    """One shape for a worker: everything :func:`process_shape` needs, picklable.

    Attributes
    ----------
    source, output : str
        Absolute paths of the input mesh and of the mesh to write.
    method : str
        ``"fit"`` or ``"learned"``.
    grid, seed : int
        As for :func:`voro3d.fitting.fit` (``seed`` also seeds the metrics).
    steps : int or None
        Adam steps of ``"fit"``; None for ``"learned"``, which has none.
    model : str or None
        Absolute path of the ONNX model for ``"learned"``.
    threads : int
        Threads of the worker (the fit kernel for ``"fit"``, onnxruntime for ``"learned"``).
    evaluate : bool
        Compute :func:`voro3d.metrics.evaluate` against the input.
    memory_limit_mb : int or None
        Address space the shape may add, in MiB (:mod:`voro3d.batch`).
    clean : bool
        Clean the surface (:func:`voro3d.cleaning.clean`) before writing it.
    """

    source: str
    output: str
    method: str
    grid: int
    steps: int | None
    seed: int
    model: str | None
    threads: int
    evaluate: bool
    memory_limit_mb: int | None
    clean: bool = True


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
