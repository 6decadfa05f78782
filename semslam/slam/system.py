"""The System: one object that takes frames and keeps the trajectory.

``System.track(frame)`` is the only call a driver needs; which tracker runs behind it is
chosen by ``config.tracking.method`` (later issues add ORB-SLAM-class tracking, local
mapping and loop closing behind the same call).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from semslam.config import SystemConfig
from semslam.errors import ConfigError
from semslam.geometry.camera import PinholeCamera
from semslam.io.sequence import Frame
from semslam.io.trajectory import Trajectory
from semslam.slam.types import TrackingState, TrackResult


def _frame_to_keyframe(config: SystemConfig, camera: PinholeCamera):  # type: ignore[no-untyped-def]
    from semslam.slam.frame_to_keyframe import FrameToKeyframeTracker

    return FrameToKeyframeTracker(config, camera)


TRACKERS: dict[str, Callable] = {"frame_to_keyframe": _frame_to_keyframe}  # type: ignore[type-arg]


class System:
    """Runs one tracker over frames and records every result."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera) -> None:
        if config.tracking.method not in TRACKERS:
            raise ConfigError(f"tracking.method: unknown tracker {config.tracking.method!r} (known: {', '.join(TRACKERS)})")
        if config.sensor != "rgbd":
            raise ConfigError(f"sensor: {config.sensor!r} is not supported yet (rgbd only)")
        self.config = config
        self.camera = camera
        self.tracker = TRACKERS[config.tracking.method](config, camera)
        self.results: list[TrackResult] = []

    def track(self, frame: Frame) -> TrackResult:
        result = self.tracker.track(frame)
        self.results.append(result)
        return result

    @property
    def n_keyframes(self) -> int:
        return int(getattr(self.tracker, "n_keyframes", 0))

    def trajectory(self) -> Trajectory:
        """Poses of every frame that has one (all frames after initialisation)."""
        rows = [r for r in self.results if r.pose_wc is not None]
        if not rows:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        return Trajectory(np.array([r.timestamp for r in rows]), np.stack([r.pose_wc for r in rows]))

    def counts(self) -> dict[str, int]:
        states = [r.state for r in self.results]
        return {
            "frames": len(states),
            "tracked_frames": sum(s is TrackingState.OK for s in states),
            "lost_frames": sum(s is TrackingState.LOST for s in states),
            "uninitialized_frames": sum(s is TrackingState.NOT_INITIALIZED for s in states),
            "keyframes": self.n_keyframes,
        }

    def shutdown(self) -> None:
        """Stop background work (none yet; local mapping and loop closing threads later)."""
