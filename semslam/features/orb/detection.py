"""ORB-SLAM's FAST detection: the detection region of a level, its ~30 px cells, FAST at
a high threshold with a low-threshold retry in empty cells (``ComputeKeyPointsOctTree``).

Shared by ORB-SLAM2's extractor (``detect_levels``) and STDC-SLAM's Qtree-ORB (which
uses the cell grid and ``fast_points`` for its own two-threshold Algorithm 2); see
``semslam.features.orb_slam2`` for the one difference to ORB-SLAM.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.pyramid import EDGE_THRESHOLD

__all__ = ["BORDER", "CELL_SIZE", "CellGrid", "EMPTY_DETECTION", "cell_grid", "detect_level",
           "detect_level_reference", "detect_levels", "detection_levels", "detection_region",
           "fast_points", "region_sizes"]

CELL_SIZE = 30  # ORB-SLAM's W: side of the FAST cells in level pixels
BORDER = EDGE_THRESHOLD - 3  # ORB-SLAM's minBorderX: FAST's own 3 px margin inside it


def fast_points(detector: cv2.FastFeatureDetector, image: NDArray[np.uint8],
                mask: NDArray[np.uint8] | None
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """FAST keypoints as integer x, y and float32 score arrays (row-major order)."""
    kps = detector.detect(image, mask)
    if not kps:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    pts = cv2.KeyPoint_convert(kps).astype(np.int64)  # FAST positions are integers
    resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
    return pts[:, 0], pts[:, 1], resp


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


def detect_levels(images: list[NDArray[np.uint8]], fast_hi: cv2.FastFeatureDetector,
                  fast_lo: cv2.FastFeatureDetector, masks: list[NDArray[np.uint8] | None] | None = None
                  ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], NDArray[np.int64]]:
    """FAST candidates of all levels, level by level in ORB-SLAM's order (cell by cell,
    row-major inside a cell): x, y in each level's distribution frame (level pixels -
    EDGE_THRESHOLD + 3), scores and levels. ``fast_hi`` / ``fast_lo`` run at
    ``fast_threshold`` / ``fast_min_threshold``; levels without a detection region must
    have been left out by the caller.

    ``fast_hi`` runs once on each level's whole detection region and its keypoints are
    assigned to ORB-SLAM's cells; ``fast_lo`` then runs on ORB-SLAM's own ROI of each
    cell left empty, exactly as ORB-SLAM does. Why: FAST costs ~0.3 us per corner found
    but little per pixel or per call, so the low threshold is only paid where it is
    used. See the module doc for the one difference (non-max suppression across cell
    boundaries in the first pass)."""
    xs, ys, rs, cells = [], [], [], []
    cell_base = 0
    level_first_cell = []
    lo_kps: list[cv2.KeyPoint] = []
    lo_meta: list[tuple[int, int, int, int]] = []  # (count, x offset, y offset, global cell)
    for level, image in enumerate(images):
        width, height = detection_region(image) or (0, 0)
        crop = image[BORDER:BORDER + height, BORDER:BORDER + width]
        mask = None if masks is None else masks[level]
        cmask = None if mask is None else mask[BORDER:BORDER + height, BORDER:BORDER + width]
        x, y, r = fast_points(fast_hi, crop, cmask)
        grid = cell_grid(width, height)
        cell = grid.cell_of(x, y)
        empty = (np.bincount(cell, minlength=grid.n_cells) == 0) & grid.has_region
        for c in np.flatnonzero(empty).tolist():
            rows, cols = grid.rois[c]  # ORB-SLAM's cell ROI, distribution frame
            kps = fast_lo.detect(crop[rows, cols], None if cmask is None else cmask[rows, cols])
            if kps:
                lo_kps.extend(kps)
                lo_meta.append((len(kps), cols.start, rows.start, cell_base + c))
        xs.append(x)
        ys.append(y)
        rs.append(r)
        cells.append(cell + cell_base)
        level_first_cell.append(cell_base)
        cell_base += grid.n_cells
    if lo_kps:
        # One conversion for all cells' low-threshold keypoints.
        meta = np.array(lo_meta, np.int64)
        pts = cv2.KeyPoint_convert(lo_kps).astype(np.int64)
        xs.append(pts[:, 0] + np.repeat(meta[:, 1], meta[:, 0]))
        ys.append(pts[:, 1] + np.repeat(meta[:, 2], meta[:, 0]))
        rs.append(np.fromiter((k.response for k in lo_kps), np.float32, len(lo_kps)))
        cells.append(np.repeat(meta[:, 3], meta[:, 0]))
    x, y, resp, cell = np.concatenate(xs), np.concatenate(ys), np.concatenate(rs), np.concatenate(cells)
    # Sort by (cell, y, x) with one integer key (np.lexsort is ~10x slower); cells are
    # numbered level by level, so this also sorts by level.
    side = np.int64(max(max(im.shape) for im in images))
    order = np.argsort((cell * side + y) * side + x)
    cell = cell[order]
    level = np.searchsorted(np.array(level_first_cell), cell, side="right") - 1
    return x[order], y[order], resp[order], level


def detect_level(image: NDArray[np.uint8], fast_threshold: int, fast_min_threshold: int,
                 mask: NDArray[np.uint8] | None = None
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """``detect_levels`` for one level: x, y (distribution frame) and scores."""
    if detection_region(image) is None:
        return EMPTY_DETECTION
    hi = cv2.FastFeatureDetector_create(fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    lo = cv2.FastFeatureDetector_create(fast_min_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    x, y, r, _ = detect_levels([image], hi, lo, [mask])
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
            cx, cy, cr = fast_points(hi, roi, mroi)
            if len(cx) == 0:
                cx, cy, cr = fast_points(lo, roi, mroi)
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
