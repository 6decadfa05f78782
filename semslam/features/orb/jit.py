"""Compile the ORB kernels once, before the first frame.

numba compiles a kernel at its first call (seconds each; ~20 s for all of them on a cold
cache on the project machine) and caches the machine code on disk next to the modules
(``__pycache__``, or ``NUMBA_CACHE_DIR``), so later processes only load it (well under a
second). ``warm_up`` makes that happen on tiny inputs through the same wrappers the
extractors call (hence the same compiled signatures), so no frame pays for it; both ORB
extractors call it from their constructor. Call it yourself to do it earlier, e.g. before
starting the tracking thread.

numba keys a cached kernel by the file it is defined in, so each kernel module
(``fast_kernels``, ``brief_kernels``, ``quadtree_kernels``, ``pyramid_kernels``,
``blur_kernels``, ``harris_kernels``) only
calls kernels of its own module: editing one can never leave a stale copy inlined in
another.
"""

from __future__ import annotations

import threading
import time

import numpy as np

__all__ = ["warm_up"]

_lock = threading.Lock()
_done = False


def warm_up() -> float:
    """Compile (or load from the disk cache) every kernel of ``semslam.features.orb``,
    once per process. Returns the seconds this call spent (0.0 once done)."""
    global _done
    with _lock:
        if _done:
            return 0.0
        start = time.perf_counter()
        _run_kernels()
        _done = True
        return time.perf_counter() - start


def _run_kernels() -> None:
    """Every kernel once, on inputs of the types the extractors pass."""
    from semslam.features.orb.blur import blur_levels
    from semslam.features.orb.descriptors import ic_angles, orb_descriptors
    from semslam.features.orb.detection import detect_levels, detect_levels_two_thresholds, fast_points
    from semslam.features.orb.harris import harris_responses
    from semslam.features.orb.pyramid import MaskSampler, build_pyramid
    from semslam.features.orb.quadtree import SplitRule, distribute_quadtree_leaves

    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (48, 48), dtype=np.uint8)
    mask = np.ones((48, 48), np.uint8)
    pyr = build_pyramid(image, 2, 1.2, pad=3)
    blur_levels(pyr, np.zeros_like(pyr.buffer))
    fast_points(image, 20)
    x, y, score, level = detect_levels([image], 20, 7, [MaskSampler.same_size(mask)])
    for masks in (None, [MaskSampler.same_size(mask)]):
        detect_levels_two_thresholds([image], np.array([10_000]), 20, 7, masks)  # low pass included
    harris_responses(image, np.array([24]), np.array([24]))
    for rule in (SplitRule.ORB_SLAM, SplitRule.HIGH_QUALITY):
        distribute_quadtree_leaves(x, y, score, level, np.array([16]), np.array([16]), np.array([4]),
                                   score >= 20, rule)
    cx, cy = np.array([24]), np.array([24])
    orb_descriptors(image, cx, cy, ic_angles(image, cx, cy))
