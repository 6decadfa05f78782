"""Compiled (numba) quadtree distribution: ORB-SLAM's ``DistributeOctTree`` and
STDC-SLAM's Algorithm 3, node by node as the originals do it, level after level.

Same selection as the vectorised numpy version in ``semslam.features.orb.quadtree``
(which documents the semantics and is kept as the reference; tests compare both on
random and real inputs). Why compiled: the numpy version needs ~25 numpy rounds of
array operations per frame (~1-1.6 ms); a loop over nodes is a few microseconds per
level. ``nogil`` and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["quadtree_levels"]

ORB_SLAM, HIGH_QUALITY = 0, 1  # split rules, as ``quadtree.SplitRule``
_MAIN, _FINE, _DONE = 0, 1, 2  # phase of a level
_MAX_ROUNDS = 256  # as the numpy version (a safety net only)
# Columns of the node table: box [x0, x1) x [y0, y1), points perm[start:start + count]
# (in input order), number of high-quality points, made by the last round, split.
_X0, _Y0, _X1, _Y1, _START, _COUNT, _HIGH, _NEW, _SPLIT = range(9)


@njit(cache=True, nogil=True)
def _splittable(nodes, i, rule):
    """Whether node ``i`` may split. ORB-SLAM: more than one point; Algorithm 3: also a
    high-quality point and larger than 1x1 px."""
    if nodes[i, _COUNT] <= 1:
        return False
    if rule == ORB_SLAM:
        return True
    return nodes[i, _HIGH] > 0 and (nodes[i, _X1] - nodes[i, _X0] > 1 or nodes[i, _Y1] - nodes[i, _Y0] > 1)


@njit(cache=True, nogil=True)
def _divide(nodes, parent, slots, perm, tmp, quarter):
    """Split node ``parent`` into its non-empty quarters (ORB-SLAM's ``DivideNode``: split
    lines at ``ceil(size / 2)``, quarters top-left, top-right, bottom-left,
    bottom-right), partitioning its points (``_pack``ed in ``perm``) stably; child ``k``
    goes to row ``slots[k]``. ``quarter``: int64 (3, 4) work array (no allocation per
    split). Returns the number of children."""
    mx = (nodes[parent, _X0] + nodes[parent, _X1] + 1) >> 1
    my = (nodes[parent, _Y0] + nodes[parent, _Y1] + 1) >> 1
    s, c = nodes[parent, _START], nodes[parent, _COUNT]
    cnt, hi, pos = quarter[0], quarter[1], quarter[2]
    for q in range(4):
        cnt[q] = 0
        hi[q] = 0
    for k in range(s, s + c):
        v = perm[k]
        q = ((v & 0xFFFF) >= mx) + 2 * (((v >> 16) & 0xFFFF) >= my)
        tmp[k] = q
        cnt[q] += 1
        hi[q] += (v >> 32) & 1
    acc = s
    for q in range(4):
        pos[q] = acc
        acc += cnt[q]
    n = perm.size  # tmp[n:] holds the partitioned points
    for k in range(s, s + c):
        q = tmp[k]
        tmp[n + pos[q]] = perm[k]
        pos[q] += 1
    for k in range(s, s + c):
        perm[k] = tmp[n + k]
    m = 0
    acc = s
    for q in range(4):
        if cnt[q] > 0:
            child = slots[m]
            right, bottom = q & 1, q >> 1
            nodes[child, _X0] = mx if right else nodes[parent, _X0]
            nodes[child, _X1] = nodes[parent, _X1] if right else mx
            nodes[child, _Y0] = my if bottom else nodes[parent, _Y0]
            nodes[child, _Y1] = nodes[parent, _Y1] if bottom else my
            nodes[child, _START] = acc
            nodes[child, _COUNT] = cnt[q]
            nodes[child, _HIGH] = hi[q]
            nodes[child, _NEW] = 1
            nodes[child, _SPLIT] = 0
            m += 1
        acc += cnt[q]
    return m


@njit(cache=True, nogil=True, inline="always")
def _pack(index, x, y, high):
    """A point as one int64, ``index << 33 | high << 32 | y << 16 | x``: partitions move
    one word and read nothing else (x, y < 2^16)."""
    return (index << 33) | (np.int64(high) << 32) | (y << 16) | x


@njit(cache=True, nogil=True)
def _sort_by_key(items, key, n):
    """Sort ``items[:n]`` by ``key[:n]`` ascending, in place (insertion sort on a gap
    sequence; keys are distinct). Why not np.argsort: it costs seconds of compile time
    for a few hundred candidates."""
    gap = 1
    while gap < n // 3:
        gap = 3 * gap + 1
    while gap > 0:
        for i in range(gap, n):
            k, it = key[i], items[i]
            j = i
            while j >= gap and key[j - gap] > k:
                key[j], items[j] = key[j - gap], items[j - gap]
                j -= gap
            key[j], items[j] = k, it
        gap //= 3


@njit(cache=True, nogil=True)
def _bucket_starts(bucket, n, n_buckets):
    """Counting sort's offsets for ``bucket[:n]``: (start of each bucket plus the end,
    a copy of the starts to fill from)."""
    first = np.zeros(n_buckets + 1, np.int64)
    for k in range(n):
        first[bucket[k] + 1] += 1
    for b in range(n_buckets):
        first[b + 1] += first[b]
    return first, first[:n_buckets].copy()


@njit(cache=True, nogil=True)
def _advance(state, nodes, alive, n_alive, prev, n_wanted, rule):
    """The level's phase after a round: done at ``n_wanted`` nodes or when stuck
    (ORB-SLAM: the round changed nothing; Algorithm 3: no new node can split); to the
    last phase when the next full pass could overshoot."""
    n_exp = 0
    for a in range(n_alive):
        if nodes[alive[a], _NEW] and _splittable(nodes, alive[a], rule):
            n_exp += 1
    stuck = n_alive == prev if rule == ORB_SLAM else n_exp == 0
    if n_alive >= n_wanted or stuck:
        return _DONE
    if state == _MAIN and n_alive + 3 * n_exp > n_wanted:
        return _FINE
    return state


@njit(cache=True, nogil=True)
def _level(points, lo, hi, xf, px, py, high, width, height, n_wanted, rule, resp, leaf_of, leaf_base, kept, work):
    """The quadtree of one level (points ``points[lo:hi]``, in input order): sets ``kept[p] = 1``
    for the kept points and writes every point's leaf (numbered from ``leaf_base``).
    Returns the number of leaves. ``work``: int64 buffer of ``_level_work(hi - lo)``
    entries for all the arrays (no allocation, so no page faults, per level).

    Nodes live in the rows of a table (columns ``_X0`` ... ``_SPLIT``); rows of split
    nodes are reused after each round (see ``cap``)."""
    n = hi - lo
    # Initial nodes: round(W / H) vertical strips (float32 bounds like ORB-SLAM).
    n_ini = max(1, int(np.floor(width / max(height, 1) + 0.5)))
    hx = np.float32(width) / np.float32(n_ini)
    cap = 2 * n + 8  # node rows, see below
    strip = work[:n]
    perm = work[n:2 * n]
    tmp = work[2 * n:4 * n]
    o = 4 * n
    nodes = work[o:o + 9 * cap].reshape(cap, 9)
    o += 9 * cap
    alive, free, next_alive = work[o:o + cap], work[o + cap:o + 2 * cap], work[o + 2 * cap:o + 3 * cap]
    o += 3 * cap
    cand, key, born = work[o:o + cap], work[o + cap:o + 2 * cap], work[o + 2 * cap:o + 3 * cap]
    for k in range(n):
        strip[k] = min(int(np.float32(xf[points[lo + k]]) / hx), n_ini - 1)
    first, fill = _bucket_starts(strip, n, n_ini)
    for k in range(n):
        p = points[lo + k]
        perm[fill[strip[k]]] = _pack(p, px[p], py[p], high[p])
        fill[strip[k]] += 1
    # Node rows in use during a round: the leaves before it (at most n) plus its
    # children (at most n: they are non-empty and disjoint); free rows are reused first.
    n_alive = 0
    for st in range(n_ini):
        c = first[st + 1] - first[st]
        if c > 0:
            i = n_alive
            nodes[i, _X0] = int(np.float32(st) * hx)
            nodes[i, _X1] = int(np.float32(st + 1) * hx)
            nodes[i, _Y0] = 0
            nodes[i, _Y1] = height
            nodes[i, _START] = first[st]
            nodes[i, _COUNT] = c
            h = 0
            for k in range(first[st], first[st + 1]):
                h += (perm[k] >> 32) & 1
            nodes[i, _HIGH] = h
            # ORB-SLAM always runs a full pass first; Algorithm 3 counts the initial
            # nodes as just made (see the numpy version).
            nodes[i, _NEW] = rule == HIGH_QUALITY
            nodes[i, _SPLIT] = 0
            alive[n_alive] = i
            n_alive += 1
    n_fresh = n_alive  # rows never used yet start here
    n_free = 0
    slots = np.empty(4, np.int64)
    quarter = np.empty((3, 4), np.int64)

    state = _MAIN if n > 0 else _DONE
    prev = n_alive
    if rule == HIGH_QUALITY and state == _MAIN:
        state = _advance(state, nodes, alive, n_alive, prev, n_wanted, rule)
    for _ in range(_MAX_ROUNDS):
        if state == _DONE:
            break
        # Candidates: every splittable leaf (main phase), or the splittable leaves made
        # by the previous round, most points first (last phase; ties by raster order).
        n_cand = 0
        for a in range(n_alive):
            i = alive[a]
            if _splittable(nodes, i, rule) and (state == _MAIN or nodes[i, _NEW]):
                cand[n_cand] = i
                n_cand += 1
            nodes[i, _NEW] = 0
        if state == _FINE:
            big = max(width, height) + 1
            for k in range(n_cand):
                i = cand[k]
                key[k] = ((n - nodes[i, _COUNT]) * big + nodes[i, _Y0]) * big + nodes[i, _X0]
            _sort_by_key(cand, key, n_cand)
        # Split them (the last phase stops as soon as the level has n_wanted nodes).
        now = n_alive
        n_born = 0
        for k in range(n_cand):
            if state == _FINE and now >= n_wanted:
                break
            fresh = n_fresh
            for j in range(4):
                if n_free > 0:
                    n_free -= 1
                    slots[j] = free[n_free]
                else:
                    slots[j] = fresh
                    fresh += 1
            m = _divide(nodes, cand[k], slots, perm, tmp, quarter)
            for j in range(m):
                if slots[j] >= n_fresh:
                    n_fresh = slots[j] + 1
                born[n_born] = slots[j]
                n_born += 1
            for j in range(3, m - 1, -1):  # unused rows back to the free list
                if slots[j] < n_fresh:
                    free[n_free] = slots[j]
                    n_free += 1
            nodes[cand[k], _SPLIT] = 1
            now += m - 1
        # Next leaves: the unsplit ones, then the children; split rows become free.
        n_next = 0
        for a in range(n_alive):
            if nodes[alive[a], _SPLIT]:
                free[n_free] = alive[a]
                n_free += 1
            else:
                next_alive[n_next] = alive[a]
                n_next += 1
        for j in range(n_born):
            next_alive[n_next] = born[j]
            n_next += 1
        alive, next_alive = next_alive, alive
        n_alive = n_next
        state = _advance(state, nodes, alive, n_alive, prev, n_wanted, rule)
        prev = n_alive

    # Keep each leaf's highest-response point, the first in input order among ties.
    for a in range(n_alive):
        s, c = nodes[alive[a], _START], nodes[alive[a], _COUNT]
        best = perm[s] >> 33
        for k in range(s, s + c):
            p = perm[k] >> 33
            leaf_of[p] = leaf_base + a
            if resp[p] > resp[best]:
                best = p
        kept[best] = 1
    return n_alive


@njit(cache=True, nogil=True)
def work_size(n):
    """int64 entries of work buffer ``quadtree_levels`` needs for ``n`` points."""
    return 3 * n + 34 * n + 128


@njit(cache=True, nogil=True)
def quadtree_levels(x, y, response, level, widths, heights, n_wanted, high, rule, work):
    """Indices (sorted) of the points the quadtree keeps, for all levels, and every
    point's final leaf (-1 for points of levels with ``n_wanted <= 0``); see
    ``semslam.features.orb.quadtree.distribute_quadtree_leaves`` for the arguments.
    ``x``, ``y``: float64 in [0, 2^16); ``high``: uint8 (read by ``rule == HIGH_QUALITY``
    only);
    ``work``: int64 buffer of at least ``work_size(n)`` entries (reused by the caller
    from frame to frame; a smaller one is replaced)."""
    n = x.size
    n_levels = n_wanted.size
    if work.size < work_size(n):
        work = np.empty(work_size(n), np.int64)
    px, py, by_level = work[:n], work[n:2 * n], work[2 * n:3 * n]
    level_work = work[3 * n:]
    for i in range(n):
        px[i] = int(np.floor(x[i]))
        py[i] = int(np.floor(y[i]))
    # Points of each level, in input order.
    first, fill = _bucket_starts(level, n, n_levels)
    for i in range(n):
        by_level[fill[level[i]]] = i
        fill[level[i]] += 1
    leaf_of = np.empty(n, np.int64)
    for i in range(n):
        leaf_of[i] = -1
    kept = np.zeros(n, np.uint8)
    leaf_base = 0
    for lv in range(n_levels):
        if n_wanted[lv] > 0 and first[lv + 1] > first[lv]:
            leaf_base += _level(by_level, first[lv], first[lv + 1], x, px, py, high, widths[lv], heights[lv],
                                n_wanted[lv], rule, response, leaf_of, leaf_base, kept, level_work)
    n_kept = 0
    for i in range(n):
        n_kept += kept[i]
    keep = np.empty(n_kept, np.int64)
    j = 0
    for i in range(n):
        if kept[i]:
            keep[j] = i
            j += 1
    return keep, leaf_of
