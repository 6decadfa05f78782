"""Output layers of the shipped networks in NumPy and OpenCV, without torch.

The networks' graphs (run by ONNX Runtime, or by torch for a user's ``.pt``) end at their
coarse outputs; what turns those into label maps, keypoints and descriptors lives here, so
that inference needs no torch (``pip install semslam`` does not bring it) and the ONNX and
torch paths share one implementation:

* segmenters (STDC, DUNet): class probabilities upsampled to the frame (``upsample``),
* SDFCNN: the exact argmax of bilinearly upsampled logits (``upsampled_argmax``),
* FPFDCNN: keypoints by non-maximum suppression (``nms_points``, ``select_points``) and
  their descriptors sampled from the coarse map (``descriptors_at``).

Bilinear sampling follows ``F.interpolate(..., align_corners=False)`` / ``F.grid_sample``
(half-pixel centres, clamped at the borders); the tests compare each with torch.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["CELL", "NMS_RADIUS", "descriptors_at", "nms_points", "select_points", "upsample", "upsampled_argmax"]

#: FPFDCNN's coarse cell: one descriptor (and 256 pixel-shuffled probabilities) per 16 x 16
#: pixels (640 / 40 = 480 / 30), so its input sides are multiples of 16.
CELL = 16

#: FPFDCNN's keypoints are local maxima of its probability map in a (2r+1)^2 window. The
#: paper does not say which window; measured with the shipped weights (2026-11-27, benchmark
#: renders, 500 points): r = 2 against SuperPoint's usual 4 raises the range matcher's correct
#: matches from 60.0 / 55.7 % to 72.0 / 71.2 % (clear / blurred pairs 3 frames apart), lowers
#: Table 7's errT 0.053 -> 0.047, and `sdf`'s ATE on static_xyz 5.15 -> 3.76 cm (held-out
#: lounge 9.45 -> 7.78 cm): the detector's strongest responses repeat better than the
#: spread-out weaker maxima a wider window leaves. r = 1 scores more on Table 6 (78.5 %) but
#: tracks worse (4.31 cm): its points bunch on a few corners.
NMS_RADIUS = 2


def upsample(maps: NDArray[np.float32], size: tuple[int, int]) -> NDArray[np.float32]:
    """(C, h, w) maps resized bilinearly to ``size`` (w, h) with half-pixel centres, as
    ``F.interpolate(mode="bilinear", align_corners=False)`` does when enlarging."""
    c, h, w = maps.shape
    if (w, h) == tuple(size):
        return maps
    hwc = cv2.resize(np.ascontiguousarray(maps.transpose(1, 2, 0)), tuple(size), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(hwc.reshape(size[1], size[0], c).transpose(2, 0, 1))


def _source_index(n_out: int, n_in: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float32]]:
    """Bilinear sampling of an axis (half-pixel centres, clamped, as F.interpolate with
    align_corners=False): the two source indices and the weight of the second."""
    src = np.maximum((np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5, 0.0)
    i0 = np.minimum(np.floor(src).astype(np.intp), n_in - 1)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, (src - i0).astype(np.float32)


def upsampled_argmax(logits: NDArray[np.float32], size: tuple[int, int]) -> NDArray[np.intp]:
    """argmax over classes of ``logits`` (C, h, w) bilinearly upsampled to ``size`` (w, h),
    without upsampling all C channels.

    Exact: where the four source pixels of an output pixel share one argmax, that class
    wins the interpolated logits too (a convex combination of vectors whose largest entry
    is the same class keeps it largest); only output pixels on class boundaries are
    interpolated (35 ms instead of 100 ms for 40 classes at 640x480 on one core).
    """
    c, h, w = logits.shape
    y0, y1, wy = _source_index(size[1], h)
    x0, x1, wx = _source_index(size[0], w)
    low = logits.argmax(0)
    out = low[y0][:, x0]
    mixed = (out != low[y0][:, x1]) | (out != low[y1][:, x0]) | (out != low[y1][:, x1])
    yy, xx = np.nonzero(mixed)
    if yy.size:
        hwc = np.ascontiguousarray(logits.transpose(1, 2, 0))  # gathers then read whole rows
        ay, ax = wy[yy, None], wx[xx, None]
        ya, yb, xa, xb = y0[yy], y1[yy], x0[xx], x1[xx]
        top = hwc[ya, xa]
        top += ax * (hwc[ya, xb] - top)  # in place: fewer (K, C) temporaries
        v = hwc[yb, xa]
        v += ax * (hwc[yb, xb] - v)
        v -= top
        v *= ay
        v += top
        out[yy, xx] = v.argmax(1)
    return out


def nms_points(prob: NDArray[np.float32], radius: int) -> NDArray[np.bool_]:
    """Local maxima of a probability map in a (2r+1)^2 window (ties all kept). The window
    is cut at the image border (OpenCV's dilation ignores outside pixels, as max-pooling
    with padding does)."""
    if radius <= 0:
        return np.ones(prob.shape, bool)
    p = np.ascontiguousarray(prob, np.float32)
    return p == cv2.dilate(p, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))


def select_points(prob: NDArray[np.float32], n_points: int, threshold: float, nms_radius: int,
                  mask: NDArray[np.uint8] | None = None) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """(xy (N, 2) float32 pixels, probability (N,)) of the ``n_points`` most probable local
    maxima above ``threshold``, outside ``mask == 0``, strongest first (ties: row-major)."""
    keep = nms_points(prob, nms_radius) & (prob >= threshold)
    if mask is not None:
        keep &= mask > 0
    ys, xs = np.nonzero(keep)
    p = prob[ys, xs]
    order = np.argsort(-p, kind="stable")[:max(0, int(n_points))]
    xy = np.stack([xs[order], ys[order]], axis=1).astype(np.float32)
    return xy, p[order].astype(np.float32)


def descriptors_at(coarse: NDArray[np.float32], xy: NDArray[np.float32], cell: int = CELL) -> NDArray[np.float32]:
    """L2-normalised descriptors (N, D) at full-resolution pixels ``xy`` (N, 2) of a coarse
    (D, h, w) map ``cell`` times smaller: bilinear upsampling by ``cell`` read at the pixel,
    i.e. ``nets.fpfdcnn.sample_descriptors`` (``F.grid_sample``, border padding) in NumPy."""
    d, h, w = coarse.shape
    n = len(xy)
    if n == 0:
        return np.zeros((0, d), np.float32)
    # Pixel centre x of the upsampled map sits at coarse coordinate (x + 0.5) / cell - 0.5,
    # clamped to the map (border padding).
    cx = np.clip((xy[:, 0].astype(np.float32) + 0.5) / cell - 0.5, 0, w - 1)
    cy = np.clip((xy[:, 1].astype(np.float32) + 0.5) / cell - 0.5, 0, h - 1)
    x0 = np.floor(cx).astype(np.intp)
    y0 = np.floor(cy).astype(np.intp)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = (cx - x0)[:, None], (cy - y0)[:, None]
    hwd = coarse.transpose(1, 2, 0)
    top = hwd[y0, x0] * (1 - ax) + hwd[y0, x1] * ax
    bottom = hwd[y1, x0] * (1 - ax) + hwd[y1, x1] * ax
    desc = (top * (1 - ay) + bottom * ay).astype(np.float32)
    norm = np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)  # F.normalize's eps
    return np.ascontiguousarray(desc / norm, np.float32)
