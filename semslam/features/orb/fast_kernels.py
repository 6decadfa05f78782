"""Compiled FAST-9/16 (numba): OpenCV's ``FastFeatureDetector`` (TYPE_9_16, non-max
suppression) reproduced exactly, and ORB-SLAM's per-cell detection
(``ComputeKeyPointsOctTree``) built from it.

Why compiled: OpenCV's FAST is fast, but returns ``cv2.KeyPoint`` objects, and turning
them into arrays (plus ~70 calls per frame for ORB-SLAM's low-threshold retries) cost
more than the detection itself. Here nothing leaves the kernel but arrays.

OpenCV's semantics (``fast.cpp`` ``FAST_t<16>``, ``fast_score.cpp`` ``cornerScore<16>``):
- the circle: 16 offsets (x, y) ``CIRCLE``; a pixel with value ``v`` is a corner at
  threshold ``t`` iff >= 9 contiguous circle pixels ``p`` (circularly) all have
  ``p - v > t`` or all have ``p - v < -t``; ``t`` in [0, 255] (the Python wrappers
  refuse others: OpenCV clamps them in its scalar code and wraps them in its SIMD code);
- only pixels of rows / columns ``[3, size - 3)`` are tested;
- score: ``cornerScore<16>``, ported literally (non-SIMD version) as ``_corner_score``,
  the reference of the branch-free ``score_corners`` the detection uses (equal on every
  corner of the test frames);
- non-max suppression: a corner is kept iff its score is strictly greater than the
  scores of its 8 neighbours, non-corners and pixels outside the tested range counting
  as 0;
- the detect mask is applied after non-max suppression; keypoints come row by row.

ORB-SLAM runs that FAST on every cell ROI, so a corner's neighbours outside its cell's
tested range count as 0 (see ``detect_cells``). How a pass runs: the corner test for a
flat run of pixels at once (one byte per vector lane), a scan of the flags, the scores
of the corners found, then the suppression (for whole rows at once when corners are
dense, else corner by corner). All kernels are ``nogil`` (they run in the tracking
thread next to other Python threads) and cached on disk (``cache=True``);
``semslam.features.orb.jit.warm_up`` compiles them once.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["CIRCLE", "detect_cells", "detect_pyramid", "detect_two_thresholds_pyramid", "score_corners"]

# OpenCV's offsets16 (x, y), in circle order.
CIRCLE = np.array([[0, 3], [1, 3], [2, 2], [3, 1], [3, 0], [3, -1], [2, -2], [1, -3],
                   [0, -3], [-1, -3], [-2, -2], [-3, -1], [-3, 0], [-3, 1], [-2, 2], [-1, 3]],
                  np.int64)


# --------------------------------------------------------------------------- corner test

@njit(cache=True, nogil=True, inline="always")
def _above(a, h):
    """Non-zero iff a > h (uint8; written with max/sub so LLVM keeps 64 byte lanes)."""
    return np.uint8(max(a, h) - h)


@njit(cache=True, nogil=True, inline="always")
def _below(a, lo):
    """Non-zero iff a < lo (uint8)."""
    return np.uint8(lo - min(a, lo))


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
        bright = _min9(_above(a0, h), _above(a1, h), _above(a2, h), _above(a3, h), _above(a4, h),
                       _above(a5, h), _above(a6, h), _above(a7, h), _above(a8, h), _above(a9, h),
                       _above(a10, h), _above(a11, h), _above(a12, h), _above(a13, h), _above(a14, h),
                       _above(a15, h))  # non-zero iff 9 contiguous are
        dark = _min9(_below(a0, lo), _below(a1, lo), _below(a2, lo), _below(a3, lo), _below(a4, lo),
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
def _smin(a, b):
    """min as a select: numba's builtin min widens small integers to int64, which makes
    LLVM vectorise the score network 8 lanes wide instead of 32 (7x slower)."""
    return a if a < b else b


@njit(cache=True, nogil=True, inline="always")
def _smax(a, b):
    """max as a select (see ``_smin``)."""
    return a if a > b else b


@njit(cache=True, nogil=True, inline="always")
def _min9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15):
    """Largest, over the 16 arcs of 9 contiguous circle pixels, of the arc's minimum."""
    p0 = _smin(d0, d1); p1 = _smin(d1, d2); p2 = _smin(d2, d3); p3 = _smin(d3, d4)  # noqa: E702
    p4 = _smin(d4, d5); p5 = _smin(d5, d6); p6 = _smin(d6, d7); p7 = _smin(d7, d8)  # noqa: E702
    p8 = _smin(d8, d9); p9 = _smin(d9, d10); p10 = _smin(d10, d11); p11 = _smin(d11, d12)  # noqa: E702
    p12 = _smin(d12, d13); p13 = _smin(d13, d14); p14 = _smin(d14, d15); p15 = _smin(d15, d0)  # noqa: E702
    q0 = _smin(p0, p2); q1 = _smin(p1, p3); q2 = _smin(p2, p4); q3 = _smin(p3, p5)  # noqa: E702
    q4 = _smin(p4, p6); q5 = _smin(p5, p7); q6 = _smin(p6, p8); q7 = _smin(p7, p9)  # noqa: E702
    q8 = _smin(p8, p10); q9 = _smin(p9, p11); q10 = _smin(p10, p12); q11 = _smin(p11, p13)  # noqa: E702
    q12 = _smin(p12, p14); q13 = _smin(p13, p15); q14 = _smin(p14, p0); q15 = _smin(p15, p1)  # noqa: E702
    o0 = _smin(q0, q4); o1 = _smin(q1, q5); o2 = _smin(q2, q6); o3 = _smin(q3, q7)  # noqa: E702
    o4 = _smin(q4, q8); o5 = _smin(q5, q9); o6 = _smin(q6, q10); o7 = _smin(q7, q11)  # noqa: E702
    o8 = _smin(q8, q12); o9 = _smin(q9, q13); o10 = _smin(q10, q14); o11 = _smin(q11, q15)  # noqa: E702
    o12 = _smin(q12, q0); o13 = _smin(q13, q1); o14 = _smin(q14, q2); o15 = _smin(q15, q3)  # noqa: E702
    return max(max(_smax(_smin(o0, d8), _smin(o1, d9)), _smax(_smin(o2, d10), _smin(o3, d11))),
               max(_smax(_smin(o4, d12), _smin(o5, d13)), _smax(_smin(o6, d14), _smin(o7, d15))),
               max(_smax(_smin(o8, d0), _smin(o9, d1)), _smax(_smin(o10, d2), _smin(o11, d3))),
               max(_smax(_smin(o12, d4), _smin(o13, d5)), _smax(_smin(o14, d6), _smin(o15, d7))))


@njit(cache=True, nogil=True, inline="always")
def _max9(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15):
    """Smallest, over the 16 arcs of 9 contiguous circle pixels, of the arc's maximum."""
    p0 = _smax(d0, d1); p1 = _smax(d1, d2); p2 = _smax(d2, d3); p3 = _smax(d3, d4)  # noqa: E702
    p4 = _smax(d4, d5); p5 = _smax(d5, d6); p6 = _smax(d6, d7); p7 = _smax(d7, d8)  # noqa: E702
    p8 = _smax(d8, d9); p9 = _smax(d9, d10); p10 = _smax(d10, d11); p11 = _smax(d11, d12)  # noqa: E702
    p12 = _smax(d12, d13); p13 = _smax(d13, d14); p14 = _smax(d14, d15); p15 = _smax(d15, d0)  # noqa: E702
    q0 = _smax(p0, p2); q1 = _smax(p1, p3); q2 = _smax(p2, p4); q3 = _smax(p3, p5)  # noqa: E702
    q4 = _smax(p4, p6); q5 = _smax(p5, p7); q6 = _smax(p6, p8); q7 = _smax(p7, p9)  # noqa: E702
    q8 = _smax(p8, p10); q9 = _smax(p9, p11); q10 = _smax(p10, p12); q11 = _smax(p11, p13)  # noqa: E702
    q12 = _smax(p12, p14); q13 = _smax(p13, p15); q14 = _smax(p14, p0); q15 = _smax(p15, p1)  # noqa: E702
    o0 = _smax(q0, q4); o1 = _smax(q1, q5); o2 = _smax(q2, q6); o3 = _smax(q3, q7)  # noqa: E702
    o4 = _smax(q4, q8); o5 = _smax(q5, q9); o6 = _smax(q6, q10); o7 = _smax(q7, q11)  # noqa: E702
    o8 = _smax(q8, q12); o9 = _smax(q9, q13); o10 = _smax(q10, q14); o11 = _smax(q11, q15)  # noqa: E702
    o12 = _smax(q12, q0); o13 = _smax(q13, q1); o14 = _smax(q14, q2); o15 = _smax(q15, q3)  # noqa: E702
    return min(min(_smin(_smax(o0, d8), _smax(o1, d9)), _smin(_smax(o2, d10), _smax(o3, d11))),
               min(_smin(_smax(o4, d12), _smax(o5, d13)), _smin(_smax(o6, d14), _smax(o7, d15))),
               min(_smin(_smax(o8, d0), _smax(o9, d1)), _smin(_smax(o10, d2), _smax(o11, d3))),
               min(_smin(_smax(o12, d4), _smax(o13, d5)), _smin(_smax(o14, d6), _smax(o15, d7))))


_SCORE_CHUNK = 256  # corners per gather (the differences stay in L1)
_SCORE_ROW = _SCORE_CHUNK + 8  # padded: 16 rows 512 B apart would share 2 L1 sets (~8 % slower)


@njit(cache=True, nogil=True)
def score_corners(img, width, positions, n, threshold, scores):
    """``cornerScore<16>`` of the pixels ``positions[:n]`` (flat, row stride ``width``)
    into ``scores``, branch-free so LLVM vectorises it over corners. The same value as
    ``_corner_score`` (tests): that loop computes ``max(threshold, A, -M) - 1`` with
    ``A`` = the largest arc-of-9 minimum and ``M`` = the smallest arc-of-9 maximum of
    ``d = v - p``; its ``continue`` only skips arcs that cannot change the result."""
    pix = _circle_offsets(width)
    d = np.empty((16, _SCORE_ROW), np.int16)
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
            scores[c0 + c] = np.int16(_smax(_smax(t, a), np.int16(-b)) - 1)


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


_LANES = 64  # pixels per vector iteration of the corner test


@njit(cache=True, nogil=True)
def _flag_span(work, width, y0, y1, x0, x1, t, flags):
    """Corner flags at ``t`` of columns ``[x0, x1)`` of rows ``[y0, y1)`` (inside the
    tested range), row by row, each row's run widened to a multiple of the vector width
    where the row allows it (a 30 px run costs ~9x more per pixel than 64); or, for
    spans over half the row, all columns in one flat run. Returns the columns flagged."""
    n = x1 - x0
    wide = -(-n // _LANES) * _LANES
    if 2 * wide > width - 6:  # most of the row: one flat run over the band is cheaper
        _flag_rows(work, width, y0, y1, t, flags)
        return 3, width - 3
    x0 = max(3, x1 - wide)
    n = min(wide, width - 3 - x0)
    tt = np.uint8(min(max(t, 0), 255))
    for y in range(y0, y1):
        _corner_flags(work, y * width + x0, n, width, tt, flags)
    return x0, x0 + n


_BLOCK = 8  # bytes tested at once when scanning flags


@njit(cache=True, nogil=True)
def _scan_range(flags, start, end, positions, n):
    """Append the flat indices in ``[start, end)`` with a non-zero flag to ``positions``
    from ``n`` on, in order; returns the new count. Blocks of 8 flags are skipped when
    all zero (most are) and otherwise appended without branches (a 15 % density of
    corners makes per-byte branches mispredict): ~3x faster than a byte loop."""
    u = np.uint64
    p = start
    while p + _BLOCK <= end:
        acc = np.uint8(0)
        for i in range(_BLOCK):
            acc |= flags[u(p + i)]
        if acc:
            for i in range(_BLOCK):
                positions[n] = p + i
                n += flags[p + i] != 0
        p += _BLOCK
    while p < end:
        positions[n] = p
        n += flags[p] != 0
        p += 1
    return n


@njit(cache=True, nogil=True)
def _scan(flags, width, y0, y1, positions):
    """Flat indices of the non-zero ``flags`` of rows ``[y0, y1)``, in order, into
    ``positions``; returns their count. The flags of the 3 + 3 border columns must be 0."""
    return _scan_range(flags, y0 * width, y1 * width, positions, 0)


@njit(cache=True, nogil=True)
def _suppress(scores, width, y0, y1, x0, x1, left, right, first_row, last_row, keep):
    """OpenCV's non-max suppression for every pixel of rows ``[y0, y1)``, columns
    ``[x0, x1)`` (inside ``[3, width - 3)``) at once: ``keep[p] = 1`` iff ``scores[p]`` is strictly above its 8
    neighbours', a neighbour in another cell counting as 0. ``left[x]`` / ``right[x]``
    are 0 where the left / right neighbour of column x is in another cell (else 255),
    ``first_row[y]`` / ``last_row[y]`` say the same of the rows above / below.
    Branch-free over whole rows so it vectorises: cheaper than testing corners one by
    one when there are thousands."""
    lm = left[x0:x1]
    rm = right[x0:x1]
    for y in range(y0, y1):
        up = np.uint8(0 if first_row[y] else 255)
        down = np.uint8(0 if last_row[y] else 255)
        r = y * width + x0
        e = r + x1 - x0
        c = scores[r:e]
        wl, wr = scores[r - 1:e - 1], scores[r + 1:e + 1]
        a, al, ar = scores[r - width:e - width], scores[r - width - 1:e - width - 1], scores[r - width + 1:e - width + 1]
        b, bl, br = scores[r + width:e + width], scores[r + width - 1:e + width - 1], scores[r + width + 1:e + width + 1]
        out = keep[r:e]
        for i in range(x1 - x0):
            lmi, rmi = lm[i], rm[i]
            m = max(np.uint8(wl[i] & lmi), np.uint8(wr[i] & rmi))
            m_up = np.uint8(max(a[i], max(np.uint8(al[i] & lmi), np.uint8(ar[i] & rmi))) & up)
            m_down = np.uint8(max(b[i], max(np.uint8(bl[i] & lmi), np.uint8(br[i] & rmi))) & down)
            out[i] = np.uint8(c[i] > max(m, max(m_up, m_down)))


@njit(cache=True, nogil=True)
def _cell_span(k, cell, size):
    """[first, end) of the pixels cell ``k`` (of ``cell`` px) tests along a side of ``size``
    px: the cells' tested ranges tile ``[3, size - 3)``."""
    return 3 + k * cell, min(3 + (k + 1) * cell, size - 3)


@njit(cache=True, nogil=True)
def _scan_cells(flags, width, y0, y1, i, n_cols, w_cell, wanted, positions, cells):
    """Flat indices of the non-zero flags inside the wanted cells of cell row ``i`` (rows
    ``[y0, y1)``), row-major, into ``positions``, their cells into ``cells``; returns how
    many."""
    n = 0
    for y in range(y0, y1):
        r = y * width
        for j in range(n_cols):
            c = i * n_cols + j
            if wanted[c]:
                c0, c1 = _cell_span(j, w_cell, width)
                m = _scan_range(flags, r + c0, r + c1, positions, n)
                for k in range(n, m):
                    cells[k] = c
                n = m
    return n


@njit(cache=True, nogil=True)
def _local_max(scores, p, width, x, y, left, right, first_row, last_row):
    """OpenCV's non-max test for one corner: its score strictly above its 8 neighbours',
    a neighbour in another cell counting as 0 (same rule as ``_suppress``)."""
    s = scores[p]
    lm, rm = left[x] != 0, right[x] != 0
    if (lm and scores[p - 1] >= s) or (rm and scores[p + 1] >= s):
        return False
    if not first_row[y]:
        q = p - width
        if scores[q] >= s or (lm and scores[q - 1] >= s) or (rm and scores[q + 1] >= s):
            return False
    if not last_row[y]:
        q = p + width
        if scores[q] >= s or (lm and scores[q - 1] >= s) or (rm and scores[q + 1] >= s):
            return False
    return s > 0


@njit(cache=True, nogil=True)
def _fast_pass(work, flags, keep, positions, cells, width, y0, y1, x0, x1, t, wanted, i, n_cols, w_cell,
               col_cell, row_cell, left, right, first_row, last_row):
    """FAST at ``t`` in the cells ``wanted`` of rows ``[y0, y1)``, each cell on its own:
    either the whole region (``i < 0``: every cell, ``[x0, x1) = [3, width - 3)``, one
    flat pass) or the wanted cells of cell row ``i``, which lie in columns ``[x0, x1)``.
    Corner flags, the scores of the wanted cells' corners (written over their flags:
    the score image), per-cell suppression (over the whole span when corners are
    dense, else corner by corner). Survivors (row-major) go to ``positions`` and their
    cells to ``cells``; returns how many."""
    if i < 0:
        _flag_rows(work, width, y0, y1, t, flags)
        n = _scan(flags, width, y0, y1, positions)
        y, row_end = y0, (y0 + 1) * width
        for k in range(n):
            p = positions[k]
            while p >= row_end:
                y += 1
                row_end += width
            cells[k] = row_cell[y] * n_cols + col_cell[p - (row_end - width)]
        if not wanted.all():  # only the wanted cells' corners are scored
            kept = 0
            for k in range(n):
                if wanted[cells[k]]:
                    positions[kept] = positions[k]
                    cells[kept] = cells[k]
                    kept += 1
            n = kept
    else:
        x0, x1 = _flag_span(work, width, y0, y1, x0, x1, t, flags)
        n = _scan_cells(flags, width, y0, y1, i, n_cols, w_cell, wanted, positions, cells)
    score = np.empty(n, np.int16)
    score_corners(work, width, positions, n, t, score)
    for k in range(n):
        flags[positions[k]] = np.uint8(score[k])
    dense = n * 128 > (y1 - y0) * (x1 - x0)  # ~0.15 ns per pixel against ~20 ns per corner
    if dense:
        _suppress(flags, width, y0, y1, x0, x1, left, right, first_row, last_row, keep)
    m = 0
    y, row_end = y0, (y0 + 1) * width
    for k in range(n):
        p = positions[k]
        while p >= row_end:
            y += 1
            row_end += width
        x = p - (row_end - width)
        if keep[p] if dense else _local_max(flags, p, width, x, y, left, right, first_row, last_row):
            positions[m] = p
            cells[m] = cells[k]
            m += 1
    return m


# --------------------------------------------------------------------------- detection

@njit(cache=True, nogil=True)
def _detect_region(src, base, stride, width, height, t_hi, t_lo, n_cols, n_rows, w_cell, h_cell,
                   mask, mrows, mcols, use_mask, work, flags, keep, positions, cells, out, n_out, level):
    """``detect_cells`` for one region, appending (x, y, score, cell, level) rows to
    ``out`` from row ``n_out`` on (grown as needed); returns (out, new row count)."""
    if width < 7 or height < 7:
        return out, n_out
    n_cells = n_cols * n_rows
    # Cell of every column / row, and where the cells' ranges begin and end.
    col_cell = np.empty(width, np.int64)
    row_cell = np.empty(height, np.int64)
    left = np.full(width, 255, np.uint8)
    right = np.full(width, 255, np.uint8)
    first_row = np.zeros(height, np.bool_)
    last_row = np.zeros(height, np.bool_)
    for x in range(width):
        col_cell[x] = min(max(x - 3, 0) // w_cell, n_cols - 1)
        if x >= 3 and (x - 3) % w_cell == 0:
            left[x] = 0
        if x + 1 == width - 3 or (x >= 3 and (x - 2) % w_cell == 0):
            right[x] = 0
    for y in range(height):
        row_cell[y] = min(max(y - 3, 0) // h_cell, n_rows - 1)
        first_row[y] = y >= 3 and (y - 3) % h_cell == 0
        last_row[y] = y + 1 == height - 3 or (y >= 3 and (y - 2) % h_cell == 0)
    _copy_region(src, base, stride, width, height, work)

    # Every cell at the high threshold, but those the mask forbids entirely (nothing
    # found there could be kept: the same keypoints, without scoring the people of a
    # masked frame); the mask drops keypoints after suppression.
    blocked = _masked_cells(width, height, n_cols, n_rows, w_cell, h_cell, mask, mrows, mcols, use_mask)
    wanted = ~blocked
    m = _fast_pass(work, flags, keep, positions, cells, width, 3, height - 3, 3, width - 3, t_hi, wanted, -1, n_cols,
                   w_cell, col_cell, row_cell, left, right, first_row, last_row)
    if out.shape[0] < n_out + m:
        out = _grown_rows(out, n_out + m)
    n = n_out
    count = np.zeros(n_cells, np.int64)
    for k in range(m):
        p = positions[k]
        y = p // width
        x = p - y * width
        if use_mask and mask[mrows[y], mcols[x]] == 0:
            continue
        out[n, 0], out[n, 1], out[n, 2], out[n, 3], out[n, 4] = x, y, flags[p], cells[k], level
        count[cells[k]] += 1
        n += 1

    # The low threshold in the cells left empty (not those forbidden), band by band.
    if t_lo >= 0:
        for i in range(n_rows):
            y0, y1 = _cell_span(i, h_cell, height)
            x0, x1 = width, 0  # columns of the band's empty cells
            for j in range(n_cols):
                c = i * n_cols + j
                c0, c1 = _cell_span(j, w_cell, width)
                wanted[c] = count[c] == 0 and y1 > y0 and c1 > c0 and not blocked[c]
                if wanted[c]:
                    x0, x1 = min(x0, c0), max(x1, c1)
            if x1 <= x0:
                continue
            m = _fast_pass(work, flags, keep, positions, cells, width, y0, y1, x0, x1, t_lo, wanted, i, n_cols,
                           w_cell, col_cell, row_cell, left, right, first_row, last_row)
            if out.shape[0] < n + m:
                out = _grown_rows(out, n + m)
            for k in range(m):
                p = positions[k]
                y = p // width
                x = p - y * width
                if use_mask and mask[mrows[y], mcols[x]] == 0:
                    continue
                out[n, 0], out[n, 1], out[n, 2], out[n, 3], out[n, 4] = x, y, flags[p], cells[k], level
                n += 1

    # ORB-SLAM's order: stable counting sort by cell (row-major inside each cell).
    first = np.zeros(n_cells + 1, np.int64)
    for k in range(n_out, n):
        first[out[k, 3] + 1] += 1
    for c in range(n_cells):
        first[c + 1] += first[c]
    block = out[n_out:n].copy()
    for k in range(n - n_out):
        c = block[k, 3]
        out[n_out + first[c]] = block[k]
        first[c] += 1
    return out, n


@njit(cache=True, nogil=True)
def _masked_cells(width, height, n_cols, n_rows, w_cell, h_cell, mask, mrows, mcols, use_mask):
    """Which cells (raster order) the mask forbids entirely: every pixel of the cell's
    tested range has ``mask[mrows[y], mcols[x]] == 0``. A cell with an allowed pixel is
    usually found at its first one; a forbidden cell costs one read per pixel."""
    blocked = np.zeros(n_cols * n_rows, np.bool_)
    if not use_mask:
        return blocked
    for i in range(n_rows):
        y0, y1 = _cell_span(i, h_cell, height)
        for j in range(n_cols):
            x0, x1 = _cell_span(j, w_cell, width)
            full = True
            for y in range(y0, y1):
                row = mask[mrows[y]]
                for x in range(x0, x1):
                    if row[mcols[x]] != 0:
                        full = False
                        break
                if not full:
                    break
            blocked[i * n_cols + j] = full
    return blocked


@njit(cache=True, nogil=True)
def _grown_rows(a, rows):
    """A copy of the 2-D ``a`` with room for at least ``rows`` rows."""
    b = np.empty((max(rows, 2 * a.shape[0], 64), a.shape[1]), a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True, nogil=True)
def _split_columns(out, n):
    """x, y (int64), score (uint8), cell and level (int64) arrays of ``out[:n]``."""
    xs = np.empty(n, np.int64)
    ys = np.empty(n, np.int64)
    ss = np.empty(n, np.uint8)
    cs = np.empty(n, np.int64)
    ls = np.empty(n, np.int64)
    for k in range(n):
        xs[k], ys[k], ss[k], cs[k], ls[k] = out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4]
    return xs, ys, ss, cs, ls


@njit(cache=True, nogil=True)
def detect_cells(src, base, stride, width, height, t_hi, t_lo, n_cols, n_rows, w_cell, h_cell,
                 mask, mrows, mcols, use_mask, work, flags, keep, positions):
    """FAST keypoints of the ``width`` x ``height`` region at ``src[base + y * stride + x]``,
    ORB-SLAM's way: the region is cut into ``n_rows`` x ``n_cols`` cells whose tested
    ranges ``[3 + j w_cell, min(3 + (j + 1) w_cell, width - 3))`` (likewise rows) tile
    ``[3, width - 3) x [3, height - 3)``; each cell is FAST at ``t_hi`` on its own, i.e.
    non-max suppression sees only neighbours inside the cell; a cell left without
    keypoints is FAST at ``t_lo`` on its own (no retry if ``t_lo < 0``). One cell covering
    the region (``n_cols = n_rows = 1``, ``w_cell >= width - 6``) is plain OpenCV FAST.

    ``mask[mrows[y], mcols[x]] == 0`` forbids region pixel (x, y) (after suppression,
    like FAST's mask), if ``use_mask``. ``work``, ``flags``, ``keep``: uint8 buffers of at
    least ``width * height``; ``positions``: int64 buffer of as many.

    How: ``_fast_pass`` at ``t_hi`` over the whole region, then at ``t_lo`` over each band
    of cell rows that holds a cell left empty, for its empty cells only. A cell the mask
    forbids entirely is skipped in both passes (nothing found there could be kept).

    Returns x, y (region pixels, int64), score (uint8) and cell index of the keypoints,
    cell by cell in raster order and row-major inside a cell (ORB-SLAM's order)."""
    cells = np.empty(positions.size, np.int64)
    out, n = _detect_region(src, base, stride, width, height, t_hi, t_lo, n_cols, n_rows, w_cell, h_cell,
                            mask, mrows, mcols, use_mask, work, flags, keep, positions, cells,
                            np.empty((64, 5), np.int64), 0, 0)
    xs, ys, ss, cs, _ = _split_columns(out, n)
    return xs, ys, ss, cs


@njit(cache=True, nogil=True)
def detect_pyramid(src, bases, stride, widths, heights, grids, t_hi, t_lo, mask, mrows, mcols, map_first,
                   use_mask, work, flags, keep, positions, cells):
    """``detect_cells`` on every level of a pyramid whose levels' regions all live in
    ``src`` with row stride ``stride``: level ``l``'s region starts at ``bases[l]`` and is
    ``widths[l]`` x ``heights[l]`` with cells ``grids[l]`` = (n_cols, n_rows, w_cell,
    h_cell); its mask maps are ``mrows[map_first[l, 0]:]`` and ``mcols[map_first[l, 1]:]``;
    ``cells``: int64 buffer like ``positions``. One call per frame (instead of one per
    level). Returns x, y, score, cell and level of the keypoints, level by level, each in
    ORB-SLAM's order."""
    out = np.empty((4096, 5), np.int64)
    n = 0
    for lv in range(bases.size):
        h, w = heights[lv], widths[lv]
        out, n = _detect_region(src, bases[lv], stride, w, h, t_hi, t_lo, grids[lv, 0], grids[lv, 1],
                                grids[lv, 2], grids[lv, 3], mask, mrows[map_first[lv, 0]:map_first[lv, 0] + h],
                                mcols[map_first[lv, 1]:map_first[lv, 1] + w], use_mask, work, flags, keep,
                                positions, cells, out, n, lv)
    return _split_columns(out, n)


# --------------------------------------------------------------------------- STDC-SLAM

@njit(cache=True, nogil=True)
def _plain_fast(src, base, stride, width, height, t, mask, mrows, mcols, use_mask, work, flags, keep, positions,
                cells, out, level):
    """Plain OpenCV FAST at ``t`` on the whole region (one cell, so non-max suppression
    sees across ORB-SLAM's cell borders), masked after suppression: rows (x, y, score,
    0, level) of ``out`` in row-major order; returns (out, count)."""
    return _detect_region(src, base, stride, width, height, t, -1, 1, 1, max(width - 6, 1), max(height - 6, 1),
                          mask, mrows, mcols, use_mask, work, flags, keep, positions, cells, out, 0, level)


@njit(cache=True, nogil=True)
def _low_prefix(lo, m, t_hi, n_cols, w_cell, h_cell, n_cells, deficit):
    """Algorithm 2's low points, in place in ``lo[:m]`` (row-major): those of score below
    ``t_hi`` (the others are the high pass's points again), then only those of the cells
    inserted in raster order while the level was short of ``deficit``: cell ``c`` is
    inserted iff the low points of the cells before it number fewer than ``deficit``.
    Their cells go to column 3. Returns how many remain."""
    k_out = 0
    per_cell = np.zeros(n_cells, np.int64)
    for k in range(m):
        if lo[k, 2] < t_hi:
            c = ((lo[k, 1] - 3) // h_cell) * n_cols + (lo[k, 0] - 3) // w_cell
            lo[k_out] = lo[k]
            lo[k_out, 3] = c
            per_cell[c] += 1
            k_out += 1
    inserted = np.zeros(n_cells, np.bool_)
    before = 0
    for c in range(n_cells):
        inserted[c] = before < deficit
        before += per_cell[c]
    m = 0
    for k in range(k_out):
        if inserted[lo[k, 3]]:
            lo[m] = lo[k]
            m += 1
    return m


@njit(cache=True, nogil=True)
def _append_in_cell_order(hi, m_hi, lo, m_lo, width, n_cols, w_cell, h_cell, n_cells, out, n):
    """Append the high (``hi[:m_hi]``) and low (``lo[:m_lo]``) points of a level to
    ``out`` from row ``n`` on as rows (x, y, score, high, level), sorted by (cell, y, x):
    the two row-major lists merged (high first on a tie, which cannot happen), then a
    stable counting sort by cell. Returns (out, new row count)."""
    m = m_hi + m_lo
    if out.shape[0] < n + m:
        out = _grown_rows(out, n + m)
    merged = np.empty((m, 6), np.int64)  # x, y, score, cell, level, high
    i = j = 0
    for k in range(m):
        take_hi = j >= m_lo or (i < m_hi and hi[i, 1] * width + hi[i, 0] <= lo[j, 1] * width + lo[j, 0])
        row = hi[i] if take_hi else lo[j]
        for col in range(5):
            merged[k, col] = row[col]
        merged[k, 5] = 1 if take_hi else 0
        if take_hi:
            merged[k, 3] = ((row[1] - 3) // h_cell) * n_cols + (row[0] - 3) // w_cell
            i += 1
        else:
            j += 1
    first = np.zeros(n_cells + 1, np.int64)
    for k in range(m):
        first[merged[k, 3] + 1] += 1
    for c in range(n_cells):
        first[c + 1] += first[c]
    for k in range(m):
        c = merged[k, 3]
        r = n + first[c]
        first[c] += 1
        out[r, 0], out[r, 1], out[r, 2] = merged[k, 0], merged[k, 1], merged[k, 2]
        out[r, 3], out[r, 4] = merged[k, 5], merged[k, 4]
    return out, n + m


@njit(cache=True, nogil=True)
def detect_two_thresholds_pyramid(src, bases, stride, widths, heights, grids, t_hi, t_lo, n_wanted, mask, mrows,
                                  mcols, map_first, use_mask, work, flags, keep, positions, cells):
    """STDC-SLAM's Algorithm 2 (two-threshold FAST) on every level of a pyramid laid out
    as for ``detect_pyramid`` (same arguments, plus ``n_wanted``: each level's budget
    ``N_i``): ``P^H`` = plain FAST at ``t_hi`` on the level's whole region; if
    ``|P^H| < N_i``, plain FAST at ``t_lo`` on it, whose points of score < ``t_hi`` are
    ``P^L``, inserted cell by cell (ORB-SLAM's cells ``grids[l]``) in raster order until
    ``|P^H| + |P^L| >= N_i``. The mask drops points after suppression, before counting.

    Returns x, y, score (uint8), high (0/1), level (int64 each) of the points, level by
    level and in (cell, y, x) order inside a level, and per level ``|P^H|`` and the
    number of low points inserted."""
    n_levels = bases.size
    n_high = np.zeros(n_levels, np.int64)
    n_low = np.zeros(n_levels, np.int64)
    out = np.empty((4096, 5), np.int64)
    hi = np.empty((4096, 5), np.int64)
    lo = np.empty((64, 5), np.int64)
    n = 0
    for lv in range(n_levels):
        h, w = heights[lv], widths[lv]
        n_cols, n_rows, w_cell, h_cell = grids[lv, 0], grids[lv, 1], grids[lv, 2], grids[lv, 3]
        mr = mrows[map_first[lv, 0]:map_first[lv, 0] + h]
        mc = mcols[map_first[lv, 1]:map_first[lv, 1] + w]
        hi, m_hi = _plain_fast(src, bases[lv], stride, w, h, t_hi, mask, mr, mc, use_mask, work, flags, keep,
                               positions, cells, hi, lv)
        n_high[lv] = m_hi
        m_lo = 0
        deficit = n_wanted[lv] - m_hi
        if deficit > 0:
            lo, m_all = _plain_fast(src, bases[lv], stride, w, h, t_lo, mask, mr, mc, use_mask, work, flags, keep,
                                    positions, cells, lo, lv)
            m_lo = _low_prefix(lo, m_all, t_hi, n_cols, w_cell, h_cell, n_cols * n_rows, deficit)
        n_low[lv] = m_lo
        out, n = _append_in_cell_order(hi, m_hi, lo, m_lo, w, n_cols, w_cell, h_cell, n_cols * n_rows, out, n)
    xs, ys, ss, high, ls = _split_columns(out, n)
    return xs, ys, ss, high, ls, n_high, n_low
