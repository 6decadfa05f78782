"""STDC-SLAM's semantic thread (Fig. 1): segment each frame in a thread of its own as soon
as it is decoded, so segmentation of frame k+1 runs while frame k is tracked; tracking
waits only for what it needs, the mask of its own frame.

The mask is the segmenter's a-priori dynamic classes, grown over depth by STDC-SLAM's
Segmentation Refinement Module (``dynamics/srm.py``) when it is on; both run in this
thread, ahead of tracking. What ``prepare`` started is kept here, keyed by the frame's
index, until tracking asks for the frame's mask.

Scheduling (``semantics.schedule`` / ``stride``): on two cores the segmenter competes with
tracking. A frame can be skipped - when it is decoded while the previous frame is still
being segmented (``when_behind``, ``latest``), or by a forced stride - and then gets the
mask of the last segmented frame, warped to it with the motion model (``dynamics/warp.py``).
With ``latest`` tracking does not wait either: a frame whose segmentation has not finished
gets the newest finished mask, warped; its own mask serves the frames after it.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from semslam.config import SemanticsConfig
from semslam.core.protocols import DepthSource, MotionPrior
from semslam.core.types import Frame, LabelMap
from semslam.dynamics.warp import plane_depth, relative_pose, warp_mask
from semslam.geometry.camera import PinholeCamera
from semslam.runtime import lower_thread_priority

log = logging.getLogger(__name__)


@dataclass
class _Segmented:
    """A segmented frame: what the masks of skipped frames after it are warped from."""

    index: int
    mask: NDArray[np.bool_] | Future[NDArray[np.bool_]]
    depth: NDArray[np.float32] | None

    @cached_property
    def plane_depth_m(self) -> float | None:
        """The warp's plane (``warp.plane_depth``), measured once for all the frames warped
        from this one (the mask must be finished)."""
        assert not isinstance(self.mask, Future)
        return plane_depth(self.mask, self.depth)


#: Tracked poses kept for warping (frames back from the newest): more than any backlog.
_POSE_HISTORY = 32


class SemanticThread:
    """``prepare(frame)`` starts segmenting (or skips the frame); ``mask(frame, prior)``
    returns (mask, ms tracking spent on it: waiting, or warping a skipped frame's mask);
    ``labels(index)`` the class labels behind the last mask given, if its own."""

    def __init__(self, cfg: SemanticsConfig, threaded: bool = True, camera: PinholeCamera | None = None,
                 depth: DepthSource | None = None) -> None:
        from semslam.semantics.base import create_segmenter

        self.cfg = cfg
        self.camera = camera
        # A depth network's depth for frames that come without one (a monocular camera): SRM
        # and the mask warp read it where an RGB-D frame's own depth would be.
        self._depth_source = depth
        self._pool = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="semantic",
            # With `latest` tracking never waits for this thread: it runs below tracking like
            # local mapping (at camera rate on 2 cores, walking_xyz 25-26 -> 24 ms/frame
            # median, late frames 67-84 -> 37-53; with `every` tracking waits for it, and
            # niced it made no difference).
            initializer=lower_thread_priority if cfg.schedule == "latest" else None) if threaded else None
        # Made in the thread that runs it: a backend's own inference threads (MediaPipe's
        # graph, a torch pool) inherit that thread's niceness. Made here, MediaPipe's ran at
        # tracking's priority beside the niced thread that only waited for them
        # (walking_xyz, 10 alternating pairs: 1.4 ms/frame median less at camera rate, 1.9
        # as fast as frames decode).
        if self._pool is None:
            self.segmenter = create_segmenter(cfg)
        else:
            try:
                self.segmenter = self._pool.submit(create_segmenter, cfg).result()
            except BaseException:
                self._pool.shutdown(wait=True)
                raise
        self._pending: Future[NDArray[np.bool_]] | None = None  # the last segmentation submitted
        self._started: dict[int, Future[NDArray[np.bool_]]] = {}  # submitted, until tracking takes them
        self._skipped: set[int] = set()  # frame indices prepare() decided not to segment
        self._source: _Segmented | None = None  # the newest finished segmentation tracking took
        self._late: list[_Segmented] = []  # ("latest") segmentations tracking went past unfinished
        self._poses: dict[int, NDArray[np.float64]] = {}  # recent tracked T_cw, from the priors
        self.segment_ms: list[float] = []
        self.refine_ms: list[float] = []
        self.wait_ms: list[float] = []  # tracking waiting for a segmented frame's mask
        self.warp_ms: list[float] = []  # tracking warping a skipped frame's mask
        self.frames_without_own_mask = 0  # ("latest") frames that did not wait for their own mask
        self._labels: dict[int, LabelMap] = {}  # segmented frames' labels until tracking takes them
        self._taken: tuple[int, LabelMap | None] = (-1, None)  # (frame, labels) of the last mask given
        self.resized_label_maps = 0  # backend answers of another size than the frame
        self._closed = False

    def _compute(self, frame: Frame) -> NDArray[np.bool_]:
        from semslam.semantics.base import dynamic_mask

        t0 = time.perf_counter()
        labels = self.segmenter.segment(frame.rgb, frame)
        if labels.shape != frame.rgb.shape[:2]:
            labels = self._resized(labels, frame)
        self._labels[frame.index] = labels  # for the maps' classes (keyframes take it)
        mask = dynamic_mask(labels, list(self.cfg.dynamic_classes))
        t1 = time.perf_counter()
        self.segment_ms.append((t1 - t0) * 1e3)
        depth = self._depth_of(frame) if self.cfg.srm and mask.any() else None
        if depth is not None:
            from semslam.dynamics.srm import refine_segmentation

            mask = refine_segmentation(mask, depth, window=self.cfg.srm_window, tau=self.cfg.srm_tau_m)
            self.refine_ms.append((time.perf_counter() - t1) * 1e3)
        return mask

    def _depth_of(self, frame: Frame) -> NDArray[np.float32] | None:
        """The frame's depth: its own (RGB-D, a stereo pair's), else the depth network's."""
        if frame.depth is not None or self._depth_source is None:
            return frame.depth
        return self._depth_source.depth(frame)

    def _resized(self, labels: LabelMap, frame: Frame) -> LabelMap:
        """A backend that answered at another size: its labels resized to the frame, with a
        warning the first time and a count (``resized_label_maps``)."""
        from semslam.semantics.base import fit_labels

        if not self.resized_label_maps:
            log.warning("semantics.backend=%s returned %dx%d labels for a %dx%d image (frame %d); resizing them "
                        "(nearest neighbour), counted in stats.json as resized_label_maps",
                        self.cfg.backend, labels.shape[1], labels.shape[0], frame.rgb.shape[1], frame.rgb.shape[0],
                        frame.index)
        self.resized_label_maps += 1
        return fit_labels(labels, frame.rgb.shape[:2])

    def _on_stride(self, index: int) -> bool:
        return index % self.cfg.stride == 0

    def _behind(self) -> bool:
        """The previous frame is still being segmented (a backlog is building)."""
        return (self.cfg.schedule != "every" and self._pending is not None
                and not self._pending.done())

    def prepare(self, frame: Frame) -> None:
        """Start segmenting the frame, or mark it skipped (called from the reader, right
        after decoding)."""
        index = frame.index
        if not self._on_stride(index) or (self._pool is not None and self._behind()):
            self._skipped.add(index)
        elif self._pool is not None:
            self._started[index] = self._pending = self._pool.submit(self._compute, frame)

    def mask(self, frame: Frame, prior: MotionPrior | None = None) -> tuple[NDArray[np.bool_], float]:
        """The frame's mask: its own segmentation, or (skipped frame, or ``latest`` and not
        finished) the newest finished mask warped to it; called by tracking, frame after frame."""
        t0 = time.perf_counter()
        m: NDArray[np.bool_] | Future[NDArray[np.bool_]] | None = self._started.pop(frame.index, None)
        labels: LabelMap | None = None
        self._learn_pose(prior)
        self._promote_late()
        skipped = frame.index in self._skipped or (m is None and not self._on_stride(frame.index))
        self._skipped.discard(frame.index)
        if (isinstance(m, Future) and not m.done() and self.cfg.schedule == "latest"
                and self._source is not None):
            self._late.append(_Segmented(frame.index, m, self._depth_of(frame)))
            self.frames_without_own_mask += 1
            skipped, m = True, None
        if skipped and m is None and self._source is not None:
            m = self._warp(frame.index, prior)
            ms = (time.perf_counter() - t0) * 1e3
            self.warp_ms.append(ms)
        else:
            if isinstance(m, Future):
                m = m.result()
            elif m is None:
                m = self._compute(frame)
            self._source = _Segmented(frame.index, m, self._depth_of(frame))
            self._late.clear()  # all older than this frame
            labels = self._labels.pop(frame.index, None)
            for old in [i for i in list(self._labels) if i < frame.index]:  # list(): one C-level copy,
                self._labels.pop(old, None)  # safe while the semantic thread inserts
            ms = (time.perf_counter() - t0) * 1e3
            self.wait_ms.append(ms)
        self._taken = (frame.index, labels)
        return m, ms

    def labels(self, index: int) -> LabelMap | None:
        """The class labels of frame ``index`` if ``mask`` last gave its own segmentation."""
        taken, labels = self._taken
        return labels if taken == index else None

    def _learn_pose(self, prior: MotionPrior | None) -> None:
        """A frame's tracked pose arrives with the prior of the frame after it."""
        if prior is None:
            return
        self._poses[prior.last_index] = prior.T_cw_last.copy()
        for index in [i for i in self._poses if i < prior.last_index - _POSE_HISTORY]:
            del self._poses[index]

    def _promote_late(self) -> None:
        """The newest segmentation tracking went past that has finished since becomes the source."""
        done = [s for s in self._late if isinstance(s.mask, Future) and s.mask.done()]
        if not done:
            return
        newest = done[-1]
        assert isinstance(newest.mask, Future)
        self._source = _Segmented(newest.index, newest.mask.result(), newest.depth)
        self._late = [s for s in self._late if s.index > newest.index]

    def _warp(self, index: int, prior: MotionPrior | None) -> NDArray[np.bool_]:
        """The source mask moved by the camera's motion; the margin, for the people's own
        motion, grows with the frames since the source (benchmarks/mask_warp.py)."""
        src = self._source
        assert src is not None and not isinstance(src.mask, Future)
        T_kj = None
        if self.cfg.warp == "pose" and prior is not None and self.camera is not None:
            T_kj = relative_pose(self._poses.get(src.index), prior.predicted())
        margin = self.cfg.warp_margin_px * max(1, index - src.index)
        return warp_mask(src.mask, src.depth, self.camera, T_kj, margin,
                         src.plane_depth_m if T_kj is not None else None)

    def stats(self) -> dict[str, float]:
        def median(v: list[float]) -> float:
            return float(np.median(v)) if v else 0.0

        def p95(v: list[float]) -> float:
            return float(np.percentile(v, 95)) if v else 0.0

        return {
            "segmented_frames": len(self.segment_ms),
            "segment_ms_median": median(self.segment_ms),
            "segment_ms_p95": p95(self.segment_ms),
            "srm_ms_median": median(self.refine_ms),
            "semantic_wait_ms_median": median(self.wait_ms),
            "semantic_wait_ms_p95": p95(self.wait_ms),
            "warped_frames": len(self.warp_ms),
            "warp_ms_median": median(self.warp_ms),
            "warp_ms_p95": p95(self.warp_ms),
            "frames_without_own_mask": self.frames_without_own_mask,
            "resized_label_maps": self.resized_label_maps,
        }

    def close(self) -> None:
        """Stop the thread and free the segmenter; safe to call twice, stats stay readable."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if not self._closed:
            self._closed = True
            self.segmenter.close()
