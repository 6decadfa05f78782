"""The turn between two frames from the shift of small images (``frontend/shift_rotation.py``),
on a real Kinect photo turned by a known rotation (the homography K R K^-1), sharp and with
motion blur and a gain change. A shift is not a homography (the edges of a turned image
stretch), so the bounds are what the tracker needs: a search seed inside the motion model's
15-px window (1.6 deg at f = 525)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from semslam.frontend.shift_rotation import ShiftRotation, small_image

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "kinect_rgbd_5frames"
K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


def _photo() -> np.ndarray:
    gray = cv2.imread(str(DATA / "color" / "1.png"), cv2.IMREAD_GRAYSCALE)
    assert gray is not None and gray.shape == (480, 640)
    return gray


def _turned(gray: np.ndarray, R_prev_cur: np.ndarray) -> np.ndarray:
    """What a camera turned by ``R_prev_cur`` (its axes in the first camera's) sees of the
    same scene: pixels move by K R^T K^-1."""
    H = K @ R_prev_cur.T @ np.linalg.inv(K)
    return cv2.warpPerspective(gray, H, (gray.shape[1], gray.shape[0]), borderMode=cv2.BORDER_REFLECT)


def _angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(A @ B.T).magnitude()))


def test_turn_from_the_shift_of_a_real_photo() -> None:
    gray = _photo()
    est = ShiftRotation(K[0, 0], K[1, 1])
    for yaw, pitch in ((4.0, 1.0), (-6.5, -1.5), (0.5, 0.0)):
        R = Rotation.from_rotvec(np.radians([pitch, yaw, 0.0])).as_matrix()
        shift = est.shift_px(small_image(gray), small_image(_turned(gray, R)))
        assert shift is not None
        dx, dy = shift
        assert np.sign(dx) == -np.sign(yaw)  # content moves left on a right turn
        assert _angle_deg(est.relative_rotation(dx, dy), R) < 0.4, (yaw, pitch, dx, dy)  # measured <= 0.28


def test_turn_survives_motion_blur_and_a_gain_change() -> None:
    gray = _photo()
    R = Rotation.from_rotvec(np.radians([1.2, 5.0, 0.0])).as_matrix()
    cur = _turned(gray, R).astype(np.float32)
    kernel = np.zeros((1, 31), np.float32)
    kernel[0, :] = 1.0 / 31.0  # a 31-px streak, a 200 deg/s turn over a 16 ms exposure
    cur = np.clip(cv2.filter2D(cur, -1, kernel) * 1.4, 0, 255).astype(np.uint8)  # +40 % gain
    est = ShiftRotation(K[0, 0], K[1, 1])
    shift = est.shift_px(small_image(gray), small_image(cur))
    assert shift is not None
    dx, dy = shift
    assert _angle_deg(est.relative_rotation(dx, dy), R) < 1.0, (dx, dy)  # measured 0.61


def test_a_blank_frame_has_no_shift() -> None:
    """A covered lens (black, white): the correlation has no peak, so no turn is read from it
    (OpenCV would answer half the image size, a 30 deg "turn")."""
    gray = _photo()
    est = ShiftRotation(K[0, 0], K[1, 1])
    for value in (0, 255):
        blank = np.full_like(gray, value)
        assert est.shift_px(small_image(gray), small_image(blank)) is None
        assert est.shift_px(small_image(blank), small_image(blank)) is None
