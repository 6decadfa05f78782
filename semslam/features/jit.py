"""Compile (or load from numba's on-disk cache) every compiled kernel before the first
frame, so that JIT time is reported once (``stats.json``: ``jit_warmup_s``) and never
counted in a frame's time.

Each kernel module exposes ``warm_up()``, which calls its kernels on tiny inputs of the
types the pipeline uses; add new kernel modules to ``KERNEL_MODULES``.
"""

from __future__ import annotations

import importlib
import time

KERNEL_MODULES = (
    "semslam.features.matching_kernels",
    "semslam.features.keypoint_grid",
    "semslam.backend.pose_only",
    "semslam.dynamics.multiview_kernels",
)

_done = False


def warm_up() -> float:
    """Seconds spent compiling or loading the kernels (0 after the first call in a process)."""
    global _done
    if _done:
        return 0.0
    t0 = time.perf_counter()
    for name in KERNEL_MODULES:
        importlib.import_module(name).warm_up()
    _done = True
    return time.perf_counter() - t0
