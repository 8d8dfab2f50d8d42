"""The local engine: a pool of worker processes, each running one shape at a time over a pipe."""
from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from collections import deque

from .plan import ShapeTask, _remove_partials, _result
from .worker import _proc_status_kb, _worker_main

__all__ = ["run_local"]

# A local worker that dies this many times in a row before it is ready is not a shape's fault.
_STARTUP_ATTEMPTS = 3


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


def run_local(tasks: list, record, *, workers: int, timeout: float | None, prepare: tuple) -> None:
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
