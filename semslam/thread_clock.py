"""Where a thread's wall time went: on a CPU, waiting in the run queue for one, or neither.

Why: on 2 cores a frame's tracking time is its own CPU work plus waits - for a core (other
threads and processes run on both) and for the GIL or a lock (a sleeping thread). Each
wants a different remedy (less work, priorities, fewer GIL hand-overs), and wall time alone
cannot tell them apart. Linux's ``/proc/thread-self/schedstat`` gives the first two per
thread (nanoseconds on a CPU, nanoseconds runnable but waiting); the rest of the wall time
is time the thread slept. Elsewhere only the CPU time is known (``time.thread_time``).
"""

from __future__ import annotations

import os
import time

__all__ = ["thread_times"]

_SCHEDSTAT = "/proc/thread-self/schedstat"
_has_schedstat = os.path.exists(_SCHEDSTAT)


def thread_times() -> tuple[float, float | None]:
    """(CPU ms, run-queue ms or None where the platform does not say), both cumulative for
    the calling thread: subtract two readings for the time between them. One open, read
    and close of ``schedstat`` (~10 us; nothing is kept open, so nothing leaks however many
    runs a process makes)."""
    global _has_schedstat
    if _has_schedstat:
        try:
            fd = os.open(_SCHEDSTAT, os.O_RDONLY)
            try:
                on_cpu, waiting = os.read(fd, 128).split()[:2]
            finally:
                os.close(fd)
            return int(on_cpu) / 1e6, int(waiting) / 1e6
        except (OSError, ValueError):  # a kernel without schedstats: CPU time only from now on
            _has_schedstat = False
    return time.thread_time() * 1e3, None
