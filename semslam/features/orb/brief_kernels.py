"""Compiled (numba) orientation and descriptor of ORB keypoints: the intensity-centroid
moments of ORB-SLAM's ``IC_Angle`` and the steered rBRIEF of ``computeOrbDescriptor``.

Why compiled: per keypoint both read a few hundred pixels at data-dependent places; numpy
needs big temporaries for that (31x31 windows, 512 offsets per keypoint), a loop reads
them straight from the image. Results are bit-identical to the numpy versions kept in
``semslam.features.orb.descriptors`` (tests). Kernels are ``nogil`` and cached on disk.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["ic_moments", "rotated_pattern", "steered_brief"]


@intrinsic
def _fma32(typingctx, a, b, c):  # noqa: ARG001 (numba's intrinsic signature)
    """float32 ``a * b + c`` with one rounding (LLVM's ``llvm.fma.f32``)."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        f32 = ir.FloatType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(f32, [f32, f32, f32]),
                                            "llvm.fma.f32")
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True, nogil=True)
def ic_moments(img, stride, x, y, weights_u, weights_v, m10, m01):
    """Intensity-centroid moments of the keypoints (``x``, ``y``): ``m10 = sum u I``,
    ``m01 = sum v I`` over ORB-SLAM's circular patch, into float32 ``m10`` / ``m01``
    (exact: integers < 2^24). ``img``: flat uint8 image with row stride ``stride``;
    ``weights_u`` / ``weights_v``: int32 (31, 32) weights u / v of the window
    ``[x - 15, x + 16] x [y - 15, y + 15]``, 0 outside the circle and in the last
    column (fixed 32-wide rows accumulated column-wise vectorise; the sums are
    ``IC_Angle``'s, exactly). The window must lie inside ``img``."""
    rows, cols = weights_u.shape
    half = rows // 2
    u = np.uint64
    acc10 = np.zeros(cols, np.int32)
    acc01 = np.zeros(cols, np.int32)
    for i in range(x.size):
        base = u((y[i] - half) * stride + x[i] - half)
        acc10[:] = 0
        acc01[:] = 0
        for r in range(rows):
            row = base + u(r * stride)
            for c in range(cols):
                p = np.int32(img[row + u(c)])
                acc10[c] = np.int32(acc10[c] + np.int32(weights_u[r, c] * p))
                acc01[c] = np.int32(acc01[c] + np.int32(weights_v[r, c] * p))
        s10 = 0
        s01 = 0
        for c in range(cols):
            s10 += acc10[c]
            s01 += acc01[c]
        m10[i] = np.float32(s10)
        m01[i] = np.float32(s01)


@njit(cache=True, nogil=True, inline="always")
def _rotate(a, b, px, py):
    """Pattern point (px, py) rotated by (cos, sin) = (a, b), rounded half to even:
    (column, row) = (rint(fma(b, -py, a px)), rint(fma(b, px, a py)))."""
    return np.rint(_fma32(b, -py, a * px)), np.rint(_fma32(b, px, a * py))


@njit(cache=True, nogil=True)
def rotated_pattern(cos_a, sin_a, pattern_x, pattern_y, col, row):
    """The rotated, rounded offsets ``steered_brief`` reads, (n, n_points) float32 each;
    for tests."""
    for i in range(cos_a.size):
        for k in range(pattern_x.size):
            col[i, k], row[i, k] = _rotate(cos_a[i], sin_a[i], pattern_x[k], pattern_y[k])


@njit(cache=True, nogil=True)
def steered_brief(img, stride, x, y, cos_a, sin_a, pattern_x, pattern_y, out):
    """ORB-SLAM's ``computeOrbDescriptor`` for every keypoint into ``out`` (n, 32) uint8:
    test ``k`` compares the blurred image at the pattern's pair ``2k``, ``2k + 1``
    rotated by the keypoint's angle (``cos_a``, ``sin_a``, float32), bit ``k % 8`` of
    byte ``k // 8`` set iff the first is darker.

    Rotated offset of a pattern point (px, py): column ``rint(fma(b, -py, a px))``, row
    ``rint(fma(b, px, a py))`` (round half to even, like ``cvRound``): the arithmetic of
    the numpy version's float32 BLAS product (first product rounded, second fused),
    which this reproduces bit for bit. ``img``: flat uint8 image with row stride
    ``stride``; keypoints at least 19 px from the border."""
    n_pts = pattern_x.size
    offsets = np.empty(n_pts, np.int64)
    for i in range(x.size):
        a = cos_a[i]
        b = sin_a[i]
        center = y[i] * stride + x[i]
        for k in range(n_pts):
            col, row = _rotate(a, b, pattern_x[k], pattern_y[k])
            offsets[k] = center + np.int64(row) * stride + np.int64(col)
        for byte in range(n_pts // 16):
            val = 0
            for bit in range(8):
                k = 2 * (8 * byte + bit)
                val |= (img[offsets[k]] < img[offsets[k + 1]]) << bit
            out[i, byte] = np.uint8(val)
