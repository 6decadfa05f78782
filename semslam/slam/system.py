"""The System: one object that takes frames and keeps the trajectory.

``System.track(frame)`` is the only call a driver needs; which tracker runs behind it is
chosen by ``config.tracking.method`` (later issues add ORB-SLAM-class tracking, local
mapping and loop closing behind the same call).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

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


def _orb_slam(config: SystemConfig, camera: PinholeCamera, map_path: Path | None = None):  # type: ignore[no-untyped-def]
    from semslam.slam.orb_slam import OrbSlam

    slam_map = None
    if map_path is not None:
        from semslam.features import feature_spec
        from semslam.slam.map_io import load_map

        slam_map = load_map(map_path, feature_spec(config.features))
    return OrbSlam(config, camera, slam_map)


TRACKERS: dict[str, Callable] = {"frame_to_keyframe": _frame_to_keyframe, "orb_slam": _orb_slam}  # type: ignore[type-arg]


class System:
    """Runs one tracker over frames and records every result."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera, map_path: Path | None = None) -> None:
        if config.tracking.method not in TRACKERS:
            raise ConfigError(f"tracking.method: unknown tracker {config.tracking.method!r} (known: {', '.join(TRACKERS)})")
        if config.sensor != "rgbd":
            raise ConfigError(f"sensor: {config.sensor!r} is not supported yet (rgbd only)")
        self.config = config
        self.camera = camera
        if map_path is not None and config.tracking.method != "orb_slam":
            raise ConfigError("--load-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
        self.tracker = TRACKERS[config.tracking.method](config, camera, *([map_path] if map_path else []))
        self.results: list[TrackResult] = []

    def prepare(self, frame: Frame) -> Frame:
        """Start per-frame work that can run ahead of tracking (segmentation), from the reader."""
        fn = getattr(self.tracker, "prepare", None)
        return fn(frame) if fn else frame

    def track(self, frame: Frame) -> TrackResult:
        result = self.tracker.track(frame)
        self.results.append(result)
        return result

    @property
    def n_keyframes(self) -> int:
        return int(getattr(self.tracker, "n_keyframes", 0))

    def trajectory(self) -> Trajectory:
        """Poses of every frame that has one (all frames after initialisation); for trackers
        with a map, after their final optimisation."""
        if hasattr(self.tracker, "trajectory"):
            return self.tracker.trajectory()
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

    def keyframe_trajectory(self) -> Trajectory | None:
        fn = getattr(self.tracker, "keyframe_trajectory", None)
        return fn() if fn else None

    def extra_stats(self) -> dict[str, object]:
        fn = getattr(self.tracker, "extra_stats", None)
        return fn() if fn else {}

    def save_map(self, path: Path) -> None:
        fn = getattr(self.tracker, "save_map", None)
        if fn is None:
            raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
        fn(path)

    def shutdown(self) -> None:
        """Stop background work: let local mapping and loop closing finish their queues."""
        fn = getattr(self.tracker, "shutdown", None)
        if fn:
            fn()
