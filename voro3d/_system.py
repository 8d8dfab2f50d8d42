"""What the operating system lets this process use."""
from __future__ import annotations

import os

__all__ = ["available_cpus"]


def available_cpus() -> int:
    """CPUs this process may run on: its affinity mask where the OS has one (Linux), else all of them.

    ``os.cpu_count()`` counts the machine's CPUs even in a process pinned to a few of them (a
    ``voro3d batch`` worker, ``taskset``, a container's cpuset), whose thread pools would then
    oversubscribe its cores.
    """
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
