"""Frame-to-frame rotation from the images and depth (OpenCV ``cv2.rgbd`` odometry), for
frames whose features fail to match (motion blur on fast turns).

A motion-blurred frame's descriptors match little, and the pose from those few matches is
degrees off. Dense alignment of the whole image against the previous frame needs no
descriptors. Only the rotation is solved: with it alone free, OpenCV's odometries land within
about a tenth of a degree of the true rotation on blurred turns, while their 6-DoF modes (and
Open3D's) slide centimetres along walls. The translation is the guess's (the depth-odometry
prior carries the camera centre at the velocity of well-tracked frames). The rotation
converges from up to 4-6 deg off, and only while the held translation is within ~1 cm
(measurements: ``docs/results/tracking_history.md``)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config.schema import DEPTH_ODOMETRY_METHODS as METHODS
from semslam.geometry.se3 import rotation_angle

#: The most an alignment may turn the guess (degrees): it converges from up to 4-6 deg off,
#: and a larger change is a false minimum.
MAX_CORRECTION_DEG = 6.0
_CREATE = {
    "rgbd": lambda: cv2.rgbd.RgbdOdometry_create,
    "icp": lambda: cv2.rgbd.ICPOdometry_create,
    "rgbd_icp": lambda: cv2.rgbd.RgbdICPOdometry_create,
}


def rotation_angle_deg(T: NDArray[np.float64]) -> float:
    """The rotation angle of a transform (degrees)."""
    return float(np.degrees(rotation_angle(T[:3, :3])))


class RotationOdometry:
    """``T_prev_cur`` (a point in the current camera to the previous one) with the rotation
    aligned densely and the translation kept from the initial guess (the motion model)."""

    def __init__(self, K: NDArray[np.float64], method: str = "rgbd", max_depth_m: float = 4.0) -> None:
        if method not in _CREATE:
            raise ValueError(f"depth odometry method {method!r}: expected one of {', '.join(METHODS)}")
        self.method = method
        self._odo: Any = _CREATE[method]()(cameraMatrix=np.asarray(K, np.float32), maxDepth=max_depth_m,
                                            transformType=cv2.rgbd.Odometry_ROTATION)

    def relative(self, gray_prev: NDArray[np.uint8], depth_prev: NDArray[np.float32],
                 gray_cur: NDArray[np.uint8], depth_cur: NDArray[np.float32],
                 init_prev_cur: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """``T_prev_cur`` from ``init_prev_cur``, or None where the alignment fails or turns
        the guess by more than ``MAX_CORRECTION_DEG``."""
        d_prev = np.ascontiguousarray(depth_prev, np.float32)
        d_cur = np.ascontiguousarray(depth_cur, np.float32)
        ok, Rt = self._odo.compute(gray_cur, d_cur, None, gray_prev, d_prev, None,
                                   initRt=np.asarray(init_prev_cur, np.float64))
        if not ok or Rt is None or not np.all(np.isfinite(Rt)):
            return None
        T = np.asarray(Rt, np.float64).copy()
        if rotation_angle_deg(np.linalg.inv(init_prev_cur) @ T) > MAX_CORRECTION_DEG:
            return None
        T[:3, 3] = init_prev_cur[:3, 3]  # only the rotation was free; keep the guess's translation exactly
        return T
