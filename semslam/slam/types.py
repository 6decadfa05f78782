"""Small value types shared by the trackers and the System."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray


class TrackingState(str, Enum):
    NOT_INITIALIZED = "not_initialized"
    OK = "ok"
    LOST = "lost"


@dataclass
class TrackResult:
    """What ``System.track(frame)`` returns for one frame.

    ``pose_wc`` is None only before initialisation; while LOST it holds the motion-model
    prediction, as ORB-SLAM's trajectory output does for lost frames.
    """

    timestamp: float
    pose_wc: NDArray[np.float64] | None
    state: TrackingState
    n_matches: int = 0
    n_inliers: int = 0
    n_keypoints: int = 0
    is_keyframe: bool = False
    dynamic_ratio: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
