"""STDC-SLAM's semantic thread (Fig. 1): segment each frame in a thread of its own as soon
as it is decoded, so segmentation of frame k+1 runs while frame k is tracked; tracking
waits only for what it needs, the mask of its own frame.

The mask is the segmenter's a-priori dynamic classes, grown over depth by STDC-SLAM's
Segmentation Refinement Module (``dynamics/srm.py``) when it is on; both run in this
thread, ahead of tracking. The mask travels on the pipeline's ``FramePacket``.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from semslam.config import SemanticsConfig
from semslam.core.protocols import FramePacket
from semslam.core.types import Frame


class SemanticThread:
    """``prepare(packet)`` starts segmenting; ``mask(packet)`` returns (mask, ms waited)."""

    def __init__(self, cfg: SemanticsConfig, threaded: bool = True) -> None:
        from semslam.semantics.base import create_segmenter

        self.cfg = cfg
        self.segmenter = create_segmenter(cfg)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="semantic") if threaded else None
        self.segment_ms: list[float] = []
        self.refine_ms: list[float] = []
        self._closed = False

    def _compute(self, frame: Frame) -> NDArray[np.bool_]:
        from semslam.semantics.base import dynamic_mask

        t0 = time.perf_counter()
        labels = self.segmenter.segment(frame.rgb, frame)
        mask = dynamic_mask(labels, list(self.cfg.dynamic_classes))
        t1 = time.perf_counter()
        self.segment_ms.append((t1 - t0) * 1e3)
        if self.cfg.srm and frame.depth is not None and mask.any():
            from semslam.dynamics.srm import refine_segmentation

            mask = refine_segmentation(mask, frame.depth, window=self.cfg.srm_window, tau=self.cfg.srm_tau_m)
            self.refine_ms.append((time.perf_counter() - t1) * 1e3)
        return mask

    def prepare(self, packet: FramePacket) -> None:
        """Start segmenting the packet's frame (called from the reader, right after decoding)."""
        if self._pool is not None and packet.dynamic is None:
            packet.dynamic = self._pool.submit(self._compute, packet.frame)

    def mask(self, packet: FramePacket) -> tuple[NDArray[np.bool_], float]:
        t0 = time.perf_counter()
        m = packet.dynamic
        if isinstance(m, Future):
            m = m.result()
        elif m is None:
            m = self._compute(packet.frame)
        packet.dynamic = m
        return m, (time.perf_counter() - t0) * 1e3

    def stats(self) -> dict[str, float]:
        return {
            "segmented_frames": len(self.segment_ms),
            "segment_ms_median": float(np.median(self.segment_ms)) if self.segment_ms else 0.0,
            "segment_ms_p95": float(np.percentile(self.segment_ms, 95)) if self.segment_ms else 0.0,
            "srm_ms_median": float(np.median(self.refine_ms)) if self.refine_ms else 0.0,
        }

    def close(self) -> None:
        """Stop the thread and free the segmenter; safe to call twice, stats stay readable."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if not self._closed:
            self._closed = True
            self.segmenter.close()
