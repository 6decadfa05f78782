"""Run bundle adjustments in a separate process.

GTSAM's Python bindings hold the GIL while they optimise, so a BA in a thread stalls
tracking for its whole duration (measured: other Python work ran 5x slower). A BA problem
is a handful of numpy arrays, cheap to send to a worker process, which lets tracking and
optimisation use both cores as ORB-SLAM's threads do.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

from semslam.backend.bundle_adjustment import BAProblem, BAResult, bundle_adjust


def _warm() -> bool:
    import gtsam  # noqa: F401  (import once so the first BA does not pay for it)

    return True


class BundleAdjustmentRunner:
    """``run(problem, **kwargs) -> BAResult``, in this process or in one worker process."""

    def __init__(self, use_process: bool) -> None:
        self._pool: ProcessPoolExecutor | None = None
        if use_process:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
            self._warmup: Future[bool] | None = self._pool.submit(_warm)
        else:
            self._warmup = None

    def run(self, problem: BAProblem, **kwargs: Any) -> BAResult:
        if self._pool is None:
            return bundle_adjust(problem, **kwargs)
        return self._pool.submit(bundle_adjust, problem, **kwargs).result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
