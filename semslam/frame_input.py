"""What ``semslam.System.track`` checks and converts in the frames user code gives it:
increasing timestamps, colour images as RGB uint8, depth in metres. Each failure is a
``DataError`` naming the frame (``where``) and what was expected.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ImuSamples
from semslam.errors import DataError
from semslam.io.images import depth_to_metres


def check_timestamp(timestamp: float, last: float, where: str) -> float:
    try:
        t = float(timestamp)
    except (TypeError, ValueError):
        raise DataError(where, f"timestamp {timestamp!r} is not a number") from None
    if not np.isfinite(t):
        raise DataError(where, "timestamp is not finite")
    if t <= last:
        raise DataError(where, f"timestamp {t:.6f} is not after the previous frame's ({last:.6f}); "
                               "timestamps must increase")
    return t


def as_rgb(image: Any, bgr: bool, where: str) -> NDArray[np.uint8]:
    """A fresh HxWx3 RGB copy (a keyframe keeps its image: the caller's buffer may be reused)."""
    if not isinstance(image, np.ndarray):
        raise DataError(where, f"rgb is a {type(image).__name__}, expected a numpy array (HxWx3 uint8)")
    if image.dtype != np.uint8:
        raise DataError(where, f"rgb is {image.dtype}, expected uint8 (HxWx3, 0-255)")
    if image.ndim == 2:
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_GRAY2RGB)
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 1:
        raise DataError(where, f"rgb has shape {image.shape}, expected HxWx3 (or HxW grey)")
    if bgr:
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2RGB)
    return np.array(image, copy=True, order="C")


def as_metres(depth: Any, scale: float, shape: tuple[int, ...], where: str) -> NDArray[np.float32]:
    """Depth in metres as float32 (0 = no measurement), converted as ``io.images.read_depth``
    converts a depth PNG, so the same image gives the same numbers."""
    if not isinstance(depth, np.ndarray):
        raise DataError(where, f"depth is a {type(depth).__name__}, expected a numpy array (HxW)")
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[:, :, 0]
    if depth.ndim != 2:
        raise DataError(where, f"depth has shape {depth.shape}, expected HxW")
    if depth.shape != tuple(shape):
        raise DataError(where, f"depth is {depth.shape[1]}x{depth.shape[0]} but rgb is {shape[1]}x{shape[0]}")
    if depth.dtype == np.uint16:
        return depth_to_metres(depth, scale)
    if depth.dtype in (np.float32, np.float64):
        if (depth < 0).any():
            raise DataError(where, "depth has negative values (expected metres, 0 = no measurement)")
        return depth_to_metres(depth, scale)
    raise DataError(where, f"depth is {depth.dtype}; expected uint16 ({scale:g} units per metre, depth_scale) "
                           "or float metres")


def as_imu_samples(readings: Any, last_t: float, frame_t: float, where: str) -> ImuSamples:
    """``[(t, gyro xyz, acc xyz), ...]`` (or an (N, 7) array) as ``ImuSamples``: finite,
    times increasing, after the readings given before and not after the frame's time."""
    try:
        rows = np.asarray([[float(t), *np.asarray(g, dtype=np.float64).ravel(), *np.asarray(a, dtype=np.float64).ravel()]
                           for t, g, a in readings], dtype=np.float64) if not isinstance(readings, np.ndarray) \
            else np.asarray(readings, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(where, "imu: expected (t, gyro xyz, acc xyz) readings") from None
    if rows.size == 0:
        return ImuSamples.empty()
    if rows.ndim != 2 or rows.shape[1] != 7:
        raise DataError(where, f"imu: expected (t, gyro xyz, acc xyz) readings (7 numbers each), got shape {rows.shape}")
    if not np.isfinite(rows).all():
        raise DataError(where, "imu: a reading is not finite (NaN or inf)")
    t = rows[:, 0]
    if t[0] <= last_t or (np.diff(t) <= 0).any():
        bad = 0 if t[0] <= last_t else int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        before = last_t if bad == 0 else t[bad - 1]
        raise DataError(where, f"imu: reading {bad} at t={t[bad]:.6f} is not after the one before it "
                               f"(t={before:.6f}); IMU times must increase")
    if t[-1] > frame_t + 1e-6:
        raise DataError(where, f"imu: reading at t={t[-1]:.6f} is after the frame (t={frame_t:.6f}); give each "
                               "frame the readings up to its time")
    return ImuSamples(t.copy(), rows[:, 1:4].copy(), rows[:, 4:7].copy())
