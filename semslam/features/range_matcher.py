"""SDF-SLAM's range matcher (Yang et al. 2022, Fig. 4 and eq. 8).

For each keypoint of the first image, the candidates are the second image's keypoints in
a square of side ``window_px`` = 140 px centred on it (|dx| <= 70 and |dy| <= 70, border
included); the match is the candidate with the smallest L2 descriptor distance (eq. 8).
A query with no candidate in its window has no match.

Eq. 8 says nothing else, so nothing else is checked by default: several queries may take
the same train point, there is no distance limit, no ratio test and no mutual check.
``ratio`` (Lowe's test against the second-nearest candidate in the window) and ``mutual``
(the train point's nearest query in its own window must be this query) are optional. The
paper's Table 6 counts show its matcher rejected matches as ``mutual`` does, so Table 6's
target is judged with it (``eval.feature_eval``); the ``sdf`` tracker keeps it off, where
PnP-RANSAC removes wrong matches and the check measured no better (README).

Vectorised: the query x train distance matrix is computed by blocks of queries with one
matrix product (``L2Matcher.distance_matrix``), pairs outside the window are set to
infinity, and the row minimum is the match (ties: the lowest train index, as
``np.argmin``). For the paper's 500 x 500 points this is one 2 MB block.

The class also implements the ``Matcher`` protocol for L2 descriptors (distances, search
by candidates, brute force: delegated to ``L2Matcher``), so a tracker that selects it with
``features.matcher: range`` keeps every other search it does.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.features.matching import L2Matcher, Matches

__all__ = ["WINDOW_PX", "RangeMatcher"]

WINDOW_PX = 140.0  # side of the square search window (SDF-SLAM IV-B)


class RangeMatcher(L2Matcher):
    """Eq. 8's nearest descriptor within a ``window_px`` square around each query point."""

    _ROWS = 1024  # query rows per dense block

    def __init__(self, window_px: float = WINDOW_PX, ratio: float | None = None, mutual: bool = False) -> None:
        if not window_px > 0:
            raise ValueError(f"range matcher: window_px must be > 0, got {window_px}")
        if ratio is not None and not 0 < ratio <= 1:
            raise ValueError(f"range matcher: ratio must be in (0, 1], got {ratio}")
        self.window_px = float(window_px)
        self.ratio = ratio
        self.mutual = bool(mutual)

    def window_distances(self, xy_q: NDArray[np.floating], desc_q: NDArray[np.floating],
                         xy_t: NDArray[np.floating], desc_t: NDArray[np.floating]) -> NDArray[np.float64]:
        """L2 distances (len(q) x len(t)); inf where the train point is outside the window."""
        half = self.window_px / 2.0
        xy_q, xy_t = np.asarray(xy_q, np.float64), np.asarray(xy_t, np.float64)
        out = np.full((len(xy_q), len(xy_t)), np.inf)
        for i in range(0, len(xy_q), self._ROWS):
            j = min(i + self._ROWS, len(xy_q))
            diff = np.abs(xy_q[i:j, None, :] - xy_t[None, :, :])
            inside = (diff[..., 0] <= half) & (diff[..., 1] <= half)
            block = self.distance_matrix(desc_q[i:j], desc_t)
            out[i:j] = np.where(inside, block, np.inf)
        return out

    def match(self, xy_q: NDArray[np.floating], desc_q: NDArray[np.floating],
              xy_t: NDArray[np.floating], desc_t: NDArray[np.floating]) -> Matches:
        """(query indices, train indices, L2 distances) of eq. 8's matches, by query index."""
        if len(xy_q) == 0 or len(xy_t) == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.float64)
        dist = self.window_distances(xy_q, desc_q, xy_t, desc_t)
        rows = np.arange(len(dist))
        best = np.argmin(dist, axis=1)
        best_d = dist[rows, best]
        ok = np.isfinite(best_d)
        if self.ratio is not None:
            second = np.partition(dist, 1, axis=1)[:, 1] if dist.shape[1] > 1 else np.full(len(dist), np.inf)
            ok &= best_d < self.ratio * second
        if self.mutual:
            ok &= np.argmin(dist, axis=0)[best] == rows
        return rows[ok].astype(np.intp), best[ok].astype(np.intp), best_d[ok]
