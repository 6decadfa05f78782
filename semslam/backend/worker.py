"""Run bundle adjustments and pose graphs in a separate process.

GTSAM's Python bindings hold the GIL while they optimise, so a GTSAM solve in a thread stalls
tracking for its whole duration (measured: other Python work ran 5x slower); the essential
graph (GTSAM) and the BAs run here for that reason.  A problem is a handful of numpy arrays,
cheap to send to a worker process, which lets tracking and optimisation use both cores as
ORB-SLAM's threads do.  (The default BA solver, numba's, releases the GIL; it runs here too,
so that both solvers behave alike; ``benchmarks/backend_timing.py slam`` reports the IPC.)
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem, BAResult, bundle_adjust, warm_up
from semslam.backend.pose_graph import optimize_pose_graph
from semslam.runtime import lower_thread_priority


def _warm() -> bool:
    lower_thread_priority()  # the worker's one thread runs every BA: below tracking
    warm_up()  # load the compiled solver (and GTSAM) once, so the first BA does not pay for it
    return True


class BundleAdjustmentRunner:
    """``run(problem, **kwargs) -> BAResult``, in this process or in one worker process.

    Built inert; ``start(use_process=True)`` starts the worker process (so the owner can
    build everything that may fail first), ``close()`` ends it. Until started, or after
    ``start(use_process=False)``, BAs run in the calling thread.
    """

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None

    def start(self, use_process: bool) -> None:
        """Start the worker process, which loads the compiled solver while tracking starts;
        in-process, load it now (so no frame pays for it)."""
        if use_process and self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
            self._pool.submit(_warm)
        elif not use_process:
            warm_up()

    def run(self, problem: BAProblem, **kwargs: Any) -> BAResult:
        if self._pool is None:
            return bundle_adjust(problem, **kwargs)
        return self._pool.submit(bundle_adjust, problem, **kwargs).result()

    def run_pose_graph(self, *args: Any, **kwargs: Any) -> NDArray[np.float64]:
        """``pose_graph.optimize_pose_graph`` in the worker (raises its ``PoseGraphFailed``)."""
        if self._pool is None:
            return optimize_pose_graph(*args, **kwargs)
        return self._pool.submit(optimize_pose_graph, *args, **kwargs).result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
