"""Depth sources: where a frame's metric depth comes from (``core.protocols.DepthSource``).

RGB-D sequences carry the sensor's depth; the monocular SDF-SLAM preset will get it from
its depth network through the same call.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.config import DepthConfig
from semslam.core.types import Frame


class SensorDepth:
    """The depth image read with the frame (metres, 0 = no measurement)."""

    def depth(self, frame: Frame) -> NDArray[np.float32] | None:
        return frame.depth


def create_sensor(cfg: DepthConfig) -> SensorDepth:
    """Registry factory of depth source ``sensor``."""
    return SensorDepth()
