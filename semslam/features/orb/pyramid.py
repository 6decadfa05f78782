"""ORB-SLAM's scale pyramid and the per-level numbers other modules need (sigma^2 for
reprojection-error weights, per-level feature budgets).

Follows ORB-SLAM2 ``ORBextractor`` (constructor and ``ComputePyramid``)."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.pyramid_kernels import reflect_pad_levels
from semslam.features.orb.scratch import kernel_array

# ORB-SLAM's constants: FAST keypoints are kept EDGE_THRESHOLD px away from the level
# border so that the 31x31 orientation patch and the rotated BRIEF pattern (reach
# round(13 sqrt(2)) = 18 px) never leave the level image.
EDGE_THRESHOLD = 19
PATCH_SIZE = 31
HALF_PATCH_SIZE = 15


def scale_factors(n_levels: int, scale_factor: float) -> NDArray[np.float64]:
    """s^level for every level (ORB-SLAM ``mvScaleFactor``): level-0 px per level px."""
    return float(scale_factor) ** np.arange(n_levels, dtype=np.float64)


def inv_scale_factors(n_levels: int, scale_factor: float) -> NDArray[np.float64]:
    """1 / s^level (ORB-SLAM ``mvInvScaleFactor``)."""
    return 1.0 / scale_factors(n_levels, scale_factor)


def level_sigma2(n_levels: int, scale_factor: float) -> NDArray[np.float64]:
    """s^(2 level) (ORB-SLAM ``mvLevelSigma2``): variance of a keypoint's position in
    level-0 pixels^2, used to weight reprojection errors and chi^2 gates."""
    return scale_factors(n_levels, scale_factor) ** 2


def inv_level_sigma2(n_levels: int, scale_factor: float) -> NDArray[np.float64]:
    """1 / s^(2 level) (ORB-SLAM ``mvInvLevelSigma2``): information weight per level."""
    return 1.0 / level_sigma2(n_levels, scale_factor)


def features_per_level(n_features: int, n_levels: int, scale_factor: float) -> NDArray[np.int64]:
    """ORB-SLAM's feature budget per level: N (1 - 1/s) / (1 - (1/s)^L) (1/s)^level,
    rounded, with the remainder given to the last level so the sum is exactly N.

    Computed in float32 with round-half-to-even like ORB-SLAM (``cvRound`` on floats) so
    the counts are bit-identical (1000, 1.2, 8 -> 217 181 151 126 105 87 73 60)."""
    if n_levels < 1:
        raise ValueError("n_levels must be >= 1")
    factor = np.float32(1.0) / np.float32(scale_factor)
    desired = np.float32(n_features) * (np.float32(1.0) - factor) / np.float32(
        1.0 - math.pow(float(factor), float(n_levels))
    ) if n_levels > 1 else np.float32(n_features)
    counts = np.zeros(n_levels, np.int64)
    total = 0
    for level in range(n_levels - 1):
        counts[level] = int(np.rint(desired))
        total += int(counts[level])
        desired = np.float32(desired * factor)
    counts[n_levels - 1] = max(n_features - total, 0)
    return counts


@functools.lru_cache(maxsize=64)
def _level_sizes(width: int, height: int, n_levels: int, scale_factor: float) -> tuple[tuple[int, int], ...]:
    inv = np.float32(1.0) / np.float32(scale_factors(n_levels, scale_factor)).astype(np.float32)
    return tuple((int(np.rint(np.float32(width) * s)), int(np.rint(np.float32(height) * s))) for s in inv)


def level_sizes(width: int, height: int, n_levels: int, scale_factor: float) -> list[tuple[int, int]]:
    """(width, height) of every level: cvRound(size / s^level) as in ORB-SLAM (cached:
    the same few image sizes come back every frame)."""
    return list(_level_sizes(int(width), int(height), int(n_levels), float(scale_factor)))


class StackedPyramid:
    """The level images stored one below the other in one buffer with a single row
    stride, each surrounded by ``pad`` px of BORDER_REFLECT_101.

    Why: per-keypoint gathers (orientation patch, BRIEF tests) for all levels become one
    numpy gather; blurring each level's pixels reading the padding around it equals
    blurring every level on its own with BORDER_REFLECT_101 (ORB-SLAM) as long as the
    kernel radius is <= ``pad`` (``orb.blur``); and the
    buffer is reused from frame to frame (fresh multi-MB arrays cost page faults).
    Level ``l``'s pixel (x, y) is ``buffer[rows[l] + y, pad + x]``; ``levels[l]`` is a
    view of it, ``widths[l]`` x ``heights[l]`` pixels."""

    def __init__(self, buffer: NDArray[np.uint8], rows: NDArray[np.int64], pad: int,
                 levels: list[NDArray[np.uint8]]) -> None:
        self.buffer, self.rows, self.pad, self.levels = buffer, rows, pad, levels
        self.widths = np.array([lv.shape[1] for lv in levels], np.int64)
        self.heights = np.array([lv.shape[0] for lv in levels], np.int64)


def build_pyramid(gray: NDArray[np.uint8], n_levels: int, scale_factor: float, pad: int = 3,
                  buffer: NDArray[np.uint8] | None = None) -> StackedPyramid:
    """The scale pyramid, each level resized with INTER_LINEAR from the previous level
    (as ORB-SLAM does; resizing from level 0 would alias more on the small levels).

    ``buffer`` is reused when its shape fits (see ``pyramid_buffer_shape``). Levels too
    small to hold a pixel are left out. Deviation: ORB-SLAM pads each level by
    EDGE_THRESHOLD, but nothing it computes reads that padding (FAST runs on cell ROIs,
    keypoints are >= EDGE_THRESHOLD from the border, the descriptor blur runs on an
    unpadded clone with BORDER_REFLECT_101); our ``pad`` only serves that blur."""
    gray = np.asarray(gray)
    sizes = [(w, h) for w, h in level_sizes(gray.shape[1], gray.shape[0], n_levels, scale_factor)
             if w > pad and h > pad]
    shape = pyramid_buffer_shape(sizes, pad)
    if buffer is None or buffer.shape != shape or buffer.dtype != np.uint8:
        buffer = np.zeros(shape, np.uint8)
    heights = np.array([h + 2 * pad for _, h in sizes], np.int64)
    rows = np.concatenate([[0], np.cumsum(heights)[:-1]]).astype(np.int64) + pad
    levels: list[NDArray[np.uint8]] = []
    for level, ((w, h), r) in enumerate(zip(sizes, rows)):
        view = buffer[r:r + h, pad:pad + w]
        if level == 0:
            view[...] = gray
        else:
            cv2.resize(levels[-1], (w, h), dst=view, interpolation=cv2.INTER_LINEAR)
        levels.append(view)
    pyr = StackedPyramid(buffer, rows, pad, levels)
    if pad and sizes:
        # BORDER_REFLECT_101 around every level, rows first then columns (corners too).
        reflect_pad_levels(buffer, rows, pyr.widths, pyr.heights, pad)
    return pyr


def pyramid_buffer_shape(sizes: list[tuple[int, int]], pad: int) -> tuple[int, int]:
    """(rows, cols) of the stacked buffer for level sizes (width, height)."""
    return (sum(h + 2 * pad for _, h in sizes), max(w for w, _ in sizes) + 2 * pad)


class MaskSampler(NamedTuple):
    """A detect mask as seen from one image: pixel (x, y) is allowed iff
    ``mask[rows[y], cols[x]] != 0``. Why: the FAST kernels read the mask only at the few
    keypoints that survive non-max suppression, so a level's mask is never materialised
    (``image()`` does, for references and tests)."""

    mask: NDArray[np.uint8]  # 2-D, C-contiguous
    rows: NDArray[np.int64]
    cols: NDArray[np.int64]

    @classmethod
    def same_size(cls, mask: NDArray) -> MaskSampler:
        """A mask of the image's own size (FAST's ``mask`` argument)."""
        m = kernel_array(mask, np.uint8)
        return cls(m, np.arange(m.shape[0], dtype=np.int64), np.arange(m.shape[1], dtype=np.int64))

    def crop(self, x0: int, y0: int, width: int, height: int) -> MaskSampler:
        """The sampler of the sub-image ``[x0, x0 + width) x [y0, y0 + height)``."""
        return MaskSampler(self.mask, self.rows[y0:y0 + height], self.cols[x0:x0 + width])

    def image(self) -> NDArray[np.uint8]:
        """The mask as an image of the sampled size."""
        return np.ascontiguousarray(self.mask[self.rows][:, self.cols])


def level_mask_indices(mask_shape: tuple[int, int], level_shape: tuple[int, int], scale: float
                       ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Level-0 row of every level row and column of every level column: the nearest
    level-0 pixel to the level pixel's reported position ``(x, y) * s`` (float32).
    The arrays are shared between calls with the same arguments (a frame's sixteen of
    them cost ~0.1 ms), hence read-only."""
    return _level_mask_indices(tuple(mask_shape[:2]), tuple(level_shape[:2]), float(scale))


@functools.lru_cache(maxsize=64)
def _level_mask_indices(mask_shape: tuple[int, int], level_shape: tuple[int, int], scale: float
                        ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    h, w = level_shape
    s = np.float32(scale)
    rows = np.minimum(np.rint(np.arange(h, dtype=np.float32) * s).astype(np.int64), mask_shape[0] - 1)
    cols = np.minimum(np.rint(np.arange(w, dtype=np.float32) * s).astype(np.int64), mask_shape[1] - 1)
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def level_mask(mask: NDArray[np.uint8], level_shape: tuple[int, int], scale: float) -> NDArray[np.uint8]:
    """The level-0 mask sampled at the level pixels' level-0 positions.

    A level pixel (x, y) is reported at (x s, y s) in level-0 pixels (float32, like the
    keypoints); it is allowed iff the level-0 pixel nearest to that position is allowed,
    so filtering at the level is exactly filtering the output keypoints by
    ``mask[rint(y), rint(x)]``."""
    rows, cols = level_mask_indices(mask.shape, level_shape, scale)
    return np.ascontiguousarray(mask[rows][:, cols])


def level_masks(mask: NDArray[np.uint8] | None, images: list[NDArray[np.uint8]],
                scales: NDArray[np.float64]) -> list[NDArray[np.uint8]] | None:
    """``level_mask`` for every level image (level 0 is the mask itself); None without a mask."""
    if mask is None:
        return None
    return [mask if level == 0 else level_mask(mask, image.shape, scales[level])
            for level, image in enumerate(images)]


def level_mask_samplers(mask: NDArray[np.uint8] | None, images: list[NDArray[np.uint8]],
                        scales: NDArray[np.float64]) -> list[MaskSampler] | None:
    """``level_masks`` without materialising them: one ``MaskSampler`` per level image
    (same pixels allowed as ``level_masks``); None without a mask."""
    if mask is None:
        return None
    m = kernel_array(mask, np.uint8)
    return [MaskSampler(m, *level_mask_indices(m.shape, image.shape, 1.0 if level == 0 else scales[level]))
            for level, image in enumerate(images)]


def level0_xy(x: NDArray[np.integer], y: NDArray[np.integer], level: NDArray[np.integer],
              scales: NDArray[np.float64]) -> NDArray[np.float32]:
    """Level pixels (x, y) at ``level`` as level-0 positions ``(x, y) * s^level`` in float32
    (ORB-SLAM reports keypoints like this)."""
    scale = scales.astype(np.float32)[level]
    return np.stack([x, y], axis=1).astype(np.float32) * scale[:, None]
