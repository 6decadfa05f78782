"""ORB-SLAM2's stereo matching of a rectified pair (``Frame::ComputeStereoMatches``).

For every left keypoint: the right keypoints of its row band (ORB-SLAM2's ``vRowIndices``:
a right keypoint covers the rows within 2 * scale of its octave) whose octave is within one
of the left's and whose column gives a disparity in [0, bf / baseline]; the one of least
descriptor distance, if under (TH_HIGH + TH_LOW) / 2 = 75, is refined by SAD of an 11 x 11
window (w = 5) at the left keypoint's pyramid level over +-5 level pixels (L = 5), the
parabola through the best three SADs gives the sub-pixel offset (|delta| > 1: rejected),
depth = bf / disparity. Last, matches whose SAD is >= 1.5 * 1.4 * the median SAD are dropped.

Deviations: ORB-SLAM2 checks the right window's bounds as ``scaleduR0 + L - w >= 0`` (a
typo for ``- L - w``); here the whole +-(L + w) range and the rows must lie in the level, so
no window reads outside the image. Unmatched keypoints get depth 0 (the project's "no
depth"), not -1; ``ur`` is -1 as in ORB-SLAM2.

The per-keypoint search is one compiled loop (numba, ``nogil``, ``cache=True``) over the
right keypoints sorted by row: a binary search gives the slice whose rows can cover the left
keypoint's row, the exact ``floor(y - r) <= row <= ceil(y + r)`` test picks from it, and
ties keep the lowest right index, as ORB-SLAM2's index-ordered scan does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from semslam.core.types import Keypoints
# The 64-bit popcount the descriptor matchers use (inlined by numba).
from semslam.features.matching_kernels import _popcount64, as_words
from semslam.features.orb.pyramid import StackedPyramid, build_pyramid, scale_factors

#: ORBmatcher::TH_HIGH, TH_LOW: the descriptor threshold is their mean.
TH_HIGH, TH_LOW = 100, 50
#: SAD window half-size and search half-range, in level pixels (ORB-SLAM2's w and L).
SAD_W, SAD_L = 5, 5


@dataclass
class StereoMatches:
    """Per left keypoint: ``ur`` the matched right column in level-0 pixels (-1: none),
    ``depth`` bf / disparity (0: none), ``right`` the matched right keypoint (-1: none),
    ``sad`` the best SAD (-1: none) and ``delta`` the parabola's sub-pixel offset in level
    pixels (0: none; ``ur - scale * delta`` is the integer-pixel match)."""

    ur: NDArray[np.float64]
    depth: NDArray[np.float32]
    right: NDArray[np.intp]
    sad: NDArray[np.int64]
    delta: NDArray[np.float64]

    @property
    def matched(self) -> NDArray[np.bool_]:
        return self.depth > 0


def stereo_pyramid(gray: NDArray[np.uint8], n_levels: int, scale_factor: float) -> StackedPyramid:
    """The image pyramid the SAD refinement reads, built as the ORB extractor builds its own
    (each level INTER_LINEAR from the previous); no padding, the windows stay inside."""
    return build_pyramid(np.ascontiguousarray(gray, np.uint8), n_levels, scale_factor, pad=0)


@numba.njit(cache=True, nogil=True)
def _window_sad(lbuf: NDArray[np.uint8], lr0: int, lc: int, rbuf: NDArray[np.uint8], rr0: int, rc: int,
                w: int) -> float:
    # Both windows minus their centre pixel (ORB-SLAM2's brightness normalisation).
    cl = float(lbuf[lr0 + w, lc + w])
    cr = float(rbuf[rr0 + w, rc + w])
    s = 0.0
    for dy in range(2 * w + 1):
        for dx in range(2 * w + 1):
            s += abs((float(lbuf[lr0 + dy, lc + dx]) - cl) - (float(rbuf[rr0 + dy, rc + dx]) - cr))
    return s


@numba.njit(cache=True, nogil=True)
def _stereo_match(lx: NDArray[np.float32], ly: NDArray[np.float32], loct: NDArray[np.int32],
                  ldesc: NDArray[np.uint64], rx: NDArray[np.float32], ry: NDArray[np.float32],
                  roct: NDArray[np.int32], rdesc: NDArray[np.uint64], order: NDArray[np.intp],
                  ry_sorted: NDArray[np.float32], lbuf: NDArray[np.uint8], lrows: NDArray[np.int64],
                  lpad: int, rbuf: NDArray[np.uint8], rrows: NDArray[np.int64], rpad: int,
                  widths: NDArray[np.int64], heights: NDArray[np.int64], scales: NDArray[np.float64],
                  bf: float, min_d: float, max_d: float, th_orb: int, th_high: int, w: int, L: int,
                  n_rows: int):
    n = len(lx)
    ur = np.full(n, -1.0)
    depth = np.zeros(n, np.float32)
    right = np.full(n, -1, np.intp)
    sad = np.full(n, -1, np.int64)
    delta = np.zeros(n, np.float64)
    n_levels = len(widths)
    r_max = 2.0 * scales[n_levels - 1]
    words = ldesc.shape[1]
    dists = np.empty(2 * L + 1)
    for il in range(n):
        v_l = ly[il]
        u_l = lx[il]
        lev = loct[il]
        if lev >= n_levels:
            continue
        row = int(v_l)  # ORB-SLAM2 indexes vRowIndices with the float row (truncation)
        if row < 0 or row >= n_rows:
            continue
        min_u = u_l - max_d
        max_u = u_l - min_d
        if max_u < 0:
            continue
        lo = np.searchsorted(ry_sorted, row - r_max - 1.0)
        hi = np.searchsorted(ry_sorted, row + r_max + 1.0, side="right")
        best = th_high
        best_r = -1
        for k in range(lo, hi):
            ir = order[k]
            if roct[ir] < lev - 1 or roct[ir] > lev + 1:
                continue
            r = 2.0 * scales[roct[ir]]
            if not (np.floor(ry[ir] - r) <= row <= np.ceil(ry[ir] + r)):
                continue
            u_r = rx[ir]
            if u_r < min_u or u_r > max_u:
                continue
            d = 0
            for q in range(words):
                d += _popcount64(ldesc[il, q] ^ rdesc[ir, q])
            if d < best or (d == best and best_r >= 0 and ir < best_r):
                best = d
                best_r = ir
        if best_r < 0 or best >= th_orb:
            continue
        # SAD refinement at the left keypoint's level (C++ round: half away from zero, x >= 0).
        inv = 1.0 / scales[lev]
        su_l = int(np.floor(u_l * inv + 0.5))
        sv_l = int(np.floor(v_l * inv + 0.5))
        su_r0 = int(np.floor(rx[best_r] * inv + 0.5))
        wl, hl = widths[lev], heights[lev]
        if sv_l - w < 0 or sv_l + w + 1 > hl or su_l - w < 0 or su_l + w + 1 > wl:
            continue
        if su_r0 - L - w < 0 or su_r0 + L + w + 1 > wl:
            continue
        lr0 = lrows[lev] + sv_l - w
        rr0 = rrows[lev] + sv_l - w
        best_sad = 1 << 62
        best_inc = 0
        for inc in range(-L, L + 1):
            s = _window_sad(lbuf, lr0, lpad + su_l - w, rbuf, rr0, rpad + su_r0 + inc - w, w)
            dists[L + inc] = s
            if s < best_sad:
                best_sad = int(s)
                best_inc = inc
        if best_inc == -L or best_inc == L:
            continue
        d1 = dists[L + best_inc - 1]
        d2 = dists[L + best_inc]
        d3 = dists[L + best_inc + 1]
        den = 2.0 * (d1 + d3 - 2.0 * d2)
        if den == 0.0:
            continue  # flat: no minimum to fit (ORB-SLAM2 gets inf/nan and rejects it)
        dr = (d1 - d3) / den
        if dr < -1.0 or dr > 1.0:
            continue
        best_ur = scales[lev] * (su_r0 + best_inc + dr)
        disparity = u_l - best_ur
        if disparity >= min_d and disparity < max_d:
            if disparity <= 0:
                disparity = 0.01
                best_ur = u_l - 0.01
            depth[il] = bf / disparity
            ur[il] = best_ur
            right[il] = best_r
            sad[il] = best_sad
            delta[il] = dr
    return ur, depth, right, sad, delta


def compute_stereo_matches(left: Keypoints, right: Keypoints, pyr_left: StackedPyramid,
                           pyr_right: StackedPyramid, scale_factor: float, bf: float,
                           baseline: float, th_low: float = TH_LOW, th_high: float = TH_HIGH) -> StereoMatches:
    """ORB-SLAM2's ``ComputeStereoMatches``: keypoints of the left and the right image of a
    rectified pair (level-0 pixels, ``octave`` = pyramid level, 32-byte ORB descriptors),
    the two images' ``stereo_pyramid``s, ``bf`` = fx * baseline (pixels * metres). The
    nearest depth searched is ``baseline`` (ORB-SLAM2's minZ), so disparities in
    [0, bf / baseline). ``th_low`` / ``th_high``: the extractor's TH_LOW / TH_HIGH (its
    ``FeatureSpec``'s); a match needs a distance under their mean."""
    if pyr_left.widths[0] != pyr_right.widths[0] or pyr_left.heights[0] != pyr_right.heights[0]:
        raise ValueError(f"stereo images differ in size: left {pyr_left.widths[0]}x{pyr_left.heights[0]}, "
                         f"right {pyr_right.widths[0]}x{pyr_right.heights[0]}")
    n = len(left)
    ldesc, rdesc = as_words(left.descriptors), as_words(right.descriptors)
    if n == 0 or len(right) == 0 or ldesc is None or rdesc is None:
        if n and (ldesc is None or rdesc is None) and len(right):
            raise ValueError("stereo matching needs binary descriptors of a multiple of 8 bytes")
        return StereoMatches(np.full(n, -1.0), np.zeros(n, np.float32), np.full(n, -1, np.intp),
                             np.full(n, -1, np.int64), np.zeros(n))
    levels = min(len(pyr_left.widths), len(pyr_right.widths))
    scales = scale_factors(levels, scale_factor)
    rx = np.ascontiguousarray(right.xy[:, 0], np.float32)
    ry = np.ascontiguousarray(right.xy[:, 1], np.float32)
    order = np.argsort(ry, kind="stable").astype(np.intp)
    ur, depth, idx, sad, delta = _stereo_match(
        np.ascontiguousarray(left.xy[:, 0], np.float32), np.ascontiguousarray(left.xy[:, 1], np.float32),
        np.ascontiguousarray(left.octave, np.int32), ldesc, rx, ry,
        np.ascontiguousarray(right.octave, np.int32), rdesc, order, ry[order],
        pyr_left.buffer, pyr_left.rows, pyr_left.pad, pyr_right.buffer, pyr_right.rows, pyr_right.pad,
        pyr_left.widths[:levels], pyr_left.heights[:levels], scales, float(bf), 0.0, float(bf) / float(baseline),
        int(th_high + th_low) // 2, int(th_high), SAD_W, SAD_L, int(pyr_left.heights[0]))
    matched = np.flatnonzero(depth > 0)
    if len(matched):
        # Outliers by SAD: ORB-SLAM2 sorts (SAD, index) pairs and takes the middle one.
        median = float(np.sort(sad[matched])[len(matched) // 2])
        drop = matched[sad[matched] >= 1.5 * 1.4 * median]
        ur[drop], depth[drop], idx[drop], sad[drop], delta[drop] = -1.0, 0.0, -1, -1, 0.0
    return StereoMatches(ur, depth, idx, sad, delta)


def warm_up() -> None:
    """Compile (or load) the kernel on a tiny input."""
    kp = Keypoints(np.array([[20.0, 20.0]], np.float32), np.zeros(1, np.int32), np.zeros(1, np.float32),
                   np.zeros(1, np.float32), np.zeros((1, 32), np.uint8))
    pyr = stereo_pyramid(np.zeros((40, 40), np.uint8), 1, 1.2)
    compute_stereo_matches(kp, kp, pyr, pyr, 1.2, 10.0, 0.1)
