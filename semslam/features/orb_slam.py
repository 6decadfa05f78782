"""ORB extraction as ORB-SLAM2/3 does it (``ORBextractor.cc``), vectorised with numpy and
OpenCV: scale pyramid, FAST per ~30 px cell with a lower threshold for empty cells,
quadtree distribution, intensity-centroid orientation, steered rBRIEF on the blurred
level image.

Why not ``cv2.ORB``: OpenCV keeps the strongest Harris responses over the whole image,
which clusters keypoints on texture; ORB-SLAM's cells + quadtree spread them over the
image, which is what tracking and pose estimation need.

Stages and where they differ from ORB-SLAM (all else is meant to be identical):
- pyramid: ``semslam.features.pyramid`` (each level resized from the previous one as
  in ORB-SLAM; all levels in one reused buffer with 3 px of reflect padding for the
  blur, instead of ORB-SLAM's EDGE_THRESHOLD padding that nothing reads);
- detection: ORB-SLAM runs FAST (9-16, non-max suppression) on every ~30 px cell ROI,
  again with ``fast_min_threshold`` where nothing was found. We run FAST at
  ``fast_threshold`` once on each level's whole detection region and assign the
  keypoints to ORB-SLAM's cells with integer arithmetic (``ceil``-sized cells, 3 px FAST
  margin, same clipping: the cells' detection ranges tile the region exactly), then run
  FAST at ``fast_min_threshold`` on ORB-SLAM's own ROI of each cell left empty. Why
  this split: FAST costs ~0.3 us per corner found and little per pixel (~0.4 ms for all
  levels) or per call (~2 us), so one low-threshold pass over everything costs 2-3x
  more on textured frames, and one call per cell for the first pass costs ~3 ms of
  Python loop. The one difference to ORB-SLAM is in that first pass: its per-cell
  non-max suppression cannot see a stronger neighbour across a cell boundary (scores
  outside the ROI are 0), ours can, so a few corners on cell boundaries next to a
  stronger one in the next cell are suppressed here (and a cell whose only corners are
  such is treated as empty). ``detect_level_reference`` is the literal per-cell
  version; on the real 640x480 test frames 97-98 % of the extracted keypoints are
  identical (tests and ``benchmarks/extractor_timing.py``). Related fact, checked on
  the test frames: FAST's score does not depend on the threshold and a pixel is a
  corner at threshold t iff its score is >= t;
- mask: FAST's own mask (applied after its non-max suppression) so masked corners
  neither count for a cell nor reach the quadtree and the budget goes to allowed pixels;
- quadtree: ``semslam.features.quadtree`` (ties between equal-sized nodes broken by
  position instead of heap address);
- orientation: ``IC_Angle`` with ORB-SLAM's ``umax`` circle, as one gather + matmul
  for all levels (levels stacked in one buffer, ``pyramid.StackedPyramid``);
  ``cv2.phase`` gives OpenCV's ``fastAtan2`` (what ORB-SLAM calls);
- descriptors: ORB-SLAM's ``computeOrbDescriptor`` (pattern ``bit_pattern_31_`` from
  OpenCV's orb.cpp, the learned rBRIEF test pairs, round-half-even like ``cvRound``)
  as one gather for all levels; the 7x7 sigma-2 blur is one call on the stacked
  levels, each padded with BORDER_REFLECT_101 (identical to blurring each level on its
  own as ORB-SLAM does); bit ``k`` of byte ``i`` is test ``8 i + k``.
"""

from __future__ import annotations

import functools
import math
import time

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.features.base import Keypoints, register_extractor
from semslam.features.pyramid import (
    EDGE_THRESHOLD,
    HALF_PATCH_SIZE,
    build_pyramid,
    features_per_level,
    inv_level_sigma2,
    level_mask,
    level_sigma2,
    scale_factors,
)
from semslam.features.quadtree import distribute_quadtree_levels

__all__ = [
    "CELL_SIZE", "OrbSlamExtractor", "Scratch", "detect_level", "detect_level_reference", "detect_levels",
    "features_per_level", "ic_angles", "inv_level_sigma2", "level_sigma2", "orb_descriptors", "scale_factors",
]

CELL_SIZE = 30  # ORB-SLAM's W: side of the FAST cells in level pixels
_BORDER = EDGE_THRESHOLD - 3  # ORB-SLAM's minBorderX: FAST's own 3 px margin inside it
_STAGES = ("pyramid", "fast_cells", "quadtree", "orientation", "blur", "descriptors")

# ORB's learned 256 test pairs for a 31x31 patch (OpenCV orb.cpp ``bit_pattern_31_``,
# BSD licence, copied by ORB-SLAM), as x1,y1, x2,y2 per test.
_BIT_PATTERN_31 = np.array([
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


def _umax() -> NDArray[np.int64]:
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
    umax = _umax()
    w = np.zeros((PATCH, PATCH, 2), np.float32)
    for v in range(-HALF_PATCH_SIZE, HALF_PATCH_SIZE + 1):
        d = int(umax[abs(v)])
        u = np.arange(-d, d + 1)
        w[v + HALF_PATCH_SIZE, u + HALF_PATCH_SIZE, 0] = u
        w[v + HALF_PATCH_SIZE, u + HALF_PATCH_SIZE, 1] = v
    return w.reshape(PATCH * PATCH, 2)


PATCH = 2 * HALF_PATCH_SIZE + 1
_MOMENT_WEIGHTS = _moment_weights()
# Rotated pattern x' = x a - y b, y' = x b + y a as one (N,2) @ (2,512) product each.
_PAT_X_ROT = np.stack([_BIT_PATTERN_31[:, 0], -_BIT_PATTERN_31[:, 1]]).astype(np.float32)
_PAT_Y_ROT = np.stack([_BIT_PATTERN_31[:, 1], _BIT_PATTERN_31[:, 0]]).astype(np.float32)
_ROUND_MAGIC = np.float32(1.5 * 2**23)  # x + M in float32 rounds half-to-even (|x| < 2^22)
_ROUND_BITS = np.int32(0x4B400000)


def _rint_i32(v: NDArray[np.float32]) -> NDArray[np.int32]:
    """Round-half-to-even to int32 (``cvRound``), in place, with one add and one
    reinterpretation: about 3x faster than ``np.rint(v).astype(np.int32)``."""
    v += _ROUND_MAGIC
    out = v.view(np.int32)
    out -= _ROUND_BITS
    return out


class Scratch:
    """Work buffers reused from call to call (grown as needed). Why: on this machine a
    fresh multi-MB numpy array costs more in page faults than the arithmetic on it."""

    def __init__(self) -> None:
        self._bufs: dict[str, NDArray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type) -> NDArray:
        size = int(np.prod(shape))
        buf = self._bufs.get(name)
        if buf is None or buf.size < size or buf.dtype != dtype:
            buf = np.empty(max(size, 2 * buf.size if buf is not None else size), dtype)
            self._bufs[name] = buf
        return buf[:size].reshape(shape)


_IC_CHUNK = 128  # keypoints per window copy (keeps the temporaries small and in cache)


def ic_angles(image: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
              scratch: Scratch | None = None) -> NDArray[np.float32]:
    """ORB-SLAM's ``IC_Angle`` for keypoints at integer pixels (at least 15 px from the
    border): the direction in degrees [0, 360) of the intensity centroid of the circular
    patch, ``fastAtan2(m01, m10)``. Why: it makes BRIEF rotation-invariant.

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


def orb_descriptors(blurred: NDArray[np.uint8], x: NDArray[np.integer], y: NDArray[np.integer],
                    angle_deg: NDArray[np.floating], scratch: Scratch | None = None) -> NDArray[np.uint8]:
    """ORB-SLAM's ``computeOrbDescriptor``: 256 intensity tests of the pattern rotated by
    the keypoint angle on the blurred image, packed 8 per byte, least significant bit
    first. Keypoints must be at least 19 px (EDGE_THRESHOLD) from the border.

    Vectorised: rotated offsets as two (N,2) @ (2,512) products, rounded half-to-even
    like ``cvRound``, one flat gather; all temporaries in reused buffers."""
    n = len(x)
    if n == 0:
        return np.zeros((0, 32), np.uint8)
    scratch = scratch or Scratch()
    img = np.ascontiguousarray(blurred)
    stride = img.shape[1]
    rad = np.asarray(angle_deg, np.float32) * np.float32(math.pi / 180.0)
    ab = np.empty((n, 2), np.float32)
    np.cos(rad, out=ab[:, 0])  # a
    np.sin(rad, out=ab[:, 1])  # b
    col = _rint_i32(np.matmul(ab, _PAT_X_ROT, out=scratch.get("d_col", (n, 512), np.float32)))
    row = _rint_i32(np.matmul(ab, _PAT_Y_ROT, out=scratch.get("d_row", (n, 512), np.float32)))
    row *= np.int32(stride)
    row += col
    flat = scratch.get("d_flat", (n, 512), np.intp)
    np.add(row, (np.asarray(y, np.intp) * stride + np.asarray(x, np.intp))[:, None], out=flat)
    vals = np.take(img.reshape(-1), flat, out=scratch.get("d_vals", (n, 512), np.uint8))
    bits = np.less(vals[:, 0::2], vals[:, 1::2], out=scratch.get("d_bits", (n, 256), np.bool_))
    return np.packbits(bits, axis=1, bitorder="little")


def _fast(detector: cv2.FastFeatureDetector, image: NDArray[np.uint8], mask: NDArray[np.uint8] | None
          ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """FAST keypoints as integer x, y and float32 score arrays (row-major order)."""
    kps = detector.detect(image, mask)
    if not kps:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    pts = cv2.KeyPoint_convert(kps).astype(np.int64)  # FAST positions are integers
    resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
    return pts[:, 0], pts[:, 1], resp


class _CellGrid:
    """ORB-SLAM's FAST cells of one level, in distribution coordinates (level pixels
    minus ``EDGE_THRESHOLD - 3``). Cell (i, j) has the ROI ``[i hCell, min(i hCell +
    hCell + 6, height))`` x (likewise for columns) and, FAST keeping 3 px off the ROI
    border, detects in ``[i hCell + 3, min(...) - 3)``; these ranges tile
    ``[3, width - 3) x [3, height - 3)``. Use ``_cell_grid`` (cached per size)."""

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
def _cell_grid(width: int, height: int) -> _CellGrid:
    return _CellGrid(width, height)


def _detection_region(image: NDArray[np.uint8]) -> tuple[int, int] | None:
    """(width, height) of the distribution frame, None where the level is too small
    (ORB-SLAM stops at the first such level)."""
    h, w = image.shape
    width, height = w - 2 * _BORDER, h - 2 * _BORDER
    if width <= 0 or height <= 0:
        return None
    return width, height


_EMPTY_DETECTION = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


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
        width, height = _detection_region(image) or (0, 0)
        crop = image[_BORDER:_BORDER + height, _BORDER:_BORDER + width]
        mask = None if masks is None else masks[level]
        cmask = None if mask is None else mask[_BORDER:_BORDER + height, _BORDER:_BORDER + width]
        x, y, r = _fast(fast_hi, crop, cmask)
        grid = _cell_grid(width, height)
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
    if _detection_region(image) is None:
        return _EMPTY_DETECTION
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
    region = _detection_region(image)
    if region is None:
        return _EMPTY_DETECTION
    width, height = region
    hi = cv2.FastFeatureDetector_create(fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    lo = cv2.FastFeatureDetector_create(fast_min_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    grid = _cell_grid(width, height)
    h, w = image.shape
    min_b, max_bx, max_by = _BORDER, w - _BORDER, h - _BORDER
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
            cx, cy, cr = _fast(hi, roi, mroi)
            if len(cx) == 0:
                cx, cy, cr = _fast(lo, roi, mroi)
            xs.append(cx + j * grid.w_cell)
            ys.append(cy + i * grid.h_cell)
            rs.append(cr)
    if not xs:
        return _EMPTY_DETECTION
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(rs)



def check_extractor_inputs(gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None
                           ) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """A uint8 grey image (colour is converted) and a uint8 mask of the same size, or an error."""
    gray = np.asarray(gray)
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY if gray.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise ValueError(f"expected a uint8 grey image, got {gray.dtype} {gray.shape}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gray.shape:
            raise ValueError(f"mask shape {mask.shape} differs from the image's {gray.shape}")
        mask = np.ascontiguousarray(mask) if mask.dtype == np.uint8 else (mask != 0).view(np.uint8)
    return gray, mask

class OrbSlamExtractor:
    """ORB-SLAM2/3's ORB extractor (defaults: 1000 features, 8 levels x 1.2, FAST 20/7).

    ``extract(gray, mask)`` returns keypoints level by level (ORB-SLAM's output order),
    positions in level-0 pixels (``level pixel * s^level``, float32), ``octave`` = level,
    FAST score as response, angle in degrees, 32-byte descriptors. ``mask`` (same size,
    0 = forbidden) drops keypoints whose nearest level-0 pixel is forbidden before the
    distribution, so the budget still goes to allowed pixels.

    ``reference_detection=True`` uses the literal (slow) per-cell FAST of ORB-SLAM."""

    def __init__(self, n_features: int = 1000, scale_factor: float = 1.2, n_levels: int = 8,
                 fast_threshold: int = 20, fast_min_threshold: int = 7, reference_detection: bool = False) -> None:
        if n_levels < 1 or scale_factor <= 1.0 or n_features < 0:
            raise ValueError("need n_levels >= 1, scale_factor > 1 and n_features >= 0")
        self.n_features = int(n_features)
        self.scale_factor = float(scale_factor)
        self.n_levels = int(n_levels)
        self.fast_threshold = int(fast_threshold)
        self.fast_min_threshold = int(fast_min_threshold)
        self.reference_detection = reference_detection
        self.scale_factors = scale_factors(self.n_levels, self.scale_factor)
        self.level_sigma2 = level_sigma2(self.n_levels, self.scale_factor)
        self.inv_level_sigma2 = inv_level_sigma2(self.n_levels, self.scale_factor)
        self.features_per_level = features_per_level(self.n_features, self.n_levels, self.scale_factor)
        self._fast_hi = cv2.FastFeatureDetector_create(self.fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
        self._fast_lo = cv2.FastFeatureDetector_create(self.fast_min_threshold, True,
                                                       cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
        # Reused from frame to frame (an extractor is not meant to be shared by threads).
        self._scratch = Scratch()
        self._pyramid_buffer: NDArray[np.uint8] | None = None
        self._blur_buffer: NDArray[np.uint8] | None = None
        # Wall time of each stage of the last extract() (ms), for profiling.
        self.last_stage_ms: dict[str, float] = {}

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        gray, mask = check_extractor_inputs(gray, mask)
        if gray.size == 0 or self.n_features == 0:
            return Keypoints.empty()

        clock = [time.perf_counter()]
        pyr = build_pyramid(gray, self.n_levels, self.scale_factor, pad=3, buffer=self._pyramid_buffer)
        self._pyramid_buffer = pyr.buffer
        clock.append(time.perf_counter())
        # Levels with a detection region (ORB-SLAM stops at the first one without).
        images: list[NDArray[np.uint8]] = []
        for image in pyr.levels:
            if _detection_region(image) is None:
                break
            images.append(image)
        n_used = len(images)
        if n_used == 0:
            return Keypoints.empty()
        masks = None if mask is None else [
            mask if level == 0 else level_mask(mask, image.shape, self.scale_factors[level])
            for level, image in enumerate(images)]
        if self.reference_detection:
            found = [detect_level_reference(image, self.fast_threshold, self.fast_min_threshold,
                                            None if masks is None else masks[level])
                     for level, image in enumerate(images)]
            x, y, resp = (np.concatenate([f[i] for f in found]) for i in range(3))
            level = np.concatenate([np.full(len(f[0]), lvl, np.int64) for lvl, f in enumerate(found)])
        else:
            x, y, resp, level = detect_levels(images, self._fast_hi, self._fast_lo, masks)
        widths = np.array([im.shape[1] - 2 * _BORDER for im in images])
        heights = np.array([im.shape[0] - 2 * _BORDER for im in images])
        clock.append(time.perf_counter())
        keep = distribute_quadtree_levels(x, y, resp, level, widths, heights, self.features_per_level[:n_used])
        clock.append(time.perf_counter())
        if len(keep) == 0:
            return Keypoints.empty()
        kx, ky, klv = x[keep] + _BORDER, y[keep] + _BORDER, level[keep]

        # All levels live in one buffer: one gather for the orientations, one blur (pad 3
        # = the 7x7 kernel's radius, BORDER_REFLECT_101 like ORB-SLAM) and one gather for
        # the descriptors.
        sx, sy = kx + pyr.pad, ky + pyr.rows[klv]
        angle = ic_angles(pyr.buffer, sx, sy, self._scratch)
        clock.append(time.perf_counter())
        if self._blur_buffer is None or self._blur_buffer.shape != pyr.buffer.shape:
            self._blur_buffer = np.empty_like(pyr.buffer)
        blurred = cv2.GaussianBlur(pyr.buffer, (7, 7), 2, dst=self._blur_buffer, sigmaY=2,
                                   borderType=cv2.BORDER_REFLECT_101)
        clock.append(time.perf_counter())
        desc = orb_descriptors(blurred, sx, sy, angle, self._scratch)
        scale = self.scale_factors.astype(np.float32)[klv]
        xy = np.stack([kx, ky], axis=1).astype(np.float32) * scale[:, None]
        clock.append(time.perf_counter())
        self.last_stage_ms = dict(zip(_STAGES, (1e3 * np.diff(clock)).tolist()))
        return Keypoints(xy=xy, octave=klv.astype(np.int32), response=resp[keep].astype(np.float32),
                         angle=angle.astype(np.float32), descriptors=desc)


@register_extractor("orb_slam")
def _make(cfg: FeatureConfig) -> OrbSlamExtractor:
    return OrbSlamExtractor(cfg.n_features, cfg.scale_factor, cfg.n_levels, cfg.fast_threshold, cfg.fast_min_threshold)
