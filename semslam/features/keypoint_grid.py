"""Keypoints bucketed in a coarse image grid for radius queries (ORB-SLAM's 64 x 48
``mGrid`` and ``GetFeaturesInArea``), with a compiled kernel that returns every
(query, keypoint) pair within each query's radius whose pyramid level is in the query's
window and whose keypoint is free.

Why not a KD-tree: ``cKDTree.query_ball_point`` answers with one Python list per query,
and turning ~1500 lists into index arrays cost more than the search itself.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

GRID_COLS = 64
GRID_ROWS = 48


@numba.njit(cache=True, nogil=True)
def _cells(xy: NDArray[np.float64], cell_w: float, cell_h: float, n_cols: int, n_rows: int
           ) -> NDArray[np.intp]:
    out = np.empty(len(xy), np.intp)
    for i in range(len(xy)):
        c = min(max(int(np.floor(xy[i, 0] / cell_w)), 0), n_cols - 1)
        r = min(max(int(np.floor(xy[i, 1] / cell_h)), 0), n_rows - 1)
        out[i] = r * n_cols + c
    return out


@numba.njit(cache=True, nogil=True)
def _pairs_in_radius(uv: NDArray[np.float64], radius: NDArray[np.float64], level_lo: NDArray[np.intp],
                     level_hi: NDArray[np.intp], xy: NDArray[np.float64], octave: NDArray[np.int32],
                     free: NDArray[np.bool_], order: NDArray[np.intp], start: NDArray[np.intp],
                     cell_w: float, cell_h: float, n_cols: int, n_rows: int
                     ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``xy``, ``octave`` and ``free`` are in cell order (``order[s]`` is the keypoint at
    position ``s``), so the cells of one grid row a query covers are one contiguous run."""
    cap = 16 * len(uv) + 16
    cq = np.empty(cap, np.intp)
    ct = np.empty(cap, np.intp)
    n = 0
    for q in range(len(uv)):
        u, v, r = uv[q, 0], uv[q, 1], radius[q]
        lo, hi = level_lo[q], level_hi[q]
        r2 = r * r
        c0 = min(max(int(np.floor((u - r) / cell_w)), 0), n_cols - 1)
        c1 = min(max(int(np.floor((u + r) / cell_w)), 0), n_cols - 1)
        r0 = min(max(int(np.floor((v - r) / cell_h)), 0), n_rows - 1)
        r1 = min(max(int(np.floor((v + r) / cell_h)), 0), n_rows - 1)
        for row in range(r0, r1 + 1):
            for s in range(start[row * n_cols + c0], start[row * n_cols + c1 + 1]):
                if not free[s] or octave[s] < lo or octave[s] > hi:
                    continue
                dx, dy = xy[s, 0] - u, xy[s, 1] - v
                if dx * dx + dy * dy > r2:
                    continue
                if n == cap:
                    cap *= 2
                    cq2 = np.empty(cap, np.intp)
                    ct2 = np.empty(cap, np.intp)
                    cq2[:n], ct2[:n] = cq[:n], ct[:n]
                    cq, ct = cq2, ct2
                cq[n], ct[n] = q, order[s]
                n += 1
    return cq[:n], ct[:n]


class KeypointGrid:
    """A frame's keypoints in a ``GRID_COLS x GRID_ROWS`` grid over its image (keypoints
    outside the image go to the border cells, so no query misses them)."""

    def __init__(self, xy: NDArray[np.floating], octave: NDArray[np.integer], width: float, height: float) -> None:
        self.xy = np.ascontiguousarray(xy, np.float64)
        self.octave = np.ascontiguousarray(octave, np.int32)
        self.cell_w = max(float(width), 1.0) / GRID_COLS
        self.cell_h = max(float(height), 1.0) / GRID_ROWS
        cells = _cells(self.xy, self.cell_w, self.cell_h, GRID_COLS, GRID_ROWS)
        self.order = np.argsort(cells, kind="stable").astype(np.intp)
        counts = np.bincount(cells, minlength=GRID_COLS * GRID_ROWS)
        self.start = np.zeros(GRID_COLS * GRID_ROWS + 1, np.intp)
        np.cumsum(counts, out=self.start[1:])
        # The keypoints in cell order: a query reads each grid row's cells as one run.
        self._xy_by_cell = np.ascontiguousarray(self.xy[self.order])
        self._octave_by_cell = np.ascontiguousarray(self.octave[self.order])

    def pairs_in_radius(self, uv: NDArray[np.floating], radius: NDArray[np.floating], level_lo: NDArray[np.integer],
                        level_hi: NDArray[np.integer], free: NDArray[np.bool_]
                        ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(query, keypoint) index pairs: keypoint within ``radius[q]`` pixels of ``uv[q]``
        (inclusive), level in ``[level_lo[q], level_hi[q]]``, ``free[keypoint]``."""
        if len(uv) == 0 or len(self.xy) == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        n = len(uv)
        return _pairs_in_radius(np.ascontiguousarray(uv, np.float64),
                                np.broadcast_to(np.asarray(radius, np.float64), (n,)).copy(),
                                np.broadcast_to(np.asarray(level_lo, np.intp), (n,)).copy(),
                                np.broadcast_to(np.asarray(level_hi, np.intp), (n,)).copy(),
                                self._xy_by_cell, self._octave_by_cell,
                                np.ascontiguousarray(np.asarray(free, np.bool_)[self.order]), self.order,
                                self.start, self.cell_w, self.cell_h, GRID_COLS, GRID_ROWS)


def warm_up() -> None:
    """Compile the kernels (see ``semslam.features.jit``)."""
    grid = KeypointGrid(np.array([[1.0, 1.0], [5.0, 5.0]]), np.array([0, 1], np.int32), 10, 10)
    grid.pairs_in_radius(np.array([[1.0, 1.0]]), np.array([3.0]), np.array([0]), np.array([1]), np.ones(2, bool))
