"""Dense depth from a rectified stereo pair, for the parts that read a depth image.

ORB-SLAM2's stereo matching (``slam/orb/stereo_matching.py``) gives depth at keypoints only;
the dynamic front end (SRM mask refinement, the multi-view check, inpainting) and the map
builders read a dense depth image (float32 metres, 0 = none). :class:`StereoDepth` makes one
with OpenCV's semi-global matcher; :func:`right_view_mask` carries a left-image mask into the
right image of the pair.

Defaults, measured in ``docs/results/stereo_depth.md`` (640x480 renders, 0.11 m baseline):

- ``downscale=3``: a third of the cost of half resolution (3.4 against 7.6 ms a frame, and
  1/7 of that against full resolution) at nearly its accuracy (median error 2.0 against 2.0 %,
  p90 5.1 against 4.8 %); 1/4 doubles the error. Coarser than full resolution, the median
  error doubles (pixel locking of a coarser disparity step) but more pixels get a depth, so
  as many are within 5 % overall. Depth is upsampled by nearest, never blurred across edges.
- ``mode="sgbm3way"``: the cheapest mode; ``hh4`` buys ~1 point for ~9 ms more.
- ``block_size=5``: 7 or 9 gain ~1 point overall at the same cost but lose it within a few
  pixels of depth jumps (fattening), where the masks and the maps need it.
- ``min_depth=0.4`` m, not ORB-SLAM2's minZ = baseline: the disparities searched are
  ``bf / min_depth``, and bf / b = fx (~535 px) would cost several times more and leave no
  disparity at all in the left ~535 columns; 0.4 m is a Kinect's near limit, the range the
  RGB-D pipeline already expects. A surface nearer than it gets no depth or a false, farther one.
- ``pad_left=True``: OpenCV gives no disparity in the left ``numDisparities`` columns;
  padding both images on the left lets those columns match what their own column can see
  (disparity <= column, more is dropped): +22 points of pixels with depth for ~2.5 ms. Nearer
  points there stay 0: the right camera does not see them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.types import Frame
from semslam.errors import ConfigError

#: The matcher modes this module exposes, by name (OpenCV's StereoSGBM modes).
MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "sgbm3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh4": cv2.StereoSGBM_MODE_HH4,
    "hh": cv2.StereoSGBM_MODE_HH,
}


@dataclass
class StereoDepth:
    """Dense depth of the left image of a rectified pair: ``bf`` = fx * baseline (pixels *
    metres, depth = bf / disparity), the full image size, and the matcher's options. One
    object per reader thread (the OpenCV matcher is not shared across threads)."""

    bf: float
    width: int
    height: int
    downscale: int = 3
    min_depth: float = 0.4
    max_depth: float = 10.0
    mode: str = "sgbm3way"
    block_size: int = 5
    uniqueness: int = 10
    speckle_window: int = 100  # full-resolution pixels; scaled by the downscale's area
    speckle_range: int = 2
    pad_left: bool = True
    _matcher: Any = field(init=False, repr=False)
    _num_disp: int = field(init=False, repr=False)
    _small: tuple[int, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.bf > 0:
            raise ConfigError(f"stereo depth: bf must be positive, got {self.bf}")
        if self.width < 16 or self.height < 16:
            raise ConfigError(f"stereo depth: image too small ({self.width}x{self.height})")
        if self.downscale < 1:
            raise ConfigError(f"stereo depth: downscale must be >= 1, got {self.downscale}")
        if not 0 < self.min_depth < self.max_depth:
            raise ConfigError(f"stereo depth: need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.mode not in MODES:
            raise ConfigError(f"stereo depth: unknown mode {self.mode!r} (choose from {', '.join(MODES)})")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ConfigError(f"stereo depth: block_size must be odd and positive, got {self.block_size}")
        ds = self.downscale
        self._small = (max(1, round(self.width / ds)), max(1, round(self.height / ds)))
        max_disp = self.bf / self.min_depth / ds  # the nearest depth, in reduced-scale pixels
        self._num_disp = max(16, 16 * math.ceil(max_disp / 16))
        area = self.block_size * self.block_size
        self._matcher = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=self._num_disp,
            blockSize=self.block_size,
            P1=8 * area,  # OpenCV's recommendation for one channel: 8 and 32 * cn * blockSize^2
            P2=32 * area,
            disp12MaxDiff=1,
            preFilterCap=63,
            uniquenessRatio=self.uniqueness,
            speckleWindowSize=max(1, self.speckle_window // (ds * ds)) if self.speckle_window else 0,
            speckleRange=self.speckle_range,
            mode=MODES[self.mode],
        )

    @property
    def num_disparities(self) -> int:
        """Disparities searched, in reduced-scale pixels (a multiple of 16)."""
        return self._num_disp

    def compute(self, left_gray: NDArray[np.uint8], right_gray: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Depth (metres, 0 = none) of the left image at full resolution."""
        shape = (self.height, self.width)
        if left_gray.shape != shape or right_gray.shape != shape:
            raise ValueError(f"stereo depth: images {left_gray.shape} and {right_gray.shape}, expected {shape}")
        ds = self.downscale
        if ds > 1:
            left = cv2.resize(left_gray, self._small, interpolation=cv2.INTER_AREA)
            right = cv2.resize(right_gray, self._small, interpolation=cv2.INTER_AREA)
        else:
            left, right = left_gray, right_gray
        pad = self._num_disp if self.pad_left else 0
        if pad:
            left = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
            right = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        disp16 = self._matcher.compute(left, right)[:, pad:]  # int16, disparity * 16
        # Full-resolution disparity: 1/16 px steps, times the scale (the downscale, exactly
        # so when it divides the width).
        scale = self.width / self._small[0] if ds > 1 else 1.0
        disp = disp16.astype(np.float32) * np.float32(scale / 16.0)
        if pad:
            # A left pixel at column u can only match right columns >= 0: disparity <= u
            # (at the reduced scale); more means it matched into the padding.
            cols = np.arange(disp.shape[1], dtype=np.float32) * np.float32(scale)
            disp[disp > cols[None, :] + np.float32(scale)] = 0.0
        valid = disp > 0
        depth = np.zeros_like(disp)
        np.divide(self.bf, disp, out=depth, where=valid)
        depth[(depth < self.min_depth * 0.999) | (depth > self.max_depth)] = 0.0
        if ds > 1:
            depth = cv2.resize(depth, (self.width, self.height), interpolation=cv2.INTER_NEAREST)
        return depth


def fill_frame_depth(frame: Frame, stereo_depth: StereoDepth) -> None:
    """A stereo frame without a depth image gets the pair's (``frame.depth``)."""
    if frame.depth is None and frame.right_gray is not None:
        frame.depth = stereo_depth.compute(frame.gray, frame.right_gray)


def right_view_mask(mask: NDArray[np.bool_], depth: NDArray[np.float32], bf: float,
                    grow: int = 2, missing: str = "own", step: int = 1) -> NDArray[np.bool_]:
    """The left image's ``mask`` carried into the right image of the rectified pair: a masked
    pixel (u, v) of depth z lands at (u - bf / z, v). A pixel without depth stays at (u, v)
    (``missing="own"``) or takes the median disparity of the pixels with depth in its
    8-connected part of the mask (``missing="component"``: a person partly without stereo
    depth still moves as one; measured in docs/results/stereo_depth.md). The splat leaves
    one-pixel gaps where the disparity changes across an object, so the result is dilated by
    ``grow`` pixels horizontally (a dynamic mask may err on the large side). ``step`` > 1
    carries every ``step``-th pixel of every ``step``-th row and scales the result back up
    (nearest): a person covers tens of thousands of pixels, and the mask is there to keep
    keypoints off them, which a few pixels' resolution does as well."""
    if mask.shape != depth.shape:
        raise ValueError(f"right_view_mask: mask {mask.shape} and depth {depth.shape} differ")
    if missing not in ("own", "component"):
        raise ValueError(f"right_view_mask: missing must be 'own' or 'component', got {missing!r}")
    if step > 1:
        small = right_view_mask(mask[::step, ::step], depth[::step, ::step], bf / step,
                                max(1, -(-grow // step)), missing)
        full = cv2.resize(small.view(np.uint8), (mask.shape[1], mask.shape[0]), interpolation=cv2.INTER_NEAREST)
        return full.astype(bool)
    h, w = mask.shape
    vs, us = np.nonzero(mask)
    z = depth[vs, us]
    has = z > 0
    shift = np.zeros(len(z), np.float64)
    shift[has] = bf / z[has].astype(np.float64)
    if missing == "component" and has.any() and not has.all():
        shift = _fill_by_component(mask, vs, us, shift, has)
    ur = np.rint(us - shift).astype(np.intp)
    inside = (ur >= 0) & (ur < w)
    out = np.zeros((h, w), np.uint8)
    out[vs[inside], ur[inside]] = 1
    if grow > 0:
        out = cv2.dilate(out, np.ones((1, 2 * grow + 1), np.uint8))
    return out.astype(bool)


def _fill_by_component(mask: NDArray[np.bool_], vs: NDArray[np.intp], us: NDArray[np.intp],
                       shift: NDArray[np.float64], has: NDArray[np.bool_]) -> NDArray[np.float64]:
    """``shift`` where ``has`` is False replaced by the median shift of the pixels with depth in
    the same connected part of ``mask`` (kept where the part has none). Vectorised: the
    pixels with depth sorted by (part, shift), the median read at each part's middle index."""
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    lab = labels[vs, us]
    lab_has, s_has = lab[has], shift[has]
    order = np.lexsort((s_has, lab_has))
    lab_sorted, s_sorted = lab_has[order], s_has[order]
    counts = np.bincount(lab_sorted, minlength=lab.max() + 1)
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    lo = starts + np.maximum(counts - 1, 0) // 2
    hi = starts + counts // 2
    med = np.zeros(len(counts))
    ok = counts > 0
    med[ok] = 0.5 * (s_sorted[np.minimum(lo[ok], len(s_sorted) - 1)] + s_sorted[np.minimum(hi[ok], len(s_sorted) - 1)])
    out = shift.copy()
    fill = ~has & ok[lab]
    out[fill] = med[lab[fill]]
    return out
