"""Run bundle adjustments in a separate process.

GTSAM's Python bindings hold the GIL while they optimise, so a BA in a thread stalls
tracking for its whole duration (measured: other Python work ran 5x slower). A BA problem
is a handful of numpy arrays, cheap to send to a worker process, which lets tracking and
optimisation use both cores as ORB-SLAM's threads do.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from semslam.backend.bundle_adjustment import BAProblem, BAResult, bundle_adjust, warm_up


def _warm() -> bool:
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
        if use_process and self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
            self._pool.submit(_warm)

    def run(self, problem: BAProblem, **kwargs: Any) -> BAResult:
        if self._pool is None:
            return bundle_adjust(problem, **kwargs)
        return self._pool.submit(bundle_adjust, problem, **kwargs).result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
