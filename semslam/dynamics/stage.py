"""The dynamic-scene stage around tracking: one object, two hooks.

Before extraction (``before_extraction``): STDC-SLAM's semantic thread gives the mask of
a-priori dynamic classes, refined by SRM (``semantic_thread.py``, ``srm.py``), and DDL-SLAM's
border band grows it (``masks.py``); no keypoint is extracted there.
After the pose (``after_pose``): DDL-SLAM's multi-view geometry (``multiview.py``, III-D)
compares the frame's depth with the best-overlapping keyframes and returns the moving
regions; the tracker drops keypoints there and culls the map points matched inside.
A monocular frame has no depth: ``after_pose_mono`` runs the check's two-view form
(``multiview_mono.py``: epipolar distance and reprojection error against the keyframes).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.config import DynamicsConfig, SemanticsConfig
from semslam.core.protocols import DepthSource, FramePacket, MotionPrior, MovingRegions
from semslam.core.types import FeatureSpec, Frame, LabelMap
from semslam.dynamics.masks import dilate, extractor_mask
from semslam.dynamics.multiview import multiview_mask
from semslam.dynamics.multiview_mono import MonoView, mono_multiview
from semslam.geometry.camera import PinholeCamera

Reference = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]


class SceneDynamics:
    """``DynamicStage`` for the presets: semantic thread + SRM + border band, multi-view geometry."""

    def __init__(self, dyn: DynamicsConfig, sem: SemanticsConfig, camera: PinholeCamera, threaded: bool,
                 depth: DepthSource | None = None) -> None:
        from semslam.dynamics.semantic_thread import SemanticThread

        self.border_px = dyn.border_px
        self.camera = camera
        self.semantic = SemanticThread(sem, threaded=threaded, camera=camera, depth=depth) if dyn.semantic else None
        self.multiview = dyn if dyn.multiview else None

    def prepare(self, frame: Frame) -> None:
        if self.semantic is not None:
            self.semantic.prepare(frame)

    def before_extraction(self, packet: FramePacket, prior: MotionPrior | None = None
                          ) -> tuple[NDArray[np.bool_] | None, NDArray[np.uint8] | None, float]:
        if self.semantic is None:
            return None, None, 0.0
        dynamic, wait_ms = self.semantic.mask(packet.frame, prior)
        return dynamic, extractor_mask(dynamic, self.border_px), wait_ms

    def labels(self, index: int) -> LabelMap | None:
        return self.semantic.labels(index) if self.semantic is not None else None

    def after_pose(self, T_cw: NDArray[np.float64], depth: NDArray[np.float32],
                   references: list[Reference]) -> MovingRegions | None:
        if self.multiview is None:
            return None
        res = multiview_mask(T_cw, depth, self.camera, references, self.multiview)
        if not res.mask.any():
            return None
        return MovingRegions(res.mask, dilate(res.mask, self.border_px))

    def after_pose_mono(self, current: MonoView, references: list[MonoView], spec: FeatureSpec
                        ) -> MovingRegions | None:
        """``after_pose`` for a monocular frame: the two-view tests instead of depth."""
        if self.multiview is None:
            return None
        w, h = self.camera.image_size
        mask, _ = mono_multiview(current, references, self.camera, spec, (int(round(h)), int(round(w))),
                                 self.multiview)
        if not mask.any():
            return None
        return MovingRegions(mask, dilate(mask, self.border_px))

    def stats(self) -> dict[str, float]:
        return self.semantic.stats() if self.semantic is not None else {}

    def close(self) -> None:
        # The thread is kept (closed) so that ``stats()`` still reports after shutdown:
        # the pipeline writes stats.json after stopping every thread.
        if self.semantic is not None:
            self.semantic.close()


def create_dynamic_stage(dyn: DynamicsConfig, sem: SemanticsConfig, camera: PinholeCamera,
                         threaded: bool, depth: DepthSource | None = None) -> SceneDynamics | None:
    """The stage the config asks for, or None when dynamics handling is off. ``depth``: a
    depth network, for frames without their own depth (SRM and the mask warp read it)."""
    if not (dyn.semantic or dyn.multiview):
        return None
    return SceneDynamics(dyn, sem, camera, threaded, depth)
