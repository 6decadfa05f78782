"""Decoding colour and depth images with checks that name the file and the problem.

What a camera or a converter may write is decoded where it can be, with a fixed rule (no
per-frame normalisation, which would change the brightness from frame to frame):
grey, grey + alpha, RGBA and palette PNGs become RGB; 16-bit colour is divided by 257
(the inverse of the usual 8 -> 16-bit widening); float colour is taken as 0..1. Depth
values that cannot be measurements (NaN, inf, negative, and 65535, the 16-bit sentinel
some sensors write for "no return") become 0, "no measurement".
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError

_PNG_END = b"IEND\xaeB`\x82"
#: A 16-bit depth image's largest value: written by sensors for "no return", never a depth
#: (65.5 m at millimetre scale, 13.1 m at TUM's 5000 per metre: beyond RGB-D ranges).
DEPTH_SENTINEL = 65535


class FrameReadError(DataError):
    """One image of a sequence cannot be used; a sequence may skip a few of these."""


def _read_bytes(path: Path) -> bytes:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FrameReadError(path, "file not found") from None
    except IsADirectoryError:
        raise FrameReadError(path, "is a folder, not an image") from None
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


def _decode(path: Path) -> NDArray[np.generic]:
    """The image as stored (any depth, any channel count); FrameReadError if it is none."""
    data = _read_bytes(path)
    _check_complete(path, data)
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # e.g. a header announcing an image too large to allocate
        raise FrameReadError(path, f"not a readable image ({str(exc).strip().splitlines()[-1]})") from None
    if img is None or img.size == 0:
        raise FrameReadError(path, "not a readable image")
    return img


def _to_uint8(path: Path, img: NDArray[np.generic]) -> NDArray[np.uint8]:
    if img.dtype == np.uint8:
        return img  # type: ignore[return-value]
    if img.dtype == np.uint16:
        return ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    if img.dtype in (np.float32, np.float64):
        unit = np.nan_to_num(img.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        return (np.clip(unit, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    raise FrameReadError(path, f"unsupported colour image type {img.dtype} (expected 8- or 16-bit, or float 0..1)")


def read_rgb(path: Path) -> NDArray[np.uint8]:
    """An 8-bit RGB image ``(H, W, 3)`` from grey, grey + alpha, BGR or BGRA, 8/16-bit or float."""
    img = _to_uint8(path, _decode(path))
    channels = 1 if img.ndim == 2 else img.shape[2]
    if channels == 1:
        return cv2.cvtColor(img.reshape(img.shape[:2]), cv2.COLOR_GRAY2RGB)
    if channels == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if channels == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    raise FrameReadError(path, f"colour image has {channels} channels (expected 1, 3 or 4)")


def read_depth(path: Path, scale: float) -> NDArray[np.float32]:
    """A depth map in metres (0 where the sensor gave nothing) from a 16-bit image, or from a
    float image already in metres.

    ``scale`` is the number of image units per metre (TUM: 5000, millimetre files: 1000).
    An 8-bit depth image is refused: it cannot hold Kinect-range depth at useful precision
    and usually means a colour or a visualisation image was given by mistake.
    """
    img = _decode(path)
    if img.ndim != 2:
        raise DataError(path, f"depth image has {img.shape[2]} channels; expected a single-channel 16-bit image")
    if img.dtype == np.uint8:
        raise DataError(path, "depth image is 8-bit; expected 16-bit depth (TUM: metres x 5000)")
    if img.dtype not in (np.float32, np.float64, np.uint16):
        raise DataError(path, f"unsupported depth image type {img.dtype}; expected uint16")
    return depth_to_metres(img, scale)


def depth_to_metres(img: NDArray[np.generic], scale: float) -> NDArray[np.float32]:
    """uint16 depth (``scale`` units per metre) or float metres as float32 metres, 0 for no
    measurement (the 16-bit sentinel, NaN, inf, negative): one rule for depth files and for
    depth handed in by user code (``semslam.System``)."""
    if img.dtype in (np.float32, np.float64):
        depth = np.nan_to_num(img.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        depth[depth < 0] = 0.0
        return depth
    depth = img.astype(np.float32) * np.float32(1.0 / scale)
    depth[img == DEPTH_SENTINEL] = 0.0
    return depth
