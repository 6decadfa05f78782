"""ORB's orientation and descriptor: ORB-SLAM's ``IC_Angle`` (intensity centroid of a
circular 31 px patch) and ``computeOrbDescriptor`` (steered rBRIEF, OpenCV's learned
test pattern), over all keypoints of all levels of a stacked pyramid at once.

``ic_angles`` / ``orb_descriptors`` run the compiled kernels of ``orb.brief_kernels``;
``ic_angles_numpy`` / ``orb_descriptors_numpy`` are the vectorised numpy versions they
replaced, kept as references (identical results, tests).

Shared by ORB-SLAM2's extractor and STDC-SLAM's Qtree-ORB, which differ only in
detection and distribution.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.blur import blur_levels
from semslam.features.orb.brief_kernels import ic_moments, steered_brief
from semslam.features.orb.pyramid import HALF_PATCH_SIZE, StackedPyramid
from semslam.features.orb.scratch import Scratch, kernel_array
from semslam.features.orb.timing import StageClock

__all__ = ["BIT_PATTERN_31", "PATCH", "Scratch", "SteeredBrief", "ic_angles", "ic_angles_numpy",
           "orb_descriptors", "orb_descriptors_numpy",
           "umax"]

# ORB's learned 256 test pairs for a 31x31 patch (OpenCV orb.cpp ``bit_pattern_31_``,
# BSD licence, copied by ORB-SLAM), as x1,y1, x2,y2 per test.
BIT_PATTERN_31 = np.array([
    8,-3,9,5, 4,2,7,-12, -11,9,-8,2, 7,-12,12,-13,
    2,-13,2,12, 1,-7,1,6, -2,-10,-2,-4, -13,-13,-11,-8,
    -13,-3,-12,-9, 10,4,11,9, -13,-8,-8,-9, -11,7,-9,12,
    7,7,12,6, -4,-5,-3,0, -13,2,-12,-3, -9,0,-7,5,
    12,-6,12,-1, -3,6,-2,12, -6,-13,-4,-8, 11,-13,12,-8,
    4,7,5,1, 5,-3,10,-3, 3,-7,6,12, -8,-7,-6,-2,
    -2,11,-1,-10, -13,12,-8,10, -7,3,-5,-3, -4,2,-3,7,
    -10,-12,-6,11, 5,-12,6,-7, 5,-6,7,-1, 1,0,4,-5,
    9,11,11,-13, 4,7,4,12, 2,-1,4,4, -4,-12,-2,7,
    -8,-5,-7,-10, 4,11,9,12, 0,-8,1,-13, -13,-2,-8,2,
    -3,-2,-2,3, -6,9,-4,-9, 8,12,10,7, 0,9,1,3,
    7,-5,11,-10, -13,-6,-11,0, 10,7,12,1, -6,-3,-6,12,
    10,-9,12,-4, -13,8,-8,-12, -13,0,-8,-4, 3,3,7,8,
    5,7,10,-7, -1,7,1,-12, 3,-10,5,6, 2,-4,3,-10,
    -13,0,-13,5, -13,-7,-12,12, -13,3,-11,8, -7,12,-4,7,
    6,-10,12,8, -9,-1,-7,-6, -2,-5,0,12, -12,5,-7,5,
    3,-10,8,-13, -7,-7,-4,5, -3,-2,-1,-7, 2,9,5,-11,
    -11,-13,-5,-13, -1,6,0,-1, 5,-3,5,2, -4,-13,-4,12,
    -9,-6,-9,6, -12,-10,-8,-4, 10,2,12,-3, 7,12,12,12,
    -7,-13,-6,5, -4,9,-3,4, 7,-1,12,2, -7,6,-5,1,
    -13,11,-12,5, -3,7,-2,-6, 7,-8,12,-7, -13,-7,-11,-12,
    1,-3,12,12, 2,-6,3,0, -4,3,-2,-13, -1,-13,1,9,
    7,1,8,-6, 1,-1,3,12, 9,1,12,6, -1,-9,-1,3,
    -13,-13,-10,5, 7,7,10,12, 12,-5,12,9, 6,3,7,11,
    5,-13,6,10, 2,-12,2,3, 3,8,4,-6, 2,6,12,-13,
    9,-12,10,3, -8,4,-7,9, -11,12,-4,-6, 1,12,2,-8,
    6,-9,7,-4, 2,3,3,-2, 6,3,11,0, 3,-3,8,-8,
    7,8,9,3, -11,-5,-6,-4, -10,11,-5,10, -5,-8,-3,12,
    -10,5,-9,0, 8,-1,12,-6, 4,-6,6,-11, -10,12,-8,7,
    4,-2,6,7, -2,0,-2,12, -5,-8,-5,2, 7,-6,10,12,
    -9,-13,-8,-8, -5,-13,-5,-2, 8,-8,9,-13, -9,-11,-9,0,
    1,-8,1,-2, 7,-4,9,1, -2,1,-1,-4, 11,-6,12,-11,
    -12,-9,-6,4, 3,7,7,12, 5,5,10,8, 0,-4,2,8,
    -9,12,-5,-13, 0,7,2,12, -1,2,1,7, 5,11,7,-9,
    3,5,6,-8, -13,-4,-8,9, -5,9,-3,-3, -4,-7,-3,-12,
    6,5,8,0, -7,6,-6,12, -13,6,-5,-2, 1,-10,3,10,
    4,1,8,-4, -2,-2,2,-13, 2,-12,12,12, -2,-13,0,-6,
    4,1,9,3, -6,-10,-3,-5, -3,-13,-1,1, 7,5,12,-11,
    4,-2,5,-7, -13,9,-9,-5, 7,1,8,6, 7,-8,7,6,
    -7,-4,-7,1, -8,11,-7,-8, -13,6,-12,-8, 2,4,3,9,
    10,-5,12,3, -6,-5,-6,7, 8,-3,9,-8, 2,-12,2,8,
    -11,-2,-10,3, -12,-13,-7,-9, -11,0,-10,-5, 5,-3,11,8,
    -2,-13,-1,12, -1,-8,0,9, -13,-11,-12,-5, -10,-2,-10,11,
    -3,9,-2,-13, 2,-3,3,2, -9,-13,-4,0, -4,6,-3,-10,
    -4,12,-2,-7, -6,-11,-4,9, 6,-3,6,11, -13,11,-5,5,
    11,11,12,6, 7,-5,12,-2, -1,12,0,7, -4,-8,-3,-2,
    -7,1,-6,7, -13,-12,-8,-13, -7,-2,-6,-8, -8,5,-6,-9,
    -5,-1,-4,5, -13,7,-8,10, 1,5,5,-13, 1,0,10,-13,
    9,12,10,-1, 5,-8,10,-9, -1,11,1,-13, -9,-3,-6,2,
    -1,-10,1,12, -13,1,-8,-10, 8,-11,10,-6, 2,-13,3,-6,
    7,-13,12,-9, -10,-10,-5,-7, -10,-8,-8,-13, 4,-6,8,5,
    3,12,8,-13, -4,2,-3,-3, 5,-13,10,-12, 4,-13,5,-1,
    -9,9,-4,3, 0,3,3,-9, -12,1,-6,1, 3,2,4,-8,
    -10,-10,-10,9, 8,-13,12,12, -8,-12,-6,-5, 2,2,3,7,
    10,6,11,-8, 6,8,8,-12, -7,10,-6,5, -3,-9,-3,9,
    -1,-13,-1,5, -3,-7,-3,4, -8,-2,-8,3, 4,2,12,12,
    2,-5,3,11, 6,-9,11,-13, 3,-1,7,12, 11,-1,12,4,
    -3,0,-3,6, 4,-11,4,12, 2,-4,2,1, -10,-6,-8,1,
    -13,7,-11,1, -13,12,-11,-13, 6,0,11,-13, 0,-1,1,4,
    -13,3,-9,-2, -9,8,-6,-3, -13,-6,-8,-2, 5,-9,8,10,
    2,7,3,-9, -1,-6,-1,-1, 9,5,11,-2, 11,-3,12,-8,
    3,0,3,5, -1,4,0,10, 3,-6,4,5, -13,0,-10,5,
    5,8,12,11, 8,9,9,-6, 7,-4,8,-12, -10,4,-10,9,
    7,3,12,4, 9,-7,10,-2, 7,0,12,-2, -1,-6,0,-11,
], dtype=np.int32).reshape(512, 2)


def umax() -> NDArray[np.int64]:
    """Half-width of every row of ORB-SLAM's circular orientation patch (v = 0..15),
    made symmetric under transposition exactly as in the ORBextractor constructor."""
    umax = np.zeros(HALF_PATCH_SIZE + 2, np.int64)
    vmax = int(math.floor(HALF_PATCH_SIZE * math.sqrt(2.0) / 2 + 1))
    vmin = int(math.ceil(HALF_PATCH_SIZE * math.sqrt(2.0) / 2))
    hp2 = HALF_PATCH_SIZE * HALF_PATCH_SIZE
    for v in range(vmax + 1):
        umax[v] = int(np.rint(math.sqrt(hp2 - v * v)))
    v0 = 0
    for v in range(HALF_PATCH_SIZE, vmin - 1, -1):
        while umax[v0] == umax[v0 + 1]:
            v0 += 1
        umax[v] = v0
        v0 += 1
    return umax[: HALF_PATCH_SIZE + 1]


def _moment_weights() -> NDArray[np.float32]:
    """(31*31, 2) weights over the square patch: (dx, dy) inside ORB-SLAM's circle
    (rows -15..15, |dx| <= umax[|dy|]), 0 outside, so [m10, m01] = patch @ weights."""
    umax_ = umax()
    w = np.zeros((PATCH, PATCH, 2), np.float32)
    for v in range(-HALF_PATCH_SIZE, HALF_PATCH_SIZE + 1):
        d = int(umax_[abs(v)])
        u = np.arange(-d, d + 1)
        w[v + HALF_PATCH_SIZE, u + HALF_PATCH_SIZE, 0] = u
        w[v + HALF_PATCH_SIZE, u + HALF_PATCH_SIZE, 1] = v
    return w.reshape(PATCH * PATCH, 2)


PATCH = 2 * HALF_PATCH_SIZE + 1
_MOMENT_WEIGHTS = _moment_weights()
# The same weights as int32 (31, 32) images of u and v (a last column of zeros: 32-wide
# rows vectorise), for the compiled moments.
_WEIGHTS_U = np.zeros((PATCH, PATCH + 1), np.int32)
_WEIGHTS_V = np.zeros((PATCH, PATCH + 1), np.int32)
_WEIGHTS_U[:, :PATCH] = _MOMENT_WEIGHTS[:, 0].reshape(PATCH, PATCH)
_WEIGHTS_V[:, :PATCH] = _MOMENT_WEIGHTS[:, 1].reshape(PATCH, PATCH)
_PATTERN_X = np.ascontiguousarray(BIT_PATTERN_31[:, 0].astype(np.float32))
_PATTERN_Y = np.ascontiguousarray(BIT_PATTERN_31[:, 1].astype(np.float32))
_PATTERN_REACH = 18  # round(13 sqrt(2)): farthest a rotated test pixel can be
# Rotated pattern x' = x a - y b, y' = x b + y a as one (N,2) @ (2,512) product each.
_PAT_X_ROT = np.stack([BIT_PATTERN_31[:, 0], -BIT_PATTERN_31[:, 1]]).astype(np.float32)
_PAT_Y_ROT = np.stack([BIT_PATTERN_31[:, 1], BIT_PATTERN_31[:, 0]]).astype(np.float32)
_ROUND_MAGIC = np.float32(1.5 * 2**23)  # x + M in float32 rounds half-to-even (|x| < 2^22)
_ROUND_BITS = np.int32(0x4B400000)


def _rint_i32(v: NDArray[np.float32]) -> NDArray[np.int32]:
    """Round-half-to-even to int32 (``cvRound``), in place, with one add and one
    reinterpretation: about 3x faster than ``np.rint(v).astype(np.int32)``."""
    v += _ROUND_MAGIC
    out = v.view(np.int32)
    out -= _ROUND_BITS
    return out


_IC_CHUNK = 128  # keypoints per window copy (keeps the temporaries small and in cache)


def _flat(image: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], int]:
    """A C-contiguous, writeable image as a flat array and its row stride (one compiled
    signature for the kernels)."""
    if not (image.flags.c_contiguous and image.flags.writeable and image.dtype == np.uint8):
        image = np.array(image, np.uint8, order="C")
    return image.reshape(-1), image.shape[1]


def _coords(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer], left: int, right: int
            ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """x, y as int64, checked to be ``left`` px from the left / top border and ``right``
    px from the right / bottom one (the compiled kernels do not check their reads)."""
    x, y = kernel_array(x, np.int64), kernel_array(y, np.int64)
    h, w = image.shape
    if x.min() < left or y.min() < left or x.max() >= w - right or y.max() >= h - right:
        raise ValueError(f"keypoints must be >= {left} px from the image's left / top and > {right} px "
                         "from its right / bottom border")
    return x, y


def ic_angles(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
              scratch: Scratch | None = None) -> NDArray[np.float32]:
    """ORB-SLAM's ``IC_Angle`` for keypoints at integer pixels (at least 15 px from the
    border): the direction in degrees [0, 360) of the intensity centroid of the circular
    patch, ``fastAtan2(m01, m10)`` (``cv2.phase``, which is OpenCV's ``fastAtan2``).
    Why: it makes BRIEF rotation-invariant. The moments come from the compiled
    ``ic_moments``; ``scratch`` is unused (kept for the signature of the numpy version)."""
    n = len(x)
    if n == 0:
        return np.zeros(0, np.float32)
    if np.max(x) == image.shape[1] - 1 - HALF_PATCH_SIZE:
        image = np.pad(image, ((0, 0), (0, 1)))  # the kernel's 32-wide rows read one more column
    xi, yi = _coords(image, x, y, HALF_PATCH_SIZE, HALF_PATCH_SIZE)
    flat, stride = _flat(image)
    m10, m01 = np.empty(n, np.float32), np.empty(n, np.float32)
    ic_moments(flat, stride, xi, yi, _WEIGHTS_U, _WEIGHTS_V, m10, m01)
    return cv2.phase(m10, m01, angleInDegrees=True).reshape(-1)


def ic_angles_numpy(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                    scratch: Scratch | None = None) -> NDArray[np.float32]:
    """``ic_angles`` in numpy (the reference the compiled version is tested against).

    Vectorised: the 31x31 windows are copied in chunks and reduced with one float32
    matmul each (the moments are integers < 2^24, so exact)."""
    n = len(x)
    if n == 0:
        return np.zeros(0, np.float32)
    scratch = scratch or Scratch()
    windows = np.lib.stride_tricks.sliding_window_view(image, (PATCH, PATCH))
    wy = np.asarray(y, np.intp) - HALF_PATCH_SIZE
    wx = np.asarray(x, np.intp) - HALF_PATCH_SIZE
    fbuf = scratch.get("ic_f", (_IC_CHUNK, PATCH * PATCH), np.float32)
    m = scratch.get("ic_m", (n, 2), np.float32)
    for i in range(0, n, _IC_CHUNK):
        j = min(i + _IC_CHUNK, n)
        f = fbuf[: j - i]
        np.copyto(f, windows[wy[i:j], wx[i:j]].reshape(j - i, PATCH * PATCH))
        np.matmul(f, _MOMENT_WEIGHTS, out=m[i:j])
    return cv2.phase(np.ascontiguousarray(m[:, 0]), np.ascontiguousarray(m[:, 1]),
                     angleInDegrees=True).reshape(-1)


def _cos_sin(angle_deg: NDArray[np.floating]) -> NDArray[np.float32]:
    """(n, 2) float32 cos and sin of the angles (numpy's float32 functions, so both
    descriptor versions steer with the very same numbers)."""
    rad = np.asarray(angle_deg, np.float32) * np.float32(math.pi / 180.0)
    ab = np.empty((len(rad), 2), np.float32)
    np.cos(rad, out=ab[:, 0])  # a
    np.sin(rad, out=ab[:, 1])  # b
    return ab


def orb_descriptors(blurred: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                    angle_deg: NDArray[np.floating], scratch: Scratch | None = None) -> NDArray[np.uint8]:
    """ORB-SLAM's ``computeOrbDescriptor``: 256 intensity tests of the pattern rotated by
    the keypoint angle on the blurred image, packed 8 per byte, least significant bit
    first. Keypoints must be at least 19 px (EDGE_THRESHOLD) from the border. Runs the
    compiled ``steered_brief`` (same bytes as ``orb_descriptors_numpy``); ``scratch`` is
    unused."""
    n = len(x)
    if n == 0:
        return np.zeros((0, 32), np.uint8)
    xi, yi = _coords(blurred, x, y, _PATTERN_REACH, _PATTERN_REACH)
    flat, stride = _flat(blurred)
    ab = _cos_sin(angle_deg)
    out = np.empty((n, 32), np.uint8)
    steered_brief(flat, stride, xi, yi, np.ascontiguousarray(ab[:, 0]),
                  np.ascontiguousarray(ab[:, 1]), _PATTERN_X, _PATTERN_Y, out)
    return out


def orb_descriptors_numpy(blurred: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                          angle_deg: NDArray[np.floating], scratch: Scratch | None = None) -> NDArray[np.uint8]:
    """``orb_descriptors`` in numpy (the reference the compiled version is tested against).

    Vectorised: rotated offsets as two (N,2) @ (2,512) products, rounded half-to-even
    like ``cvRound``, one flat gather; all temporaries in reused buffers."""
    n = len(x)
    if n == 0:
        return np.zeros((0, 32), np.uint8)
    scratch = scratch or Scratch()
    img = np.ascontiguousarray(blurred)
    stride = img.shape[1]
    ab = _cos_sin(angle_deg)
    col = _rint_i32(np.matmul(ab, _PAT_X_ROT, out=scratch.get("d_col", (n, 512), np.float32)))
    row = _rint_i32(np.matmul(ab, _PAT_Y_ROT, out=scratch.get("d_row", (n, 512), np.float32)))
    row *= np.int32(stride)
    row += col
    flat = scratch.get("d_flat", (n, 512), np.intp)
    np.add(row, (np.asarray(y, np.intp) * stride + np.asarray(x, np.intp))[:, None], out=flat)
    vals = np.take(img.reshape(-1), flat, out=scratch.get("d_vals", (n, 512), np.uint8))
    bits = np.less(vals[:, 0::2], vals[:, 1::2], out=scratch.get("d_bits", (n, 256), np.bool_))
    return np.packbits(bits, axis=1, bitorder="little")


class SteeredBrief:
    """IC angle, the 7x7 sigma-2 blur and steered rBRIEF of keypoints on a stacked pyramid,
    with the work buffers kept from frame to frame (one per extractor; not thread-safe)."""

    def __init__(self) -> None:
        self.scratch = Scratch()
        self._blur_buffer: NDArray[np.uint8] | None = None
        self._blur_ring: NDArray[np.int32] | None = None

    def compute(self, pyr: StackedPyramid, sx: NDArray[np.integer], sy: NDArray[np.integer],
                clock: StageClock | None = None) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
        """(angles in degrees, 32-byte descriptors) of keypoints at buffer pixels (sx, sy);
        laps ``clock`` after the orientation and after the blur."""
        # All levels live in one buffer: one gather for the orientations, one compiled
        # blur of the levels' pixels (BORDER_REFLECT_101 like ORB-SLAM's per-level blur)
        # and one gather for the descriptors, whose tests stay inside the keypoint's level.
        _check_inside_levels(pyr, sx, sy, _PATTERN_REACH)
        angle = ic_angles(pyr.buffer, sx, sy, self.scratch)
        if clock is not None:
            clock.lap()
        if self._blur_buffer is None or self._blur_buffer.shape != pyr.buffer.shape:
            self._blur_buffer = np.zeros_like(pyr.buffer)
        self._blur_ring = blur_levels(pyr, self._blur_buffer, self._blur_ring)
        if clock is not None:
            clock.lap()
        return angle, orb_descriptors(self._blur_buffer, sx, sy, angle, self.scratch)


def _check_inside_levels(pyr: StackedPyramid, sx: NDArray[np.integer], sy: NDArray[np.integer],
                         reach: int) -> None:
    """Raise unless every buffer pixel (sx, sy) is >= ``reach`` px inside its own level.
    Why: only the levels' pixels are blurred, so a test pixel in the padding would read
    an unblurred value. ORB-SLAM's keypoints are EDGE_THRESHOLD (19) px inside."""
    if len(sx) == 0:
        return
    sx, sy = np.asarray(sx), np.asarray(sy)
    level = np.searchsorted(pyr.rows, sy, side="right") - 1
    x, y = sx - pyr.pad, sy - pyr.rows[np.maximum(level, 0)]
    if (level.min() < 0 or x.min() < reach or y.min() < reach or (x >= pyr.widths[level] - reach).any()
            or (y >= pyr.heights[level] - reach).any()):
        raise ValueError(f"keypoints must be >= {reach} px inside their pyramid level")
