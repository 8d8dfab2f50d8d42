"""The Ray engine: the same :func:`voro3d.batch.worker.process_shape` as Ray tasks (``pip install 'voro3d[ray]'``)."""
from __future__ import annotations

import time
from collections import deque

from .._extras import ray_session
from .plan import ShapeTask, _remove_partials, _result
from .worker import _prepare, process_shape

__all__ = ["run_ray"]

# Seconds a force-cancelled Ray task gets to be reported dead before its files are swept anyway.
_RAY_CANCEL_WAIT = 30.0


def run_ray(tasks: list, record, *, workers: int, timeout: float | None, address: str | None,
            prepare: tuple) -> None:
    """Run ``tasks`` as Ray tasks of :func:`~voro3d.batch.worker.process_shape`, calling ``record(task, result)`` as each ends."""
    threads = prepare[2]
    with ray_session(workers * threads, address=address) as ray:
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


def _cancel(ray, ref, task: ShapeTask) -> None:
    """Kill the Ray worker running ``ref``, wait until it is gone, then sweep the shape's temporary file."""
    ray.cancel(ref, force=True)
    ray.wait([ref], timeout=_RAY_CANCEL_WAIT)
    _remove_partials([task.output])
