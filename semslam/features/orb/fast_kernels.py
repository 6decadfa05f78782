"""Compiled FAST-9/16 (numba): OpenCV's ``FastFeatureDetector`` (TYPE_9_16, non-max
suppression) reproduced exactly, and ORB-SLAM's per-cell detection
(``ComputeKeyPointsOctTree``) built from it.

Why compiled: OpenCV's FAST is fast, but returns ``cv2.KeyPoint`` objects, and turning
them into arrays (plus ~70 calls per frame for ORB-SLAM's low-threshold retries) cost
more than the detection itself. Here nothing leaves the kernel but arrays.

OpenCV's semantics (``fast.cpp`` ``FAST_t<16>``, ``fast_score.cpp`` ``cornerScore<16>``):
- the circle: 16 offsets (x, y) ``CIRCLE``; a pixel with value ``v`` is a corner at
  threshold ``t`` iff >= 9 contiguous circle pixels ``p`` (circularly) all have
  ``p - v > t`` or all have ``p - v < -t``; ``t`` is clamped to [0, 255];
- only pixels of rows / columns ``[3, size - 3)`` are tested;
- score: ``cornerScore<16>`` (ported literally, non-SIMD version, ``_corner_score``);
- non-max suppression: a corner is kept iff its score is strictly greater than the
  scores of its 8 neighbours, non-corners and pixels outside the tested range counting
  as 0;
- the detect mask is applied after non-max suppression; keypoints come row by row.

ORB-SLAM runs that FAST on every cell ROI, so a corner's neighbours outside its cell's
tested range count as 0 (see ``detect_cells``). All kernels are ``nogil`` (they run in
the tracking thread next to other Python threads) and cached on disk (``cache=True``);
``semslam.features.orb.jit.warm_up`` compiles them once.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["CIRCLE", "detect_cells"]

# OpenCV's offsets16 (x, y), in circle order.
CIRCLE = np.array([[0, 3], [1, 3], [2, 2], [3, 1], [3, 0], [3, -1], [2, -2], [1, -3],
                   [0, -3], [-1, -3], [-2, -2], [-3, -1], [-3, 0], [-3, 1], [-2, 2], [-1, 3]],
                  np.int64)
_WORD = 8  # bytes per word when scanning the corner flags


# --------------------------------------------------------------------------- corner test

@njit(cache=True, nogil=True, inline="always")
def _above(a, h):
    """Non-zero iff a > h (uint8; written with max/sub so LLVM keeps 64 byte lanes)."""
    return np.uint8(max(a, h) - h)


@njit(cache=True, nogil=True, inline="always")
def _below(a, lo):
    """Non-zero iff a < lo (uint8)."""
    return np.uint8(lo - min(a, lo))


@njit(cache=True, nogil=True, inline="always")
def _run9(b0, b1, b2, b3, b4, b5, b6, b7, b8, b9, b10, b11, b12, b13, b14, b15):
    """Non-zero iff 9 circularly contiguous ``b`` are non-zero (min = and, max = or):
    runs of 2, 4, 8, then 8 + 1."""
    p0 = min(b0, b1); p1 = min(b1, b2); p2 = min(b2, b3); p3 = min(b3, b4)  # noqa: E702
    p4 = min(b4, b5); p5 = min(b5, b6); p6 = min(b6, b7); p7 = min(b7, b8)  # noqa: E702
    p8 = min(b8, b9); p9 = min(b9, b10); p10 = min(b10, b11); p11 = min(b11, b12)  # noqa: E702
    p12 = min(b12, b13); p13 = min(b13, b14); p14 = min(b14, b15); p15 = min(b15, b0)  # noqa: E702
    q0 = min(p0, p2); q1 = min(p1, p3); q2 = min(p2, p4); q3 = min(p3, p5)  # noqa: E702
    q4 = min(p4, p6); q5 = min(p5, p7); q6 = min(p6, p8); q7 = min(p7, p9)  # noqa: E702
    q8 = min(p8, p10); q9 = min(p9, p11); q10 = min(p10, p12); q11 = min(p11, p13)  # noqa: E702
    q12 = min(p12, p14); q13 = min(p13, p15); q14 = min(p14, p0); q15 = min(p15, p1)  # noqa: E702
    o0 = min(q0, q4); o1 = min(q1, q5); o2 = min(q2, q6); o3 = min(q3, q7)  # noqa: E702
    o4 = min(q4, q8); o5 = min(q5, q9); o6 = min(q6, q10); o7 = min(q7, q11)  # noqa: E702
    o8 = min(q8, q12); o9 = min(q9, q13); o10 = min(q10, q14); o11 = min(q11, q15)  # noqa: E702
    o12 = min(q12, q0); o13 = min(q13, q1); o14 = min(q14, q2); o15 = min(q15, q3)  # noqa: E702
    return max(max(max(min(o0, b8), min(o1, b9)), max(min(o2, b10), min(o3, b11))),
               max(max(min(o4, b12), min(o5, b13)), max(min(o6, b14), min(o7, b15))),
               max(max(min(o8, b0), min(o9, b1)), max(min(o10, b2), min(o11, b3))),
               max(max(min(o12, b4), min(o13, b5)), max(min(o14, b6), min(o15, b7))))


@njit(cache=True, nogil=True)
def _corner_flags(img, start, n, stride, t, out):
    """``out[p] != 0`` iff pixel ``p`` (flat index, ``start <= p < start + n``) is a FAST
    corner at threshold ``t`` (uint8). Branch-free over one flat run of pixels, so LLVM
    vectorises it with one byte per lane; pixels of the 3 px border columns get
    meaningless flags (the caller clears them). The circle must lie inside ``img``."""
    u = np.uint64
    s = u(start)
    o0 = u(start + 3 * stride); o1 = u(start + 1 + 3 * stride); o2 = u(start + 2 + 2 * stride)  # noqa: E702
    o3 = u(start + 3 + stride); o4 = u(start + 3); o5 = u(start + 3 - stride)  # noqa: E702
    o6 = u(start + 2 - 2 * stride); o7 = u(start + 1 - 3 * stride); o8 = u(start - 3 * stride)  # noqa: E702
    o9 = u(start - 1 - 3 * stride); o10 = u(start - 2 - 2 * stride); o11 = u(start - 3 - stride)  # noqa: E702
    o12 = u(start - 3); o13 = u(start - 3 + stride); o14 = u(start - 2 + 2 * stride)  # noqa: E702
    o15 = u(start - 1 + 3 * stride)
    # Unsigned indices: no negative-index wrap-around code in the loop.
    for j in range(n):
        i = u(j)
        v = img[s + i]
        h = np.uint8(v + min(np.uint8(255 - v), t))  # min(v + t, 255)
        lo = np.uint8(v - min(v, t))  # max(v - t, 0)
        a0 = img[o0 + i]; a1 = img[o1 + i]; a2 = img[o2 + i]; a3 = img[o3 + i]  # noqa: E702
        a4 = img[o4 + i]; a5 = img[o5 + i]; a6 = img[o6 + i]; a7 = img[o7 + i]  # noqa: E702
        a8 = img[o8 + i]; a9 = img[o9 + i]; a10 = img[o10 + i]; a11 = img[o11 + i]  # noqa: E702
        a12 = img[o12 + i]; a13 = img[o13 + i]; a14 = img[o14 + i]; a15 = img[o15 + i]  # noqa: E702
        bright = _run9(_above(a0, h), _above(a1, h), _above(a2, h), _above(a3, h), _above(a4, h),
                       _above(a5, h), _above(a6, h), _above(a7, h), _above(a8, h), _above(a9, h),
                       _above(a10, h), _above(a11, h), _above(a12, h), _above(a13, h), _above(a14, h),
                       _above(a15, h))
        dark = _run9(_below(a0, lo), _below(a1, lo), _below(a2, lo), _below(a3, lo), _below(a4, lo),
                     _below(a5, lo), _below(a6, lo), _below(a7, lo), _below(a8, lo), _below(a9, lo),
                     _below(a10, lo), _below(a11, lo), _below(a12, lo), _below(a13, lo), _below(a14, lo),
                     _below(a15, lo))
        out[s + i] = max(bright, dark)


# --------------------------------------------------------------------------- score

@njit(cache=True, nogil=True)
def _circle_offsets(stride):
    """OpenCV's ``makeOffsets``: flat offsets of the circle, repeated to 25 entries."""
    pix = np.empty(25, np.int64)
    for k in range(16):
        pix[k] = CIRCLE[k, 0] + CIRCLE[k, 1] * stride
    for k in range(16, 25):
        pix[k] = pix[k - 16]
    return pix


@njit(cache=True, nogil=True)
def _corner_score(img, p, pix, threshold, d):
    """OpenCV's ``cornerScore<16>`` (fast_score.cpp, non-SIMD), line by line:
    ``d[k] = v - p[k]`` for k < 25; the largest t for which the pixel is still a
    corner, ``threshold`` being the starting bound. ``d`` is an int32[25] work array."""
    v = np.int32(img[p])
    for k in range(25):
        d[k] = v - np.int32(img[p + pix[k]])
    a0 = np.int32(threshold)
    for k in range(0, 16, 2):
        a = min(d[k + 1], d[k + 2])
        a = min(a, d[k + 3])
        if a <= a0:
            continue
        a = min(a, d[k + 4])
        a = min(a, d[k + 5])
        a = min(a, d[k + 6])
        a = min(a, d[k + 7])
        a = min(a, d[k + 8])
        a0 = max(a0, min(a, d[k]))
        a0 = max(a0, min(a, d[k + 9]))
    b0 = -a0
    for k in range(0, 16, 2):
        b = max(d[k + 1], d[k + 2])
        b = max(b, d[k + 3])
        b = max(b, d[k + 4])
        b = max(b, d[k + 5])
        if b >= b0:
            continue
        b = max(b, d[k + 6])
        b = max(b, d[k + 7])
        b = max(b, d[k + 8])
        b0 = min(b0, max(b, d[k]))
        b0 = min(b0, max(b, d[k + 9]))
    return -b0 - 1


@njit(cache=True, nogil=True, inline="always")
def _min9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15):
    """Largest, over the 16 arcs of 9 contiguous circle pixels, of the arc's minimum."""
    p0 = min(d0, d1); p1 = min(d1, d2); p2 = min(d2, d3); p3 = min(d3, d4)  # noqa: E702
    p4 = min(d4, d5); p5 = min(d5, d6); p6 = min(d6, d7); p7 = min(d7, d8)  # noqa: E702
    p8 = min(d8, d9); p9 = min(d9, d10); p10 = min(d10, d11); p11 = min(d11, d12)  # noqa: E702
    p12 = min(d12, d13); p13 = min(d13, d14); p14 = min(d14, d15); p15 = min(d15, d0)  # noqa: E702
    q0 = min(p0, p2); q1 = min(p1, p3); q2 = min(p2, p4); q3 = min(p3, p5)  # noqa: E702
    q4 = min(p4, p6); q5 = min(p5, p7); q6 = min(p6, p8); q7 = min(p7, p9)  # noqa: E702
    q8 = min(p8, p10); q9 = min(p9, p11); q10 = min(p10, p12); q11 = min(p11, p13)  # noqa: E702
    q12 = min(p12, p14); q13 = min(p13, p15); q14 = min(p14, p0); q15 = min(p15, p1)  # noqa: E702
    o0 = min(q0, q4); o1 = min(q1, q5); o2 = min(q2, q6); o3 = min(q3, q7)  # noqa: E702
    o4 = min(q4, q8); o5 = min(q5, q9); o6 = min(q6, q10); o7 = min(q7, q11)  # noqa: E702
    o8 = min(q8, q12); o9 = min(q9, q13); o10 = min(q10, q14); o11 = min(q11, q15)  # noqa: E702
    o12 = min(q12, q0); o13 = min(q13, q1); o14 = min(q14, q2); o15 = min(q15, q3)  # noqa: E702
    return max(max(max(min(o0, d8), min(o1, d9)), max(min(o2, d10), min(o3, d11))),
               max(max(min(o4, d12), min(o5, d13)), max(min(o6, d14), min(o7, d15))),
               max(max(min(o8, d0), min(o9, d1)), max(min(o10, d2), min(o11, d3))),
               max(max(min(o12, d4), min(o13, d5)), max(min(o14, d6), min(o15, d7))))


@njit(cache=True, nogil=True, inline="always")
def _max9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15):
    """Smallest, over the 16 arcs of 9 contiguous circle pixels, of the arc's maximum."""
    p0 = max(d0, d1); p1 = max(d1, d2); p2 = max(d2, d3); p3 = max(d3, d4)  # noqa: E702
    p4 = max(d4, d5); p5 = max(d5, d6); p6 = max(d6, d7); p7 = max(d7, d8)  # noqa: E702
    p8 = max(d8, d9); p9 = max(d9, d10); p10 = max(d10, d11); p11 = max(d11, d12)  # noqa: E702
    p12 = max(d12, d13); p13 = max(d13, d14); p14 = max(d14, d15); p15 = max(d15, d0)  # noqa: E702
    q0 = max(p0, p2); q1 = max(p1, p3); q2 = max(p2, p4); q3 = max(p3, p5)  # noqa: E702
    q4 = max(p4, p6); q5 = max(p5, p7); q6 = max(p6, p8); q7 = max(p7, p9)  # noqa: E702
    q8 = max(p8, p10); q9 = max(p9, p11); q10 = max(p10, p12); q11 = max(p11, p13)  # noqa: E702
    q12 = max(p12, p14); q13 = max(p13, p15); q14 = max(p14, p0); q15 = max(p15, p1)  # noqa: E702
    o0 = max(q0, q4); o1 = max(q1, q5); o2 = max(q2, q6); o3 = max(q3, q7)  # noqa: E702
    o4 = max(q4, q8); o5 = max(q5, q9); o6 = max(q6, q10); o7 = max(q7, q11)  # noqa: E702
    o8 = max(q8, q12); o9 = max(q9, q13); o10 = max(q10, q14); o11 = max(q11, q15)  # noqa: E702
    o12 = max(q12, q0); o13 = max(q13, q1); o14 = max(q14, q2); o15 = max(q15, q3)  # noqa: E702
    return min(min(min(max(o0, d8), max(o1, d9)), min(max(o2, d10), max(o3, d11))),
               min(min(max(o4, d12), max(o5, d13)), min(max(o6, d14), max(o7, d15))),
               min(min(max(o8, d0), max(o9, d1)), min(max(o10, d2), max(o11, d3))),
               min(min(max(o12, d4), max(o13, d5)), min(max(o14, d6), max(o15, d7))))


_SCORE_CHUNK = 512  # corners per gather (the differences stay in L1)


@njit(cache=True, nogil=True)
def score_corners(img, width, positions, n, threshold, scores):
    """``cornerScore<16>`` of the pixels ``positions[:n]`` (flat, row stride ``width``)
    into ``scores``, branch-free so LLVM vectorises it over corners. The same value as
    ``_corner_score`` (tests): that loop computes ``max(threshold, A, -M) - 1`` with
    ``A`` = the largest arc-of-9 minimum and ``M`` = the smallest arc-of-9 maximum of
    ``d = v - p``; its ``continue`` only skips arcs that cannot change the result."""
    pix = _circle_offsets(width)
    d = np.empty((16, _SCORE_CHUNK), np.int16)
    t = np.int16(threshold)
    for c0 in range(0, n, _SCORE_CHUNK):
        m = min(_SCORE_CHUNK, n - c0)
        for c in range(m):
            p = positions[c0 + c]
            v = np.int16(img[p])
            for k in range(16):
                d[k, c] = v - np.int16(img[p + pix[k]])
        for c in range(m):
            d0 = d[0, c]; d1 = d[1, c]; d2 = d[2, c]; d3 = d[3, c]  # noqa: E702
            d4 = d[4, c]; d5 = d[5, c]; d6 = d[6, c]; d7 = d[7, c]  # noqa: E702
            d8 = d[8, c]; d9 = d[9, c]; d10 = d[10, c]; d11 = d[11, c]  # noqa: E702
            d12 = d[12, c]; d13 = d[13, c]; d14 = d[14, c]; d15 = d[15, c]  # noqa: E702
            a = _min9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15)
            b = _max9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15)
            scores[c0 + c] = np.int16(max(max(t, a), np.int16(-b)) - 1)


# --------------------------------------------------------------------------- helpers

@njit(cache=True, nogil=True)
def _copy_region(src, base, stride, width, height, work):
    """Copy ``height`` rows of ``width`` pixels from ``src[base + y * stride + x]`` into
    ``work`` (row stride ``width``). Why: the flag pass then runs over one flat run with
    only 6 wasted columns per row, whatever the source's row stride."""
    u = np.uint64
    for y in range(height):
        s = u(base + y * stride)
        o = u(y * width)
        for x in range(width):
            work[o + u(x)] = src[s + u(x)]


@njit(cache=True, nogil=True)
def _flag_rows(work, width, y0, y1, t, flags):
    """Corner flags at threshold ``t`` of rows ``[y0, y1)`` (all columns), then the
    3 + 3 border columns of those rows cleared. Rows must be in ``[3, height - 3)``."""
    start = y0 * width + 3
    n = (y1 - y0 - 1) * width + width - 6
    _corner_flags(work, start, n, width, np.uint8(min(max(t, 0), 255)), flags)
    for y in range(y0, y1):
        r = y * width
        for x in range(3):
            flags[r + x] = 0
            flags[r + width - 1 - x] = 0


@njit(cache=True, nogil=True)
def _scan_flags(flags, width, height, positions):
    """Flat indices of the non-zero flags of rows ``[3, height - 3)``, in order, into
    ``positions``; returns their count. Reads 8 bytes at a time (corners are sparse);
    the flags of the border columns must be 0."""
    first, last = 3 * width, (height - 3) * width
    n = 0
    p = first
    while p < last and p % _WORD:
        if flags[p]:
            positions[n] = p
            n += 1
        p += 1
    words = flags[p:p + (last - p) // _WORD * _WORD].view(np.uint64)
    for w in range(words.size):
        if words[w]:
            q = p + w * _WORD
            for b in range(_WORD):
                if flags[q + b]:
                    positions[n] = q + b
                    n += 1
    p += words.size * _WORD
    while p < last:
        if flags[p]:
            positions[n] = p
            n += 1
        p += 1
    return n


@njit(cache=True, nogil=True)
def _is_local_max(scores, p, width, x, y, x0, x1, y0, y1):
    """OpenCV's non-max test for the corner at flat ``p`` = (x, y): its score strictly
    above its 8 neighbours' in the score image, those outside ``[x0, x1) x [y0, y1)``
    counting as 0."""
    s = scores[p]
    if s == 0:
        return False  # a zero score is never greater than a neighbour's (>= 0)
    for dy in range(-1, 2):
        yy = y + dy
        for dx in range(-1, 2):
            xx = x + dx
            if (dx or dy) and y0 <= yy < y1 and x0 <= xx < x1 and s <= scores[p + dy * width + dx]:
                return False
    return True


# --------------------------------------------------------------------------- detection

@njit(cache=True, nogil=True)
def detect_cells(src, base, stride, width, height, t_hi, t_lo, n_cols, n_rows, w_cell, h_cell,
                 mask, mrows, mcols, use_mask, work, flags, positions):
    """FAST keypoints of the ``width`` x ``height`` region at ``src[base + y * stride + x]``,
    ORB-SLAM's way: the region is cut into ``n_rows`` x ``n_cols`` cells whose tested
    ranges ``[3 + j w_cell, min(3 + (j + 1) w_cell, width - 3))`` (likewise rows) tile
    ``[3, width - 3) x [3, height - 3)``; each cell is FAST at ``t_hi`` on its own, i.e.
    non-max suppression sees only neighbours inside the cell; a cell left without
    keypoints is FAST at ``t_lo`` on its own (no retry if ``t_lo < 0``). One cell covering
    the region (``n_cols = n_rows = 1``, ``w_cell >= width - 6``) is plain OpenCV FAST.

    ``mask[mrows[y], mcols[x]] == 0`` forbids region pixel (x, y) (after suppression,
    like FAST's mask), if ``use_mask``. ``work``, ``flags``: uint8 buffers of at least
    ``width * height``; ``positions``: int64 buffer of as many.

    How: one corner test at ``t = min(t_hi, t_lo)`` over the region and the scores of
    those corners (with ``t``); then, per cell, FAST at ``t'`` (``t_hi``, or ``t_lo``
    for an empty cell) is the corners with score >= ``t'`` that beat their in-cell
    neighbours' scores. Exact because OpenCV's score is ``max(t, A, -M) - 1`` (see
    ``score_corners``): a corner at ``t'`` has the same score for every threshold <= ``t'``,
    is a corner at ``t'`` iff its score >= ``t'``, and a neighbour with a score below
    ``t'`` (not a corner at ``t'``, hence 0 for OpenCV) never beats it.

    Returns x, y (region pixels, int64), score (uint8) and cell index of the keypoints,
    cell by cell in raster order and row-major inside a cell (ORB-SLAM's order)."""
    if width < 7 or height < 7:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8), np.zeros(0, np.int64)
    t_hi = min(max(t_hi, 0), 255)
    retry = t_lo >= 0
    t_lo = min(max(t_lo, 0), 255)
    t = min(t_hi, t_lo) if retry else t_hi
    _copy_region(src, base, stride, width, height, work)
    _flag_rows(work, width, 3, height - 3, t, flags)
    n = _scan_flags(flags, width, height, positions)
    score = np.empty(n, np.int16)
    score_corners(work, width, positions, n, t, score)

    # Score image (0 = no corner) for the suppression, and the corners' cells.
    n_cells = n_cols * n_rows
    col_cell = np.empty(width, np.int64)
    row_cell = np.empty(height, np.int64)
    for x in range(width):
        col_cell[x] = min(max(x - 3, 0) // w_cell, n_cols - 1)
    for y in range(height):
        row_cell[y] = min(max(y - 3, 0) // h_cell, n_rows - 1)
    xs = np.empty(n, np.int64)
    ys = np.empty(n, np.int64)
    count = np.zeros(n_cells + 1, np.int64)
    y, row_end = 3, 4 * width
    for k in range(n):
        p = positions[k]
        while p >= row_end:
            y += 1
            row_end += width
        xs[k], ys[k] = p - (row_end - width), y
        flags[p] = np.uint8(score[k])
        count[row_cell[y] * n_cols + col_cell[xs[k]] + 1] += 1
    # Stable counting sort by cell (row-major inside each cell).
    first = np.cumsum(count)
    fill = first[:n_cells].copy()
    order = np.empty(n, np.int64)
    for k in range(n):
        c = row_cell[ys[k]] * n_cols + col_cell[xs[k]]
        order[fill[c]] = k
        fill[c] += 1

    out = np.empty(n, np.int64)
    out_cell = np.empty(n, np.int64)
    m = 0
    for c in range(n_cells):
        i, j = c // n_cols, c % n_cols
        x0, y0 = 3 + j * w_cell, 3 + i * h_cell
        x1, y1 = min(x0 + w_cell, width - 3), min(y0 + h_cell, height - 3)
        for attempt in range(2):
            if attempt == 1 and (not retry or m > 0 and out_cell[m - 1] == c):
                break
            tc = t_hi if attempt == 0 else t_lo
            for k in range(first[c], first[c + 1]):
                q = order[k]
                if score[q] >= tc and _is_local_max(flags, positions[q], width, xs[q], ys[q], x0, x1, y0, y1) \
                        and (not use_mask or mask[mrows[ys[q]], mcols[xs[q]]] != 0):
                    out[m] = q
                    out_cell[m] = c
                    m += 1
    kx = np.empty(m, np.int64)
    ky = np.empty(m, np.int64)
    ks = np.empty(m, np.uint8)
    for k in range(m):
        q = out[k]
        kx[k], ky[k], ks[k] = xs[q], ys[q], score[q]
    return kx, ky, ks, out_cell[:m].copy()
