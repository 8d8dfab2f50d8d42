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

``--engine ray`` (``pip install 'voro3d[ray]'``) starts a local Ray instance, or joins
``--ray-address``, and runs the same per-shape function as Ray tasks. ``--memory-limit`` needs POSIX
``RLIMIT_AS``; the rest runs where ``fcntl`` and ``resource`` are missing.

Exit codes of ``voro3d batch``: 0 every shape is ok (skipped ones included), 1 some shape failed or
timed out (:data:`EXIT_SOME_FAILED`), 2 bad arguments, 130 interrupted (finished shapes are kept;
rerun the same command to resume).
"""
from __future__ import annotations

from .plan import (ENGINES, EXIT_INTERRUPTED, EXIT_OK, EXIT_SOME_FAILED, METHODS, RESULTS_NAME, BatchSummary,
                   ShapeTask)
from .runner import add_batch_parser, run_batch
from .worker import process_shape

__all__ = ["BatchSummary", "ENGINES", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_SOME_FAILED", "METHODS", "RESULTS_NAME",
           "ShapeTask", "add_batch_parser", "process_shape", "run_batch"]
