"""The camera's turn between two frames from the shift of small, blurred images.

PTAM (Klein & Murray, "Improving the agility of keyframe-based SLAM", ECCV 2008) predicts a
fast turn from the whole image, shrunk and blurred, before any feature is matched: blur that
destroys corners leaves the image's bulk shift intact. Here the shift is OpenCV's phase
correlation (``cv2.phaseCorrelate``: normalised, so gain changes do not move it) on 1/4-size
images, read as a rotation about the camera's x and y axes (a 1 cm step at 3 m moves the image
by under 2 px; a 200 deg/s turn by 60). On the project's hard-imaging render it gives each
glance frame's turn within 1-8 px where the constant-velocity model is off by up to 25 px.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

#: Images are shrunk by this factor before correlating (cost ~1 ms per 640x480 frame).
SHRINK = 4


def small_image(gray: NDArray[np.uint8], shrink: int = SHRINK) -> NDArray[np.float32]:
    """The frame shrunk by ``shrink`` (area average) and normalised to zero mean, unit spread."""
    h, w = gray.shape[:2]
    small = cv2.resize(gray, (max(1, w // shrink), max(1, h // shrink)), interpolation=cv2.INTER_AREA)
    small = small.astype(np.float32)
    return (small - small.mean()) / (float(small.std()) + 1e-6)


#: Phase correlation's peak (its share of the correlation energy) below which there is no shift
#: to read: 0 on a blank frame.
MIN_RESPONSE = 1e-3


class ShiftRotation:
    """Turn between consecutive frames from the shift of their small images."""

    def __init__(self, fx: float, fy: float, shrink: int = SHRINK) -> None:
        self.fx, self.fy, self.shrink = fx, fy, shrink
        self._window: NDArray[np.float32] | None = None

    def shift_px(self, prev_small: NDArray[np.float32], cur_small: NDArray[np.float32]) -> tuple[float, float] | None:
        """How far the image content moved from ``prev_small`` to ``cur_small``, full-size
        pixels; None when the correlation has no peak (a blank or covered frame: OpenCV then
        answers half the image size with response 0)."""
        if self._window is None or self._window.shape != cur_small.shape:
            self._window = cv2.createHanningWindow(cur_small.shape[::-1], cv2.CV_32F)
        (dx, dy), response = cv2.phaseCorrelate(prev_small, cur_small, self._window)
        if not (np.isfinite(response) and response > MIN_RESPONSE and np.isfinite(dx) and np.isfinite(dy)):
            return None
        return dx * self.shrink, dy * self.shrink

    def relative_rotation(self, dx: float, dy: float, roll_rad: float = 0.0) -> NDArray[np.float64]:
        """``R_prev_cur`` (current camera axes into the previous one's) that moves the image
        by ``(dx, dy)`` pixels: content moves left when the camera turns right (about +y)
        and down when it tilts down (about +x)."""
        rv = np.array([np.arctan2(dy, self.fy), -np.arctan2(dx, self.fx), roll_rad])
        return Rotation.from_rotvec(rv).as_matrix()
