"""The semantic thread (STDC-SLAM Fig. 1): segment each frame in a thread of its own as
soon as it is decoded, so segmentation of frame k+1 runs while frame k is tracked;
tracking waits only for what it needs, the mask of its own frame.

The mask is the segmenter's a-priori dynamic classes, optionally grown over depth by the
Segmentation Refinement Module.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from semslam.io.sequence import Frame


class SemanticWorker:
    """``prepare(frame)`` starts segmenting; ``mask(frame)`` returns (mask, ms waited)."""

    def __init__(self, semantics_cfg, threaded: bool = True) -> None:  # type: ignore[no-untyped-def]
        from semslam.semantics.base import create_segmenter

        self.cfg = semantics_cfg
        self.segmenter = create_segmenter(semantics_cfg)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="semantic") if threaded else None
        self.segment_ms: list[float] = []
        self.refine_ms: list[float] = []

    def _compute(self, frame: Frame) -> NDArray[np.bool_]:
        from semslam.semantics.base import dynamic_mask

        t0 = time.perf_counter()
        labels = self.segmenter.segment(frame.rgb, frame)
        mask = dynamic_mask(labels, list(self.cfg.dynamic_classes))
        t1 = time.perf_counter()
        self.segment_ms.append((t1 - t0) * 1e3)
        if self.cfg.srm and frame.depth is not None and mask.any():
            from semslam.semantics.refinement import refine_segmentation

            mask = refine_segmentation(mask, frame.depth, window=self.cfg.srm_window, tau=self.cfg.srm_tau_m)
            self.refine_ms.append((time.perf_counter() - t1) * 1e3)
        return mask

    def prepare(self, frame: Frame) -> Frame:
        """Start segmenting ``frame`` (call from the reader, right after decoding)."""
        if self._pool is not None and frame.dynamic_mask is None:
            frame.dynamic_mask = self._pool.submit(self._compute, frame)
        return frame

    def mask(self, frame: Frame) -> tuple[NDArray[np.bool_], float]:
        t0 = time.perf_counter()
        m = frame.dynamic_mask
        if isinstance(m, Future):
            m = m.result()
        elif m is None:
            m = self._compute(frame)
        frame.dynamic_mask = m
        return m, (time.perf_counter() - t0) * 1e3

    def stats(self) -> dict[str, float]:
        return {
            "segment_ms_median": float(np.median(self.segment_ms)) if self.segment_ms else 0.0,
            "srm_ms_median": float(np.median(self.refine_ms)) if self.refine_ms else 0.0,
        }

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
