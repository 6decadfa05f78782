"""OpenCV ORB's Harris response (``HarrisResponses``: block 7, k = 0.04) at given pixels,
the score STDC-SLAM's Qtree-ORB uses to pick each quadtree node's point.

``harris_responses`` runs the compiled ``harris_kernels.harris_at``;
``harris_responses_numpy`` is the vectorised numpy version it replaced, kept as the
reference (identical results, tests).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.harris_kernels import harris_at
from semslam.features.orb.scratch import Scratch, kernel_array

__all__ = ["HARRIS_K", "harris_responses", "harris_responses_numpy"]

HARRIS_K = 0.04
_BLOCK = 7
_SCALE = 1.0 / (4.0 * _BLOCK * 255.0)  # OpenCV: 1 / ((1 << 2) * blockSize * 255)


def harris_responses(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                     k: float = HARRIS_K, scratch: Scratch | None = None) -> NDArray[np.float64]:
    """OpenCV ORB's ``HarrisResponses`` (block 7) at integer pixels at least 4 px from
    the border: ``(a b - c^2 - k (a + b)^2) / (4 * 7 * 255)^4`` with a, b, c the sums of
    dx^2, dy^2, dx dy of 3x3 Sobel gradients over the 7x7 block (a, b, c exact integers
    as in OpenCV; the formula in float64). ``scratch`` is unused (the numpy version's
    signature)."""
    n = len(x)
    if n == 0:
        return np.zeros(0, np.float64)
    img = kernel_array(image, np.uint8)
    xi, yi = kernel_array(x, np.int64), kernel_array(y, np.int64)
    h, w = img.shape
    if xi.min() < 4 or yi.min() < 4 or xi.max() >= w - 4 or yi.max() >= h - 4:
        raise ValueError("Harris pixels must be at least 4 px from the image border")
    if xi.max() == w - 5:
        img = np.pad(img, ((0, 0), (0, 1)))  # the kernel's 8-wide rows read one more column
        w += 1
    out = np.empty(n, np.float64)
    harris_at(img.reshape(-1), w, xi, yi, float(k), _SCALE**4, out)
    return out


def _harris_kernel() -> NDArray[np.float32]:
    """(81, 98) matrix mapping a 9x9 patch (row-major) to the 7x7 Sobel x then y
    gradients around its centre (OpenCV ORB ``HarrisResponses``' dx, dy)."""
    kern = np.zeros((9, 9, 2, 7, 7), np.float32)
    for i in range(7):
        for j in range(7):
            for d, wt in ((-1, 1.0), (0, 2.0), (1, 1.0)):
                kern[i + 1 + d, j + 2, 0, i, j] += wt  # dx: right column minus left column
                kern[i + 1 + d, j, 0, i, j] -= wt
                kern[i + 2, j + 1 + d, 1, i, j] += wt  # dy: bottom row minus top row
                kern[i, j + 1 + d, 1, i, j] -= wt
    return kern.reshape(81, 98)


_HARRIS_KERNEL = _harris_kernel()
_HARRIS_CHUNK = 512


def harris_responses_numpy(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                           k: float = HARRIS_K, scratch: Scratch | None = None) -> NDArray[np.float64]:
    """``harris_responses`` in numpy (the reference the compiled version is tested against).

    Vectorised: the 9x9 windows are copied in chunks and turned into both gradient
    blocks by one float32 matmul (exact: integers < 2^24); the sums of products in
    float64 (exact: < 2^53; float32 sums, as an earlier version had, round once a sum
    passes 2^24, which a very strong corner can)."""
    n = len(x)
    if n == 0:
        return np.zeros(0, np.float64)
    scratch = scratch or Scratch()
    windows = np.lib.stride_tricks.sliding_window_view(image, (9, 9))
    wy = np.asarray(y, np.intp) - 4
    wx = np.asarray(x, np.intp) - 4
    pbuf = scratch.get("h_p", (_HARRIS_CHUNK, 81), np.float32)
    gbuf = scratch.get("h_g", (_HARRIS_CHUNK, 98), np.float32)
    abc = np.empty((n, 3), np.float64)
    for i in range(0, n, _HARRIS_CHUNK):
        j = min(i + _HARRIS_CHUNK, n)
        p, g = pbuf[: j - i], gbuf[: j - i]
        np.copyto(p, windows[wy[i:j], wx[i:j]].reshape(j - i, 81))
        np.matmul(p, _HARRIS_KERNEL, out=g)
        gx, gy = g[:, :49].astype(np.float64), g[:, 49:].astype(np.float64)
        abc[i:j, 0] = np.einsum("ij,ij->i", gx, gx)
        abc[i:j, 1] = np.einsum("ij,ij->i", gy, gy)
        abc[i:j, 2] = np.einsum("ij,ij->i", gx, gy)
    a, b, c = abc[:, 0], abc[:, 1], abc[:, 2]
    return (a * b - c * c - k * (a + b) ** 2) * _SCALE**4
