"""STDC-SLAM's Algorithm 2 (two-threshold FAST detection) for the improved Qtree-ORB
extractor (``semslam.features.qtree_orb``, whose module doc gives the choices made where
the paper is vague).

``detect_two_thresholds`` runs it for all levels in one compiled call
(``semslam.features.orb.detect_levels_two_thresholds``); ``detect_two_thresholds_numpy``
is the numpy version it replaced (one FAST call per level and pass, the cell prefix and
the ordering in numpy), kept as the reference: same points, scores, order and counts
(tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.features.orb import (
    BORDER,
    MaskSampler,
    Scratch,
    cell_grid,
    detect_levels_two_thresholds,
    detection_region,
    fast_points,
)

__all__ = ["Detection", "detect_two_thresholds", "detect_two_thresholds_numpy"]


@dataclass
class Detection:
    """Candidates of all levels, level by level in ORB-SLAM's order (cell by cell,
    row-major inside a cell): x, y in each level's distribution frame (level pixels -
    EDGE_THRESHOLD + 3), FAST score, quality (True = in ``P^H``) and level; per level
    ``|P^H|`` and ``|P^L|`` (the low points actually inserted)."""

    x: NDArray[np.int64]
    y: NDArray[np.int64]
    score: NDArray[np.float32]
    high: NDArray[np.bool_]
    level: NDArray[np.int64]
    n_high: NDArray[np.int64]
    n_low: NDArray[np.int64]


def _check_regions(images: list[NDArray[np.uint8]]) -> None:
    for image in images:
        assert detection_region(image) is not None, "levels without a detection region must be left out"


def detect_two_thresholds(images: list[NDArray[np.uint8]], n_wanted: NDArray[np.integer],
                          fast_threshold: int, fast_min_threshold: int,
                          masks: list[MaskSampler] | None = None, scratch: Scratch | None = None) -> Detection:
    """Algorithm 2 on every level: ``P^H`` = FAST at ``T_H`` (``fast_threshold``) on all
    cells; if ``|P^H| < N_i``, insert the cells' low points (FAST at ``T_L``, score <
    ``T_H``) cell by cell in raster order until ``|P^H| + |P^L| >= N_i``. Levels must all
    have a detection region; ``masks``: one per level (``level_mask_samplers``). One
    compiled call; the same result as ``detect_two_thresholds_numpy``."""
    _check_regions(images)
    return Detection(*detect_levels_two_thresholds(images, n_wanted, fast_threshold, fast_min_threshold, masks,
                                                   scratch))


def detect_two_thresholds_numpy(images: list[NDArray[np.uint8]], n_wanted: NDArray[np.integer],
                                fast_threshold: int, fast_min_threshold: int,
                                masks: list[MaskSampler] | None = None, scratch: Scratch | None = None
                                ) -> Detection:
    """``detect_two_thresholds`` with the per-level loop in Python and numpy (the
    reference the compiled version is tested against)."""
    _check_regions(images)
    scratch = scratch or Scratch()
    t_high = np.float32(fast_threshold)
    xs, ys, ss, hs, cells = [], [], [], [], []
    n_high = np.zeros(len(images), np.int64)
    n_low = np.zeros(len(images), np.int64)
    level_first_cell = []
    cell_base = 0
    for level, image in enumerate(images):
        width, height = detection_region(image)  # type: ignore[misc]
        crop = image[BORDER:BORDER + height, BORDER:BORDER + width]
        cmask = None if masks is None else masks[level].crop(BORDER, BORDER, width, height)
        grid = cell_grid(width, height)
        x, y, s = fast_points(crop, fast_threshold, cmask, scratch)
        n_high[level] = len(x)
        xs.append(x)
        ys.append(y)
        ss.append(s)
        hs.append(np.ones(len(x), bool))
        cells.append(grid.cell_of(x, y) + cell_base)
        deficit = int(n_wanted[level]) - len(x)
        if deficit > 0:
            lx, ly, ls = fast_points(crop, fast_min_threshold, cmask, scratch)
            low = ls < t_high  # the others are exactly P^H again
            lx, ly, ls = lx[low], ly[low], ls[low]
            lcell = grid.cell_of(lx, ly)
            per_cell = np.bincount(lcell, minlength=grid.n_cells)
            # Cell j is inserted iff the check after cell j-1 had not reached N_i.
            before = np.cumsum(per_cell) - per_cell
            take = (before < deficit)[lcell]
            n_low[level] = int(take.sum())
            xs.append(lx[take])
            ys.append(ly[take])
            ss.append(ls[take])
            hs.append(np.zeros(int(take.sum()), bool))
            cells.append(lcell[take] + cell_base)
        level_first_cell.append(cell_base)
        cell_base += grid.n_cells
    x, y, score = np.concatenate(xs), np.concatenate(ys), np.concatenate(ss)
    high, cell = np.concatenate(hs), np.concatenate(cells)
    # ORB-SLAM's order, (cell, y, x) as one integer key; cells are numbered level by level.
    side = np.int64(max(max(im.shape) for im in images))
    order = np.argsort((cell * side + y) * side + x, kind="stable")
    cell = cell[order]
    level = np.searchsorted(np.array(level_first_cell), cell, side="right") - 1
    return Detection(x[order], y[order], score[order], high[order], level.astype(np.int64), n_high, n_low)
