"""How many CPU threads a `runout` command computes on: the cores no other process is using.

PyTorch's OpenMP threads wait for each other at the end of every parallel operation. When
another process holds one of the cores, the thread on that core is descheduled for whole
time slices and every operation waits for it: `make demo` beside one training process on a
2-core machine took 27 minutes instead of 82 s, and `runout train` 4.9 s per step instead of
0.32 (docs/benchmarks.md). So unless the user chose (OMP_NUM_THREADS set), a command takes
the cores available to it less the ones busy now: busy is the smaller of the 1-minute load
average (rounded) and the processes running at this instant besides this one (Linux
/proc/loadavg), so a load that has just ended does not count, nor a burst that has just begun.
"""

from __future__ import annotations

import os

ENV = "OMP_NUM_THREADS"


def threads_for(cores: int, load: float, running: int) -> int:
    """Threads for a machine of `cores` usable cores whose 1-minute load average is `load`
    with `running` processes runnable now, this one included; at least 1."""
    busy = max(0, min(round(load), running - 1))
    return max(1, cores - busy)


def machine() -> tuple[int, float, int]:
    """(usable cores, 1-minute load average, processes runnable now including this one)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        with open("/proc/loadavg") as f:
            fields = f.read().split()
        return cores, float(fields[0]), int(fields[3].split("/")[0])
    except (OSError, IndexError, ValueError):  # not Linux: the load average alone
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
        return cores, load, cores + 1


def choose_threads() -> int | None:
    """Set OMP_NUM_THREADS for this process (before torch is imported) to the idle cores when
    other processes are busy, and return it; None when the user set it or all cores are free
    (torch's own default then). Silent: a command's stderr stays its one sentence on failure."""
    if os.environ.get(ENV):
        return None
    cores, load, running = machine()
    threads = threads_for(cores, load, running)
    if threads >= cores:
        return None
    os.environ[ENV] = str(threads)
    return threads
