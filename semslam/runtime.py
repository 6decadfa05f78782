"""Process-wide settings for running SLAM on a few cores, applied by entry points.

SLAM runs its own threads (tracking, local mapping, loop closing) and a BA worker
process; BLAS and OpenCV worker pools on top of them only compete for the cores
(measured on 2 cores: 36 -> 28 ms/frame median on room_loop). Nothing here acts at import:
the CLI's ``main`` and the benchmark scripts call ``limit_threads()`` first thing (BLAS
reads its variables when numpy loads), a library user decides for their own process, and
a Ray worker gets what its task sets. The environment overrides the defaults.
"""

from __future__ import annotations

import os

BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_threads() -> None:
    """One BLAS thread (for libraries not yet loaded) and one OpenCV thread, unless the
    environment (``*_NUM_THREADS``, ``SEMSLAM_OPENCV_THREADS``) says otherwise."""
    for var in BLAS_VARIABLES:
        os.environ.setdefault(var, "1")
    import cv2

    cv2.setNumThreads(int(os.environ.get("SEMSLAM_OPENCV_THREADS", "1")))


#: Niceness added to the threads and the process that tracking does not wait for (local
#: mapping, loop closing, the BA worker): on 2 cores they then take the CPU when tracking
#: and the semantic thread leave it, instead of delaying the current frame. Off by default:
#: on this 2-core machine the comparison (4 runs of `default` on walking_xyz) was drowned
#: by other load and showed no clear gain; set SEMSLAM_BACKGROUND_NICE=5 to try it.
BACKGROUND_NICE = int(os.environ.get("SEMSLAM_BACKGROUND_NICE", "0"))


def lower_thread_priority(increment: int | None = None) -> bool:
    """Lower the calling thread's CPU priority by ``increment`` (default
    ``BACKGROUND_NICE``; Linux applies a niceness per thread). Returns whether it took
    effect (never raises: a platform without per-thread priorities just runs as is)."""
    import threading

    inc = BACKGROUND_NICE if increment is None else increment
    if inc <= 0 or not hasattr(os, "setpriority"):
        return False
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + inc))
    except OSError:
        return False
    return True
