"""Compile (or load from numba's on-disk cache) every compiled kernel before the first
frame, so that JIT time is reported once (``stats.json``: ``jit_warmup_s``) and never
counted in a frame's time.

Each kernel module exposes ``warm_up()``, which calls its kernels on tiny inputs of the
types the pipeline uses; add new kernel modules of this layer or below to ``KERNEL_MODULES``,
those of higher layers to the caller's ``more`` (``assembly``).
"""

from __future__ import annotations

import importlib
import time

KERNEL_MODULES = (
    "semslam.features.matching_kernels",
    "semslam.features.keypoint_grid",
    "semslam.backend.pose_only",
)

_done: set[str] = set()


def warm_up(more: tuple[str, ...] = ()) -> float:
    """Seconds spent compiling or loading the kernels of ``KERNEL_MODULES`` and of ``more``
    (kernel modules of higher layers, named by their caller); modules already warmed up in
    this process are skipped."""
    t0 = time.perf_counter()
    for name in (*KERNEL_MODULES, *more):
        if name not in _done:
            importlib.import_module(name).warm_up()
            _done.add(name)
    return time.perf_counter() - t0
