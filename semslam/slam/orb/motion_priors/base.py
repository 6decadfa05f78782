"""What tracking asks its pose priors, and what it tells them.

A pose prior predicts or corrects the camera pose of a frame from something other than the
features' matches: the motion so far (constant velocity), the shift of the images (blurred
frames), a dense alignment of the images (depth odometry), the timing of a rolling
shutter's rows. Tracking keeps ORB-SLAM's flow (motion model -> reference keyframe ->
local map -> relocalisation -> keyframe decision) and asks its priors at fixed points of it:

* ``correct(Stage.FEATURES, ...)``: after extraction, before any matching (a prior may move
  the keypoints, e.g. to the rolling shutter's middle row);
* ``predict(state, frame)``: before matching, the pose to search from. The first prior in
  the list that returns a ``PosePrediction`` wins; the constant velocity comes last;
* ``correct(Stage.MATCHED, ...)`` after the motion model / reference keyframe /
  relocalisation, ``correct(Stage.LOCAL_MAP, ...)`` after the local map: a prior may refit
  or replace the pose (a ``Correction`` says whether the frame is tracked and whether its
  pose is now the prior's own); once one prior has posed the frame the later ones leave it;
* ``keyframe_wanted(...)``: asked of the prior that posed the frame, instead of ORB-SLAM's
  decision;
* ``update(outcome)``: once per frame, with what tracking made of it;
* ``counters()``: what it did so far, for the run's stats;
* ``map_aligned(rotation, scale)``: the map was moved by ``x' = scale * rotation @ x`` (the
  IMU's gravity alignment, a monocular map made metric): positions a prior keeps move too.

``MotionState`` is the state the priors predict from: the last frame, whether it was
tracked, and the velocity (``T_cw`` of this frame = ``velocity @ T_cw`` of the last) over
``velocity_dt`` seconds. The inertial prior (``inertial.py``) is one more prior: its
``predict`` integrates the IMU readings since ``state.last`` into a ``PosePrediction`` with
a ``covariance`` (6x6 on (rotation, translation) of the pose; tracking's pose optimisation
is held near the first prediction that has one) and a ``motion_covariance`` (the motion
from the last frame alone; tracking links keyframes by these motions), and its ``update``
re-estimates its own velocity and biases from the tracked poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.core.types import Frame
from semslam.geometry.se3 import so3_exp

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState
    from semslam.slam.orb.map import KeyFrame


class Stage(Enum):
    """Where in a frame's tracking a prior is asked to correct it."""

    FEATURES = "features"  # keypoints extracted, nothing matched yet (outside the map lock)
    MATCHED = "matched"  # motion model, reference keyframe or relocalisation done
    LOCAL_MAP = "local_map"  # the local map tracked (or not)


@dataclass(frozen=True)
class MotionState:
    """What the priors predict from: the last frame (its pose is ``last.T_cw``), whether it
    was tracked, and the velocity measured on it (None when unknown)."""

    last: "FrameState | None"
    tracked: bool
    velocity: NDArray[np.float64] | None
    velocity_dt: float  # seconds between the two frames the velocity was measured on


@dataclass(frozen=True)
class PosePrediction:
    """A pose to search the frame's features from."""

    T_cw: NDArray[np.float64]
    #: 6x6 on se(3) (rotation, translation); None when the prior cannot say. Tracking's pose
    #: optimisation holds the frame near ``T_cw`` with it.
    covariance: NDArray[np.float64] | None = None
    #: 6x6 of the motion from the last frame alone (without the last frame's own error); a
    #: prior that measures the motion (the IMU) gives it, and keyframes are linked by it.
    motion_covariance: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class CameraMotion:
    """How the camera moves at a frame's time, in its own frame: the angular rate (rad/s)
    and its centre's velocity (m/s; None where unknown). What a rolling shutter's rows
    were read out along."""

    rate: NDArray[np.float64]
    velocity: NDArray[np.float64] | None = None

    def over(self, dt: float, translation: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """The motion over ``dt`` seconds as a velocity ``V`` (``T_cw(t + dt) = V T_cw(t)``):
        ``R = exp(-w dt)``, ``t = -R v dt``; without a velocity, ``translation`` (none: 0)."""
        V = np.eye(4)
        V[:3, :3] = so3_exp(-self.rate * dt)
        if self.velocity is not None:
            V[:3, 3] = -V[:3, :3] @ self.velocity * dt
        elif translation is not None:
            V[:3, 3] = translation
        return V


@dataclass(frozen=True)
class Correction:
    """A prior's verdict after correcting a frame: tracked or not, and whether the pose is
    now the prior's own (not the features')."""

    tracked: bool
    posed: bool = False


@dataclass(frozen=True)
class FrameImages:
    """The frame as the sensor gave it, for priors that look at the images."""

    frame: Frame
    depth: NDArray[np.float32] | None


@dataclass
class FrameOutcome:
    """What tracking made of a frame, for ``PosePrior.update``."""

    frame: "FrameState"
    images: FrameImages
    tracked: bool
    started_map: bool  # the frame started a map (initialisation): no motion measured on it
    posed_by: "PosePrior | None"
    is_keyframe: bool
    velocity: NDArray[np.float64] | None
    #: Camera centre as tracked (before a merge moved the world), and the local map's
    #: inliers; None when not tracked.
    centre: NDArray[np.float64] | None
    n_inliers: int
    #: Tracking's trajectory, (timestamp, reference keyframe, T_c_ref) per tracked frame,
    #: and this frame's entry in it (None when not recorded): a prior may re-pose entries.
    trajectory: list[tuple[float, "KeyFrame", NDArray[np.float64]]]
    recorded_at: int | None


class TrackerOps(Protocol):
    """The tracking steps a prior's correction may run on the frame."""

    n_matches_inliers: int

    def track_local_map(self, cur: "FrameState") -> bool: ...

    def optimize(self, cur: "FrameState") -> int: ...

    def discard_outliers(self, cur: "FrameState") -> int: ...

    def keep_matches_consistent(self, cur: "FrameState") -> None: ...


class PosePrior(Protocol):
    """One source of pose predictions or corrections; see the module docstring."""

    #: For timings and stats.
    name: str

    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None: ...

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        """None: the prior did nothing to the frame."""
        ...

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        """For a frame this prior posed: make a keyframe? ``orb_slam_wants()``: ORB-SLAM's
        decision."""
        ...

    def update(self, outcome: FrameOutcome) -> None: ...

    def counters(self) -> dict[str, Any]:
        """What the prior did so far, for the run's stats (names unique across priors)."""
        ...

    def map_aligned(self, rotation: NDArray[np.float64], scale: float) -> None:
        """The map was moved by ``x' = scale * rotation @ x`` (under the map lock)."""
        ...


class PriorDefaults:
    """What a prior does where it has nothing to say (subclass and override the rest):
    no prediction, no correction, ORB-SLAM's keyframe decision, no counters, no positions kept."""

    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None:
        return None

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        return None

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        return orb_slam_wants()

    def update(self, outcome: FrameOutcome) -> None:
        return None

    def counters(self) -> dict[str, Any]:
        return {}

    def map_aligned(self, rotation: NDArray[np.float64], scale: float) -> None:
        return None
