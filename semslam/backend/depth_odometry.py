"""Frame-to-frame rotation from the images and depth (OpenCV ``cv2.rgbd`` odometry), for
frames whose features fail to match (motion blur on fast turns).

A motion-blurred frame's descriptors match little, and the pose from those few matches is
degrees off. Dense alignment of the whole image against the previous frame needs no
descriptors. On the blurred turns of ``walking_turns`` (640x480, 16 ms exposure, up to ~7 deg
a frame), with only the rotation free and the true translation held, OpenCV's photometric
``RgbdOdometry`` was 0.007-0.11 deg from the true rotation (``RgbdICPOdometry`` 0.003-0.055,
``ICPOdometry`` 0.03-0.18), starting from the motion model's 1-2.5 deg. Their 6-DoF modes, and
Open3D's ``rgbd_odometry_multi_scale`` (PointToPlane, Hybrid, Intensity), slid 2-5 cm along
the walls on the same frames. So only the rotation is solved; the translation is the guess's
(``Tracking`` carries the camera centre at the velocity of well-tracked frames). The rotation
converges from up to 4-6 deg off, and only while the held translation is within ~1 cm."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config.schema import DEPTH_ODOMETRY_METHODS as METHODS
from semslam.geometry.se3 import rotation_angle

#: The most an alignment may turn the guess (degrees): it converges from up to 4-6 deg off,
#: and a larger change is a false minimum (a threaded walking_hard run without this bound
#: flipped to poses 170 deg off).
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
