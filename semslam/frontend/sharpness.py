"""Image sharpness: how much motion blur a frame has, compared with the frames before it."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray


def sharpness(gray: NDArray[np.uint8]) -> float:
    """Mean absolute Laplacian over mean intensity, on a 320-px-wide copy: motion blur lowers it
    (on the blurred glance of ``walking_turns`` from 0.16-0.17 to 0.05-0.09), a gain change
    does not. What the camera looks at changes it too (0.17 -> 0.11 over the same glance
    without blur), so it is compared with the frames just before (``slam/orb/motion_priors/sharpness_history.py``)."""
    h, w = gray.shape[:2]
    scale = 320.0 / w
    small = cv2.resize(gray, (320, max(1, round(h * scale))), interpolation=cv2.INTER_AREA) if w > 320 else gray
    small = small.astype(np.float32)
    mean = float(small.mean())
    if mean <= 1e-6:
        return 0.0
    return float(np.abs(cv2.Laplacian(small, cv2.CV_32F)).mean()) / mean
