"""Kinect-like depth: axial noise, disparity quantisation, holes, range limits.

Trackers that use depth must cope with what a Kinect really delivers (TUM fr3): noise
that grows with the square of the distance (Nguyen et al. 2012), 1/8-pixel disparity
steps, no depth at object borders, on grazing surfaces and in random small blobs, and
nothing nearer than 0.4 m or farther than ~4.5 m.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

Z_MIN = 0.4
Z_MAX = 4.5
DEPTH_SCALE = 5000.0  # PNG units per metre, as in TUM
BASELINE_FOCAL = 0.075 * 580.0  # Kinect baseline (m) * IR focal length (px)
_CORR_SIGMA = 0.7  # px, spatial correlation of the depth noise
_CORR_GAIN = np.float32(1.0 / float((cv2.getGaussianKernel(5, _CORR_SIGMA) ** 2).sum()))


def axial_sigma(z: NDArray[np.float32]) -> NDArray[np.float32]:
    """Standard deviation (m) of Kinect depth at distance z (Nguyen et al. 2012)."""
    return (0.0012 + 0.0019 * (z - 0.4) ** 2).astype(np.float32)


def kinect_depth(
    z: NDArray[np.float32],
    cos: NDArray[np.float32],
    rng: np.random.Generator | None,
    noise: NDArray[np.float32] | None = None,
) -> NDArray[np.uint16]:
    """Depth PNG values (m * 5000, 0 = none) from exact z-depth.

    ``rng=None`` means no noise and no holes (exact up to the 0.2 mm PNG step), for tests.
    ``cos`` is the cosine of the incidence angle per pixel, for grazing-angle dropout;
    ``noise`` an optional standard-normal field (drawn from ``rng`` if not given).
    """
    z = z.astype(np.float32, copy=True)
    valid = np.isfinite(z) & (z >= Z_MIN) & (z <= Z_MAX)
    if rng is not None:
        zc = np.where(valid, z, 1.0).astype(np.float32)
        if noise is None:
            noise = rng.standard_normal(z.shape, dtype=np.float32)
        # a little spatial correlation, like the real sensor's block matching
        # (rescaled so that its standard deviation stays 1)
        noise = cv2.GaussianBlur(np.ascontiguousarray(noise), (5, 5), _CORR_SIGMA) * _CORR_GAIN
        zn = zc + noise * axial_sigma(zc)
        # quantise in disparity: 1/8 pixel steps of the IR camera
        disp = np.round(BASELINE_FOCAL * 8.0 / np.maximum(zn, 0.1)) / 8.0
        z = np.where(valid, BASELINE_FOCAL / np.maximum(disp, 1e-3), 0.0).astype(np.float32)
        valid &= _holes(zc, cos, valid, rng)
    out = np.where(valid, np.round(z * DEPTH_SCALE), 0.0)
    return np.clip(out, 0, 65535).astype(np.uint16)


def _holes(
    z: NDArray[np.float32],
    cos: NDArray[np.float32],
    valid: NDArray[np.bool_],
    rng: np.random.Generator,
) -> NDArray[np.bool_]:
    """Mask of pixels that keep their depth (False = hole)."""
    h, w = z.shape
    zz = np.where(valid, z, 0.0).astype(np.float32)
    # depth discontinuities: relative jump to a neighbour
    gx = np.abs(np.diff(zz, axis=1, append=zz[:, -1:]))
    gy = np.abs(np.diff(zz, axis=0, append=zz[-1:, :]))
    edge = (np.maximum(gx, gy) > 0.04 + 0.03 * zz).astype(np.uint8)
    edge = cv2.dilate(edge, np.ones((2, 2), np.uint8), anchor=(1, 1))  # both sides of the jump
    # shadow band: wider on the left of near objects (projector to the right of the camera)
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 3))
    band = cv2.dilate(edge, k, anchor=(3, 1))
    ragged = rng.random((h, w), dtype=np.float32) < 0.6
    keep = ~((band > 0) & ragged) & ~(edge > 0)
    # grazing surfaces give no return
    keep &= cos > np.float32(0.15)
    # random small dropout blobs
    blobs = np.zeros((h, w), np.uint8)
    for _ in range(int(rng.poisson(4))):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(2, 12)), int(rng.integers(2, 9)))
        cv2.ellipse(blobs, c, ax, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    keep &= blobs == 0
    # sparse isolated missing pixels
    keep &= rng.random((h, w), dtype=np.float32) > 0.003
    return keep
