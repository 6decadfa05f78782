"""Where bundle adjustments and pose graphs run.

The default BA solver (``solver="schur"``, numba) releases the GIL while it solves, so it runs
in the calling thread (local mapping's, loop closing's) beside tracking on the other core,
with nothing to copy.  GTSAM's Python bindings hold the GIL while they optimise, so a GTSAM
solve in a thread stalls tracking for its whole duration (measured: other Python work ran 5x
slower): the essential graph and BAs with ``solver="gtsam"`` run in a worker process when the
system is threaded.  A problem is a handful of numpy arrays, cheap to send there.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem, BAResult, bundle_adjust, warm_up
from semslam.backend.pose_graph import optimize_pose_graph, optimize_sim3_pose_graph
from semslam.runtime import lower_thread_priority
from semslam.worker_processes import worker_pool

log = logging.getLogger(__name__)
R = TypeVar("R")


def _warm() -> bool:
    lower_thread_priority()  # the worker's one thread runs every GTSAM solve: below tracking
    import gtsam  # noqa: F401  (import once so the first solve does not pay for it)

    return True


class BundleAdjustmentRunner:
    """``run(problem, **kwargs) -> BAResult``, ``run_pose_graph(...)`` and ``run_sim3_pose_graph(...)``.

    Built inert; ``start(use_process)`` loads the compiled solver into this process (from
    numba's disk cache; so no frame pays for it) and, for a threaded system, starts the
    worker process for GTSAM (so the owner can build everything that may fail first);
    ``close()`` ends it.  Schur BAs always run in the calling thread; GTSAM solves run in the
    worker once it is started, else in the calling thread.
    """

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()  # local mapping and loop closing share the worker
        #: Times the worker process died (killed, out of memory) and was started again.
        self.restarts = 0

    def start(self, use_process: bool) -> None:
        warm_up()
        if use_process and self._pool is None:
            self._pool = self._new_pool()

    @staticmethod
    def _new_pool() -> ProcessPoolExecutor:
        # Ends with a SIGKILLed run (one stayed 25 min before exit_with_parent) and does not
        # re-run a user's script that lacks a __main__ guard (semslam/worker_processes.py).
        pool = worker_pool()
        pool.submit(_warm)
        return pool

    def run(self, problem: BAProblem, **kwargs: Any) -> BAResult:
        if self._pool is None or kwargs.get("solver", "schur") == "schur":
            return bundle_adjust(problem, **kwargs)
        return self._in_worker(bundle_adjust, problem, **kwargs)

    def run_pose_graph(self, *args: Any, **kwargs: Any) -> NDArray[np.float64]:
        """``pose_graph.optimize_pose_graph`` in the worker (raises its ``PoseGraphFailed``)."""
        if self._pool is None:
            return optimize_pose_graph(*args, **kwargs)
        return self._in_worker(optimize_pose_graph, *args, **kwargs)

    def run_sim3_pose_graph(self, *args: Any, **kwargs: Any) -> NDArray[np.float64]:
        """``pose_graph.optimize_sim3_pose_graph`` (monocular maps) in the worker, as
        ``run_pose_graph``."""
        return self._in_worker(optimize_sim3_pose_graph, *args, **kwargs)

    def _in_worker(self, fn: Callable[..., R], *args: Any, **kwargs: Any) -> R:
        """``fn`` in the worker process; if the process died (killed, out of memory), a new
        one is started and the solve redone once, with a warning (``restarts`` counts)."""
        for attempt in (1, 2):
            with self._lock:
                pool = self._pool
            if pool is None:  # closed meanwhile (shutdown): solve here
                return fn(*args, **kwargs)
            try:
                return pool.submit(fn, *args, **kwargs).result()
            except BrokenProcessPool:
                with self._lock:
                    if self._pool is pool:  # not already restarted by the other thread
                        pool.shutdown(wait=False, cancel_futures=True)
                        self._pool = self._new_pool()
                        self.restarts += 1
                        log.warning("the BA worker process died; started a new one (restart %d), %s",
                                    self.restarts, "redoing the solve" if attempt == 1 else "giving up")
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def worker_pids(self) -> list[int]:
        """Pids of the worker process (none when solves run in the caller's thread)."""
        with self._lock:
            pool = self._pool
        return [] if pool is None else [p.pid for p in (getattr(pool, "_processes", None) or {}).values()]

    def close(self) -> None:
        """End the worker process (and wait for it: no process of a run outlives it)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
