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
import threading
import time

__all__ = ["ThreadClock"]

_SCHEDSTAT = "/proc/thread-self/schedstat"


class ThreadClock:
    """Readings of the calling thread's CPU and run-queue time, in milliseconds.

    Keeps one open descriptor of ``schedstat`` per thread that reads it (a reading is one
    ``pread``, a few microseconds: cheap enough for every frame)."""

    def __init__(self) -> None:
        self._local = threading.local()
        self.has_runqueue = os.path.exists(_SCHEDSTAT)

    def read(self) -> tuple[float, float | None]:
        """(CPU ms, run-queue ms or None where the platform does not say), both cumulative
        for the calling thread: subtract two readings for the time between them."""
        if self.has_runqueue:
            fd = getattr(self._local, "fd", None)
            try:
                if fd is None:
                    fd = self._local.fd = os.open(_SCHEDSTAT, os.O_RDONLY)
                on_cpu, waiting = os.pread(fd, 128, 0).split()[:2]
                return int(on_cpu) / 1e6, int(waiting) / 1e6
            except (OSError, ValueError):  # a kernel without schedstats: CPU time only from now on
                self.has_runqueue = False
        return time.thread_time() * 1e3, None

    def close(self) -> None:
        """Close the calling thread's descriptor (others close with the process)."""
        fd = getattr(self._local, "fd", None)
        if fd is not None:
            os.close(fd)
            self._local.fd = None
