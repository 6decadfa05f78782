"""ORB-SLAM's FAST detection: the detection region of a level, its ~30 px cells, FAST at
a high threshold with a low-threshold retry in empty cells (``ComputeKeyPointsOctTree``).

Shared by ORB-SLAM2's extractor (``detect_levels``) and STDC-SLAM's Qtree-ORB (which
uses the cell grid and ``fast_points`` for its own two-threshold Algorithm 2). Both run
on the compiled FAST of ``semslam.features.orb.fast_kernels``, which reproduces
OpenCV's exactly; ``fast_points_cv2`` and ``detect_level_reference`` (literal per-cell
OpenCV calls, as ORB-SLAM) are kept as references for the tests.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.fast_kernels import detect_cells, detect_pyramid, detect_two_thresholds_pyramid
from semslam.features.orb.pyramid import EDGE_THRESHOLD, MaskSampler
from semslam.features.orb.scratch import Scratch, kernel_array

__all__ = ["BORDER", "CELL_SIZE", "CellGrid", "EMPTY_DETECTION", "cell_grid", "detect_level",
           "detect_level_reference", "detect_levels", "detect_levels_two_thresholds", "detection_levels", "detection_region",
           "fast_points", "fast_points_cv2", "region_sizes"]

CELL_SIZE = 30  # ORB-SLAM's W: side of the FAST cells in level pixels
BORDER = EDGE_THRESHOLD - 3  # ORB-SLAM's minBorderX: FAST's own 3 px margin inside it

Detected = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]
_NO_MASK = MaskSampler(np.ones((1, 1), np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64))


def fast_points_cv2(detector: cv2.FastFeatureDetector, image: NDArray[np.uint8],
                    mask: NDArray[np.uint8] | None) -> Detected:
    """OpenCV's FAST keypoints as integer x, y and float32 score arrays (row-major
    order). The reference ``fast_points`` reproduces; slow (one ``cv2.KeyPoint`` object
    per corner)."""
    kps = detector.detect(image, mask)
    if not kps:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    pts = cv2.KeyPoint_convert(kps).astype(np.int64)  # FAST positions are integers
    resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
    return pts[:, 0], pts[:, 1], resp


def _flat_image(image: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], int]:
    """A 1-D view of a 2-D uint8 image's memory from its first pixel, and its row
    stride in pixels (a copy if the rows are not plain byte rows). Why: the kernels then
    read levels of the stacked pyramid in place, with one compiled signature."""
    if (image.dtype != np.uint8 or image.ndim != 2 or image.strides[1] != 1
            or image.strides[0] < image.shape[1] or not image.flags.writeable):
        image = np.array(image, np.uint8, order="C")  # a fresh, writeable copy
    h, w = image.shape
    stride = int(image.strides[0]) if h > 1 else w
    n = (h - 1) * stride + w if h and w else 0
    return np.lib.stride_tricks.as_strided(image, shape=(n,), strides=(1,)), stride


def _fast_region(image: NDArray[np.uint8], x0: int, y0: int, width: int, height: int, t_hi: int,
                 t_lo: int, grid: CellGrid | None, mask: MaskSampler | None, scratch: Scratch
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.uint8], NDArray[np.int64]]:
    """``fast_kernels.detect_cells`` on the region ``[x0, x0 + width) x [y0, y0 + height)``
    of ``image``, with ORB-SLAM's cells of ``grid`` or, if None, as one cell (plain FAST;
    ``t_lo`` unused)."""
    for t in (t_hi, t_lo) if grid is not None else (t_hi,):
        if not 0 <= t <= 255:
            # OpenCV clamps in its scalar code but wraps modulo 256 in its SIMD code.
            raise ValueError(f"FAST thresholds must be in [0, 255], got {t}")
    flat, stride = _flat_image(image)
    if grid is None:
        n_cols = n_rows = 1
        w_cell, h_cell = max(width - 6, 1), max(height - 6, 1)
        t_lo = -1
    else:
        n_cols, n_rows, w_cell, h_cell = grid.n_cols, grid.n_rows, grid.w_cell, grid.h_cell
    size = max(width * height, 1)
    m = mask if mask is not None else _NO_MASK
    return detect_cells(flat, y0 * stride + x0, stride, width, height, int(t_hi), int(t_lo), n_cols, n_rows,
                        w_cell, h_cell, kernel_array(m.mask, np.uint8), kernel_array(m.rows, np.int64),
                        kernel_array(m.cols, np.int64), mask is not None,
                        scratch.get("fast_work", (size,), np.uint8), scratch.get("fast_flags", (size,), np.uint8),
                        scratch.get("fast_keep", (size,), np.uint8), scratch.get("fast_positions", (size,), np.int64))


def fast_points(image: NDArray[np.uint8], threshold: int, mask: NDArray | MaskSampler | None = None,
                scratch: Scratch | None = None) -> Detected:
    """OpenCV's FAST 9/16 with non-max suppression (``cv2.FastFeatureDetector_create(
    threshold, True, TYPE_9_16).detect(image, mask)``), exactly, from the compiled
    kernel: integer x, y and float32 score arrays in OpenCV's (row-major) order.
    ``mask``: same-size image (0 = forbidden) or a ``MaskSampler``; ``threshold`` in
    [0, 255] (OpenCV is not consistent outside it)."""
    h, w = np.shape(image)
    if mask is not None and not isinstance(mask, MaskSampler):
        mask = MaskSampler.same_size(np.asarray(mask))
    x, y, s, _ = _fast_region(image, 0, 0, w, h, threshold, -1, None, mask, scratch or Scratch())
    return x, y, s.astype(np.float32)


class CellGrid:
    """ORB-SLAM's FAST cells of one level, in distribution coordinates (level pixels
    minus ``EDGE_THRESHOLD - 3``). Cell (i, j) has the ROI ``[i hCell, min(i hCell +
    hCell + 6, height))`` x (likewise for columns) and, FAST keeping 3 px off the ROI
    border, detects in ``[i hCell + 3, min(...) - 3)``; these ranges tile
    ``[3, width - 3) x [3, height - 3)``. Use ``cell_grid`` (cached per size)."""

    def __init__(self, width: int, height: int) -> None:
        self.n_cols = max(1, int(width / CELL_SIZE))
        self.n_rows = max(1, int(height / CELL_SIZE))
        self.n_cells = self.n_cols * self.n_rows
        self.w_cell = int(math.ceil(width / self.n_cols))
        self.h_cell = int(math.ceil(height / self.n_rows))
        # Cells whose detection range is not empty (ORB-SLAM skips or finds nothing in
        # the others).
        j, i = np.arange(self.n_cols), np.arange(self.n_rows)
        cols_ok = np.minimum(j * self.w_cell + self.w_cell + 6, width) - 3 > j * self.w_cell + 3
        rows_ok = np.minimum(i * self.h_cell + self.h_cell + 6, height) - 3 > i * self.h_cell + 3
        self.has_region = (rows_ok[:, None] & cols_ok[None, :]).reshape(-1)
        # ROI (row and column slices) of every cell.
        self.rois = [(slice(r * self.h_cell, min(r * self.h_cell + self.h_cell + 6, height)),
                      slice(c * self.w_cell, min(c * self.w_cell + self.w_cell + 6, width)))
                     for r in range(self.n_rows) for c in range(self.n_cols)]

    def cell_of(self, x: NDArray[np.int64], y: NDArray[np.int64]) -> NDArray[np.int64]:
        return ((y - 3) // self.h_cell) * self.n_cols + (x - 3) // self.w_cell


@functools.lru_cache(maxsize=64)
def cell_grid(width: int, height: int) -> CellGrid:
    return CellGrid(width, height)


def detection_region(image: NDArray[np.uint8]) -> tuple[int, int] | None:
    """(width, height) of the distribution frame, None where the level is too small
    (ORB-SLAM stops at the first such level)."""
    h, w = image.shape
    width, height = w - 2 * BORDER, h - 2 * BORDER
    if width <= 0 or height <= 0:
        return None
    return width, height


EMPTY_DETECTION = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


def detect_levels(images: list[NDArray[np.uint8]], fast_threshold: int, fast_min_threshold: int,
                  masks: list[MaskSampler] | None = None, scratch: Scratch | None = None
                  ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], NDArray[np.int64]]:
    """FAST candidates of all levels exactly as ORB-SLAM's ``ComputeKeyPointsOctTree``
    finds them, level by level in its order (cell by cell, row-major inside a cell):
    x, y in each level's distribution frame (level pixels - EDGE_THRESHOLD + 3), scores
    and levels. Levels without a detection region must have been left out by the caller.

    Each ~30 px cell is FAST at ``fast_threshold`` on ORB-SLAM's own ROI, and again at
    ``fast_min_threshold`` if that found nothing; a corner's non-max suppression thus
    only sees neighbours inside its cell, and ``masks`` (FAST's mask, applied after the
    suppression) decide whether a cell counts as empty. Same keypoints, scores and order
    as ``detect_level_reference`` (tests), in one compiled call for all levels (levels
    of one stacked pyramid are read in place)."""
    _check_thresholds(fast_threshold, fast_min_threshold)
    if not images:
        return EMPTY_DETECTION + (np.zeros(0, np.int64),)
    levels, mask_maps, buffers = _kernel_layout(images, masks, scratch or Scratch())
    x, y, score, _, level = detect_pyramid(*levels, int(fast_threshold), int(fast_min_threshold), *mask_maps, *buffers)
    return x, y, score.astype(np.float32), level


def detect_levels_two_thresholds(images: list[NDArray[np.uint8]], n_wanted: NDArray[np.integer], fast_threshold: int,
                                 fast_min_threshold: int, masks: list[MaskSampler] | None = None,
                                 scratch: Scratch | None = None
                                 ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], NDArray[np.bool_],
                                            NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """STDC-SLAM's two-threshold FAST (Algorithm 2, ``semslam.features.qtree_orb``) on
    all levels in one compiled call (``fast_kernels.detect_two_thresholds_pyramid``):
    plain FAST at ``fast_threshold`` on each level's whole detection region; where that
    leaves the level short of ``n_wanted``, the low points (FAST at
    ``fast_min_threshold``, score below ``fast_threshold``) of a raster-order prefix of
    ORB-SLAM's cells. Returns x, y (distribution frame), score, high, level, level by
    level in (cell, y, x) order, and per level the high points found and the low points
    inserted. Levels without a detection region must have been left out."""
    _check_thresholds(fast_threshold, fast_min_threshold)
    empty = np.zeros(0, np.int64)
    if not images:
        return empty, empty, np.zeros(0, np.float32), np.zeros(0, bool), empty, empty, empty
    levels, mask_maps, buffers = _kernel_layout(images, masks, scratch or Scratch())
    x, y, score, high, level, n_high, n_low = detect_two_thresholds_pyramid(
        *levels, int(fast_threshold), int(fast_min_threshold), kernel_array(n_wanted, np.int64), *mask_maps, *buffers)
    return x, y, score.astype(np.float32), high.astype(bool), level, n_high, n_low


def _check_thresholds(*thresholds: int) -> None:
    for t in thresholds:
        if not 0 <= t <= 255:
            raise ValueError(f"FAST thresholds must be in [0, 255], got {t}")


def _kernel_layout(images: list[NDArray[np.uint8]], masks: list[MaskSampler] | None, scratch: Scratch
                   ) -> tuple[tuple[Any, ...], tuple[Any, ...], tuple[Any, ...]]:
    """The arguments both pyramid kernels (``detect_pyramid``,
    ``detect_two_thresholds_pyramid``) take, in their order: the levels' regions (flat
    buffer, region starts, row stride, widths, heights, cell grids), the mask maps (mask,
    row / column maps, where each level's maps start, whether to use them) and the work
    buffers (sized for the largest region, reused through ``scratch``)."""
    sizes = [detection_region(image) or (0, 0) for image in images]
    grids = np.array([_grid_numbers(cell_grid(w, h)) for w, h in sizes], np.int64).reshape(-1, 4)
    widths = np.array([w for w, _ in sizes], np.int64)
    heights = np.array([h for _, h in sizes], np.int64)
    src, stride, origins = _shared_buffer(images)
    bases = origins + BORDER * stride + BORDER
    mask, rows, cols, first = _stacked_maps(masks, sizes)
    size = max(int(widths.max() * heights.max()), 1)
    buffers = (scratch.get("fast_work", (size,), np.uint8), scratch.get("fast_flags", (size,), np.uint8),
               scratch.get("fast_keep", (size,), np.uint8), scratch.get("fast_positions", (size,), np.int64),
               scratch.get("fast_cells", (size,), np.int64))
    return (src, bases, stride, widths, heights, grids), (mask, rows, cols, first, masks is not None), buffers


def _grid_numbers(grid: CellGrid) -> tuple[int, int, int, int]:
    return grid.n_cols, grid.n_rows, grid.w_cell, grid.h_cell


def _shared_buffer(images: list[NDArray[np.uint8]]) -> tuple[NDArray[np.uint8], int, NDArray[np.int64]]:
    """One flat uint8 array holding every image with one row stride, and the flat index
    of each image's first pixel: the levels' common buffer if they are views of one
    C-contiguous array with the same stride (the stacked pyramid), else a stacked copy."""
    base = images[0].base
    if (isinstance(base, np.ndarray) and base.ndim == 2 and base.dtype == np.uint8 and base.flags.c_contiguous
            and base.flags.writeable and all(im.base is base and im.strides == (base.shape[1], 1) for im in images)):
        start = base.__array_interface__["data"][0]
        origins = [im.__array_interface__["data"][0] - start for im in images]
        return base.reshape(-1), base.shape[1], np.array(origins, np.int64)
    width = max(im.shape[1] for im in images)
    rows = np.cumsum([0] + [im.shape[0] for im in images])
    stacked = np.zeros((max(int(rows[-1]), 1), max(width, 1)), np.uint8)
    for im, r in zip(images, rows):
        stacked[r:r + im.shape[0], :im.shape[1]] = im
    return stacked.reshape(-1), stacked.shape[1], rows[:-1].astype(np.int64) * stacked.shape[1]


def _stacked_maps(masks: list[MaskSampler] | None, sizes: list[tuple[int, int]]
                  ) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """The mask and the levels' regions' row / column maps, concatenated, with where each
    level's maps start (one array each for the single compiled call). Samplers of
    different masks are materialised into one stacked mask."""
    first = np.zeros((len(sizes), 2), np.int64)
    if masks is None:
        return _NO_MASK.mask, _NO_MASK.rows, _NO_MASK.cols, first
    crops = [m.crop(BORDER, BORDER, w, h) for m, (w, h) in zip(masks, sizes)]
    mask = crops[0].mask
    if any(c.mask is not mask for c in crops):
        dense = [c.image() for c in crops]
        offsets = np.cumsum([0] + [d.shape[0] for d in dense])
        mask = np.zeros((max(int(offsets[-1]), 1), max(max(d.shape[1] for d in dense), 1)), np.uint8)
        for d, o in zip(dense, offsets):
            mask[o:o + d.shape[0], :d.shape[1]] = d
        crops = [MaskSampler(mask, o + np.arange(d.shape[0], dtype=np.int64), np.arange(d.shape[1], dtype=np.int64))
                 for d, o in zip(dense, offsets)]
    first[1:, 0] = np.cumsum([len(c.rows) for c in crops])[:-1]
    first[1:, 1] = np.cumsum([len(c.cols) for c in crops])[:-1]
    rows = np.concatenate([c.rows for c in crops]).astype(np.int64)
    cols = np.concatenate([c.cols for c in crops]).astype(np.int64)
    return kernel_array(mask, np.uint8), rows, cols, first


def detect_level(image: NDArray[np.uint8], fast_threshold: int, fast_min_threshold: int,
                 mask: NDArray[np.uint8] | None = None) -> Detected:
    """``detect_levels`` for one level: x, y (distribution frame) and scores."""
    if detection_region(image) is None:
        return EMPTY_DETECTION
    sampler = None if mask is None else MaskSampler.same_size(mask)
    x, y, r, _ = detect_levels([image], fast_threshold, fast_min_threshold,
                               None if sampler is None else [sampler])
    return x, y, r


def detect_level_reference(image: NDArray[np.uint8], fast_threshold: int, fast_min_threshold: int,
                           mask: NDArray[np.uint8] | None = None
                           ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """Literal ORB-SLAM ``ComputeKeyPointsOctTree`` detection (FAST per cell ROI, again
    with the low threshold where empty). Slow (two FAST calls per cell); kept to check
    ``detect_level`` against. Same outputs as ``detect_level``."""
    region = detection_region(image)
    if region is None:
        return EMPTY_DETECTION
    width, height = region
    hi = cv2.FastFeatureDetector_create(fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    lo = cv2.FastFeatureDetector_create(fast_min_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    grid = cell_grid(width, height)
    h, w = image.shape
    min_b, max_bx, max_by = BORDER, w - BORDER, h - BORDER
    xs, ys, rs = [], [], []
    for i in range(grid.n_rows):
        ini_y = min_b + i * grid.h_cell
        max_y = min(ini_y + grid.h_cell + 6, max_by)
        if ini_y >= max_by - 3:
            continue
        for j in range(grid.n_cols):
            ini_x = min_b + j * grid.w_cell
            max_x = min(ini_x + grid.w_cell + 6, max_bx)
            if ini_x >= max_bx - 6:
                continue
            roi = image[ini_y:max_y, ini_x:max_x]
            mroi = None if mask is None else mask[ini_y:max_y, ini_x:max_x]
            cx, cy, cr = fast_points_cv2(hi, roi, mroi)
            if len(cx) == 0:
                cx, cy, cr = fast_points_cv2(lo, roi, mroi)
            xs.append(cx + j * grid.w_cell)
            ys.append(cy + i * grid.h_cell)
            rs.append(cr)
    if not xs:
        return EMPTY_DETECTION
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(rs)


def detection_levels(levels: list[NDArray[np.uint8]]) -> list[NDArray[np.uint8]]:
    """The levels up to the first one without a detection region (ORB-SLAM stops there)."""
    images: list[NDArray[np.uint8]] = []
    for image in levels:
        if detection_region(image) is None:
            break
        images.append(image)
    return images


def region_sizes(images: list[NDArray[np.uint8]]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Widths and heights of the levels' distribution frames (the quadtree's root size)."""
    widths = np.array([im.shape[1] - 2 * BORDER for im in images])
    heights = np.array([im.shape[0] - 2 * BORDER for im in images])
    return widths, heights
