"""The 7x7 sigma-2 Gaussian blur ORB's descriptor samples (ORB-SLAM's
``GaussianBlur(workingMat, workingMat, Size(7, 7), 2, 2, BORDER_REFLECT_101)`` on each
level), on the stacked pyramid.

``blur_levels`` runs the compiled ``orb.blur_kernels.gaussian7_levels`` on the levels'
pixels only, with OpenCV's fixed-point kernel (``gaussian_kernel_q8``), so it gives the
bytes of ``cv2.GaussianBlur`` on 8-bit images; ``blur_levels_reference`` is that OpenCV
call on the whole buffer, kept as the reference (tests). Why compiled: see
``blur_kernels``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.blur_kernels import gaussian7_levels
from semslam.features.orb.pyramid import StackedPyramid

__all__ = ["ORB_BLUR_KSIZE", "ORB_BLUR_SIGMA", "blur_levels", "blur_levels_reference", "gaussian_kernel_q8"]

ORB_BLUR_KSIZE = 7
ORB_BLUR_SIGMA = 2.0


def gaussian_kernel_q8(ksize: int, sigma: float) -> NDArray[np.int32]:
    """The 1-D Gaussian kernel in 8 fractional bits as OpenCV builds it for 8-bit images
    (``getGaussianKernelBitExact`` then error diffusion from the outer taps inwards,
    ``cvRound`` = half to even, the centre tap takes what makes the sum exactly 256).
    Checked against OpenCV's output for ORB's (7, 2.0) only (tests/test_orb_blur.py)."""
    if ksize % 2 != 1 or ksize < 3 or sigma <= 0:
        raise ValueError(f"need an odd ksize >= 3 and sigma > 0, got {ksize}, {sigma}")
    half = ksize // 2
    values = [math.exp(-((i - half) ** 2) / (2.0 * sigma * sigma)) for i in range(half)]
    total = 2.0 * sum(values) + 1.0
    taps = np.zeros(ksize, np.int32)
    err = 0.0
    for i, v in enumerate(values):
        adjusted = v / total * 256.0 + err
        q = round(adjusted)
        err = adjusted - q
        taps[i] = taps[ksize - 1 - i] = q
    taps[half] = 256 - 2 * int(taps[:half].sum())
    return taps


_ORB_TAPS = gaussian_kernel_q8(ORB_BLUR_KSIZE, ORB_BLUR_SIGMA)
_ORB_COEFFS = np.ascontiguousarray(_ORB_TAPS[:ORB_BLUR_KSIZE // 2 + 1])  # outer .. centre


def blur_levels(pyr: StackedPyramid, out: NDArray[np.uint8], ring: NDArray[np.int32] | None = None
                ) -> NDArray[np.int32]:
    """Blur every level of ``pyr`` into the same pixels of ``out`` (same shape as
    ``pyr.buffer``; its padding and unused margins are not written). Needs ``pyr.pad``
    >= 3. Returns the work rows (pass them back in to reuse them)."""
    if pyr.pad < ORB_BLUR_KSIZE // 2:
        raise ValueError(f"the pyramid needs >= {ORB_BLUR_KSIZE // 2} px of padding, has {pyr.pad}")
    if out.shape != pyr.buffer.shape or out.dtype != np.uint8:
        raise ValueError(f"out must be uint8 of shape {pyr.buffer.shape}, got {out.dtype} {out.shape}")
    if not pyr.levels:
        return ring if ring is not None else np.zeros((7, 1), np.int32)
    widest = int(pyr.widths.max())
    if ring is None or ring.shape[0] < 7 or ring.shape[1] < widest:
        ring = np.zeros((7, widest), np.int32)
    gaussian7_levels(pyr.buffer, out, np.ascontiguousarray(pyr.rows, np.int64), pyr.widths, pyr.heights, pyr.pad,
                     _ORB_COEFFS, ring)
    return ring


def blur_levels_reference(pyr: StackedPyramid) -> NDArray[np.uint8]:
    """OpenCV's blur of the whole stacked buffer (equal to ``blur_levels`` on the levels'
    pixels, and to blurring each level on its own with BORDER_REFLECT_101)."""
    return cv2.GaussianBlur(pyr.buffer, (ORB_BLUR_KSIZE, ORB_BLUR_KSIZE), ORB_BLUR_SIGMA,
                            sigmaY=ORB_BLUR_SIGMA, borderType=cv2.BORDER_REFLECT_101)
