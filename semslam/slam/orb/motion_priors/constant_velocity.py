"""ORB-SLAM's motion model: the last frame's motion repeated."""

from __future__ import annotations

from semslam.slam.orb.motion_priors.base import FrameImages, MotionState, PosePrediction, PriorDefaults


class ConstantVelocity(PriorDefaults):
    """Predicts ``velocity @ T_cw`` of the last frame; nothing without a velocity (the
    velocity is tracking's motion state, measured there, so nothing is kept here)."""

    name = "constant_velocity"

    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None:
        if state.velocity is None or state.last is None or state.last.T_cw is None:
            return None
        return PosePrediction(state.velocity @ state.last.T_cw)
