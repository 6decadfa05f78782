"""ORB-SLAM's motion model: the last frame's motion repeated."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from semslam.slam.orb.motion_priors.base import (Correction, FrameImages, FrameOutcome, MotionState, PosePrediction,
                                             Stage, TrackerOps)

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState


class ConstantVelocity:
    """Predicts ``velocity @ T_cw`` of the last frame; nothing without a velocity."""

    name = "constant_velocity"

    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None:
        if state.velocity is None or state.last is None or state.last.T_cw is None:
            return None
        return PosePrediction(state.velocity @ state.last.T_cw)

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        return None

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        return orb_slam_wants()

    def counters(self) -> dict[str, int]:
        return {}

    def update(self, outcome: FrameOutcome) -> None:
        """The velocity is tracking's motion state (``MotionState``), measured there."""
