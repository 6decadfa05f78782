"""Decoding colour and depth images with checks that name the file and the problem."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError

_PNG_END = b"IEND\xaeB`\x82"


class FrameReadError(DataError):
    """One image of a sequence cannot be used; a sequence may skip a few of these."""


def _read_bytes(path: Path) -> bytes:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FrameReadError(path, "file not found") from None
    except OSError as exc:
        raise FrameReadError(path, f"cannot read ({exc.strerror})") from None
    if not data:
        raise FrameReadError(path, "empty file")
    return data


def _check_complete(path: Path, data: bytes) -> None:
    """Catch truncated files that OpenCV would decode partially without complaint."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        if _PNG_END not in data[-64:]:
            raise FrameReadError(path, "truncated PNG (no IEND chunk at the end)")
    elif data[:2] == b"\xff\xd8":
        if b"\xff\xd9" not in data[-32:]:
            raise FrameReadError(path, "truncated JPEG (no end-of-image marker)")


def read_rgb(path: Path) -> NDArray[np.uint8]:
    """An 8-bit RGB image ``(H, W, 3)``; grey images are expanded to three channels."""
    data = _read_bytes(path)
    _check_complete(path, data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FrameReadError(path, "not a readable image")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_depth(path: Path, scale: float) -> NDArray[np.float32]:
    """A depth map in metres (0 where the sensor gave nothing) from a 16-bit image.

    ``scale`` is the number of image units per metre (TUM: 5000, millimetre files: 1000).
    An 8-bit depth image is refused: it cannot hold Kinect-range depth at useful precision
    and usually means a colour or a visualisation image was given by mistake.
    """
    data = _read_bytes(path)
    _check_complete(path, data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FrameReadError(path, "not a readable image")
    if img.ndim != 2:
        raise DataError(path, f"depth image has {img.shape[2]} channels; expected a single-channel 16-bit image")
    if img.dtype == np.uint8:
        raise DataError(path, "depth image is 8-bit; expected 16-bit depth (TUM: metres x 5000)")
    if img.dtype == np.float32:
        return np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0)
    if img.dtype != np.uint16:
        raise DataError(path, f"unsupported depth image type {img.dtype}; expected uint16")
    return img.astype(np.float32) * np.float32(1.0 / scale)
