"""ORB-SLAM's quadtree keypoint distribution (``ORBextractor::DistributeOctTree``) and
STDC-SLAM's improved one (Algorithm 3). The two differ only in their ``SplitRule``.

``distribute_quadtree_leaves`` runs the compiled node-by-node version
(``orb.quadtree_kernels``); ``distribute_quadtree_leaves_numpy`` is the vectorised numpy
one it replaced, kept as the reference (same selection, tests): one numpy round splits
the leaves of the trees of *all* pyramid levels at once (a main-phase pass or a
last-phase round per level), so a frame costs about as many numpy rounds as the
deepest tree instead of one Python step per node.

The semantics per level are ORB-SLAM's (``SplitRule.ORB_SLAM``):
- ``round(W/H)`` initial nodes side by side (at least 1), empty ones dropped;
- a main pass splits every node holding more than one point into its non-empty
  quarters, the split lines at ``ceil(size/2)`` in integer node coordinates (points
  left of / above the line go to the left / top child);
- stop when there are at least ``n_wanted`` nodes or a pass did not change the count;
- when the next full pass could overshoot (``nodes + 3 * splittable > n_wanted``), split
  the nodes with the most points first, one at a time, until ``n_wanted`` is reached
  (this may overshoot by up to 3, as in ORB-SLAM); each further round only considers
  the children made in the previous round;
- keep the highest-response point of each node, the first in input order among ties.

``SplitRule.HIGH_QUALITY`` (STDC-SLAM, Hu et al. 2023, Algorithm 3; choices in
``semslam.features.qtree_orb``): a node splits only if it holds > 1 points *and* >= 1
high-quality point and is larger than 1x1 px; a level stops at ``n_wanted`` nodes or
when no node can split (instead of "a pass changed nothing"), and the state is checked
before the first pass too; the response is Harris.

Deviations: in that last phase ORB-SLAM orders nodes with equal point counts by heap
address (``std::sort`` of ``pair<int, ExtractorNode*>``), which is arbitrary; we order
them by their top-left corner in raster order, so the result is deterministic. A level
with ``n_wanted <= 0`` keeps nothing (ORB-SLAM would still run one pass)."""

from __future__ import annotations

from enum import Enum

import numpy as np
from numpy.typing import NDArray

from semslam.features.orb.quadtree_kernels import HIGH_QUALITY, ORB_SLAM, quadtree_levels, work_size
from semslam.features.orb.scratch import Scratch, kernel_array

_MAIN, _FINE, _DONE = 0, 1, 2  # per-level phase


class _Leaves:
    """The leaves of all trees as parallel 1-D integer arrays (2-D fancy indexing is
    ~10x slower in numpy)."""

    __slots__ = ("x0", "y0", "x1", "y1", "count", "level", "n_old")

    def __init__(self, x0: NDArray[np.int64], y0: NDArray[np.int64], x1: NDArray[np.int64], y1: NDArray[np.int64],
                 count: NDArray[np.int64], level: NDArray[np.int64], n_old: int) -> None:
        self.x0, self.y0, self.x1, self.y1 = x0, y0, x1, y1  # half-open [x0, x1) x [y0, y1)
        self.count, self.level = count, level
        self.n_old = n_old  # leaves [n_old:] were made by the last round

    def __len__(self) -> int:
        return len(self.count)


class SplitRule(str, Enum):
    """Which leaves may split and when a level stops; see the module doc."""

    ORB_SLAM = "orb_slam"
    HIGH_QUALITY = "high_quality"


_MAX_ROUNDS = 256  # safety net only: every split shrinks a node, so depth is ~log2(size)


def distribute_quadtree_levels(x: NDArray[np.integer], y: NDArray[np.integer], response: NDArray[np.floating],
                               level: NDArray[np.integer], widths: NDArray[np.integer],
                               heights: NDArray[np.integer], n_wanted: NDArray[np.integer],
                               high: NDArray[np.bool_] | None = None,
                               rule: SplitRule = SplitRule.ORB_SLAM, scratch: Scratch | None = None
                               ) -> NDArray[np.intp]:
    """See ``distribute_quadtree_leaves``; returns the kept indices only."""
    return distribute_quadtree_leaves(x, y, response, level, widths, heights, n_wanted, high,
                                      rule, scratch)[0]


def distribute_quadtree_leaves(x: NDArray[np.integer], y: NDArray[np.integer], response: NDArray[np.floating],
                               level: NDArray[np.integer], widths: NDArray[np.integer],
                               heights: NDArray[np.integer], n_wanted: NDArray[np.integer],
                               high: NDArray[np.bool_] | None = None,
                               rule: SplitRule = SplitRule.ORB_SLAM, scratch: Scratch | None = None
                               ) -> tuple[NDArray[np.intp], NDArray[np.int64]]:
    """Indices (sorted) of the points the quadtree keeps, for all levels at once, and
    every point's final leaf (-1 for points of levels with ``n_wanted <= 0``, which keep
    nothing); the arguments are ``distribute_quadtree_leaves_numpy``'s, whose selection
    this compiled version reproduces (leaves may be numbered differently). ``scratch``
    keeps the work buffer from call to call."""
    n = len(x)
    if rule is SplitRule.HIGH_QUALITY and high is None:
        raise ValueError("SplitRule.HIGH_QUALITY needs every point's quality (high)")
    quality = np.zeros(n, np.uint8) if high is None else kernel_array(np.asarray(high, bool).view(np.uint8), np.uint8)
    level = kernel_array(level, np.int64)
    xf, yf = kernel_array(x, np.float64), kernel_array(y, np.float64)
    if n and (level.min() < 0 or level.max() >= len(n_wanted)):
        raise ValueError("every point's level must index n_wanted")
    if n and (min(xf.min(), yf.min()) < 0 or max(xf.max(), yf.max()) >= 2**16):
        raise ValueError("positions must be in [0, 65536) (the compiled quadtree packs them in 16 bits)")
    keep, leaf = quadtree_levels(
        xf, yf,
        kernel_array(response, np.float64), level, kernel_array(widths, np.int64), kernel_array(heights, np.int64),
        kernel_array(n_wanted, np.int64), quality,
        HIGH_QUALITY if rule is SplitRule.HIGH_QUALITY else ORB_SLAM,
        (scratch or Scratch()).get("quadtree", (work_size(n),), np.int64))
    return keep.astype(np.intp), leaf


def distribute_quadtree_leaves_numpy(x: NDArray[np.integer], y: NDArray[np.integer],
                                     response: NDArray[np.floating], level: NDArray[np.integer],
                                     widths: NDArray[np.integer], heights: NDArray[np.integer],
                                     n_wanted: NDArray[np.integer], high: NDArray[np.bool_] | None = None,
                                     rule: SplitRule = SplitRule.ORB_SLAM
                                     ) -> tuple[NDArray[np.intp], NDArray[np.int64]]:
    """Indices (sorted) of the points the quadtree keeps, for all levels at once
    (vectorised numpy; the reference of ``distribute_quadtree_leaves``).

    ``x``, ``y``: positions (FAST's are integers) in each level's distribution frame
    (ORB-SLAM: level pixels minus the EDGE_THRESHOLD-3 border), within ``[0, widths[l])
    x [0, heights[l])``; ``level``: each point's level; ``response`` ranks the points of
    a leaf; ``n_wanted[l]``: the level's feature budget; ``high``: each point's quality
    (only ``SplitRule.HIGH_QUALITY`` reads it). Within a level the input order is
    ORB-SLAM's ``vToDistributeKeys`` order (cell by cell, row-major inside a cell) and
    decides response ties.

    Returns the kept indices and every point's final leaf (-1 for points of levels with
    ``n_wanted <= 0``, which keep nothing), e.g. to check that a leaf keeps exactly its
    best point."""
    x_in = np.asarray(x)
    level_in = np.asarray(level, np.int64)
    widths = np.asarray(widths, np.int64)
    heights = np.asarray(heights, np.int64)
    n_wanted = np.asarray(n_wanted, np.int64)
    n_levels = len(n_wanted)
    if rule is SplitRule.HIGH_QUALITY and high is None:
        raise ValueError("SplitRule.HIGH_QUALITY needs every point's quality (high)")
    leaf_all = np.full(len(x_in), -1, np.int64)
    idx = np.flatnonzero(n_wanted[level_in] > 0) if len(x_in) else np.zeros(0, np.intp)
    if len(idx) == 0:
        return np.zeros(0, np.intp), leaf_all
    lv = level_in[idx]
    resp = np.asarray(response, np.float64)[idx]
    hi_idx = np.flatnonzero(np.asarray(high, bool)[idx]) if rule is SplitRule.HIGH_QUALITY else None
    # Bounds are integers, so comparing floor(x) is the same as comparing x.
    px = np.floor(x_in[idx]).astype(np.int64)
    py = np.floor(np.asarray(y)[idx]).astype(np.int64)

    # Initial nodes: round(W/H) vertical strips (C++ round: half away from zero), bounds
    # int(hX * i) and a point's strip int(x / hX), in float32 like ORB-SLAM.
    n_ini = np.maximum(1, np.floor(widths / np.maximum(heights, 1) + 0.5).astype(np.int64))
    hx = widths.astype(np.float32) / n_ini.astype(np.float32)
    first = np.concatenate([[0], np.cumsum(n_ini)])
    strip_level = np.repeat(np.arange(n_levels), n_ini)
    strip_i = (np.arange(first[-1]) - first[strip_level]).astype(np.float32)
    strip_x0 = (strip_i * hx[strip_level]).astype(np.int64)
    strip_x1 = ((strip_i + 1) * hx[strip_level]).astype(np.int64)
    strip = (np.minimum((x_in[idx].astype(np.float32) / hx[lv]).astype(np.int64), n_ini[lv] - 1)
             + first[lv])
    counts = np.bincount(strip, minlength=first[-1])
    nonempty = np.flatnonzero(counts)  # empty nodes are dropped
    remap = np.full(first[-1], -1, np.int64)
    remap[nonempty] = np.arange(len(nonempty))
    node_of = remap[strip]
    sl = strip_level[nonempty]
    # ORB-SLAM always runs one full pass first (the initial nodes are "old"); Algorithm 3
    # counts them as "just made", so the first state update can send a level straight to
    # the last phase (the results differ only for budgets below ~4 nodes per strip).
    n_old = len(nonempty) if rule is SplitRule.ORB_SLAM else 0
    leaves = _Leaves(strip_x0[nonempty], np.zeros(len(nonempty), np.int64), strip_x1[nonempty], heights[sl],
                     counts[nonempty], sl, n_old)

    state = np.full(n_levels, _MAIN, np.int64)
    state[np.bincount(lv, minlength=n_levels) == 0] = _DONE
    can = _splittable(leaves, node_of, rule, hi_idx)
    prev = np.bincount(leaves.level, minlength=n_levels)
    if rule is SplitRule.HIGH_QUALITY:
        prev = _advance(state, leaves, can, prev, n_wanted, rule)
    for _ in range(_MAX_ROUNDS):
        if (state == _DONE).all():
            break
        # Candidates: every splittable leaf of a main-phase level; the splittable leaves
        # made by the previous round of a last-phase level.
        lstate = state[leaves.level]
        which = can & (lstate == _MAIN)
        fine_cand = can & (lstate == _FINE)
        fine_cand[:leaves.n_old] = False
        leaves, node_of = _split_round(leaves, node_of, px, py, which, fine_cand, prev, n_wanted, heights, widths)
        can = _splittable(leaves, node_of, rule, hi_idx)
        prev = _advance(state, leaves, can, prev, n_wanted, rule)

    keep = _best_per_leaf(node_of, resp, len(leaves))
    leaf_all[idx] = node_of
    return idx[keep], leaf_all


def _splittable(leaves: _Leaves, node_of: NDArray[np.int64], rule: SplitRule,
                hi_idx: NDArray[np.intp] | None) -> NDArray[np.bool_]:
    """ORB-SLAM: a leaf with more than one point. Algorithm 3 case 1: also at least one
    high-quality point, and larger than 1x1 px (a 1x1 node holds at most one distinct
    pixel, so refusing it only guards against duplicates)."""
    multi = leaves.count > 1
    if rule is SplitRule.ORB_SLAM:
        return multi
    leaf_high = np.bincount(node_of[hi_idx], minlength=len(leaves))
    return multi & (leaf_high > 0) & ((leaves.x1 - leaves.x0 > 1) | (leaves.y1 - leaves.y0 > 1))


def _advance(state: NDArray[np.int64], leaves: _Leaves, can: NDArray[np.bool_],
             prev: NDArray[np.int64], n_wanted: NDArray[np.int64], rule: SplitRule
             ) -> NDArray[np.int64]:
    """State update after a round (in place) and the new leaf count per level.

    Stop at ``n_wanted`` nodes, or when the level is stuck: ORB-SLAM's "the pass did not
    change the count", Algorithm 3's "no node can split" (splittable leaves are always
    ones made by the last round: the others were split or cannot be). Go to the last
    phase when the next full pass could overshoot (``nodes + 3 * splittable > n_wanted``)."""
    now = np.bincount(leaves.level, minlength=len(state))
    new = slice(leaves.n_old, None)
    n_expandable = np.bincount(leaves.level[new][can[new]], minlength=len(state))
    stuck = (now == prev) if rule is SplitRule.ORB_SLAM else (n_expandable == 0)
    stop = (now >= n_wanted) | stuck
    to_fine = (state == _MAIN) & ~stop & (now + 3 * n_expandable > n_wanted)
    state[stop] = _DONE
    state[to_fine] = _FINE
    return now


def _split(leaves: _Leaves, node_of: NDArray[np.int64], moved: NDArray[np.intp], key: NDArray[np.int64],
           which: NDArray[np.bool_], midx: NDArray[np.int64], midy: NDArray[np.int64]
           ) -> tuple[_Leaves, NDArray[np.int64]]:
    """Replace the leaves flagged in ``which`` by their non-empty quarters; ``moved`` are
    the points of those leaves and ``key`` their 4 * leaf + quarter (0 = top-left n1,
    1 = top-right n2, 2 = bottom-left n3, 3 = bottom-right n4). Returns the new leaves
    (unsplit ones first) and every point's leaf."""
    n = len(leaves)
    child_count = np.bincount(key, minlength=4 * n)
    child_keys = np.flatnonzero(child_count)
    keep = np.flatnonzero(~which)
    n_keep = len(keep)
    # Relabel with lookup tables (O(n), no sort).
    relabel = np.empty(4 * n, np.int64)
    relabel[child_keys] = np.arange(n_keep, n_keep + len(child_keys))
    old_to_new = np.empty(n, np.int64)
    old_to_new[keep] = np.arange(n_keep)
    node_of = old_to_new[node_of]
    node_of[moved] = relabel[key]

    cp = child_keys >> 2
    right = (child_keys & 1).astype(bool)
    bottom = (child_keys & 2).astype(bool)
    cmx, cmy = midx[cp], midy[cp]
    leaves = _Leaves(
        np.concatenate([leaves.x0[keep], np.where(right, cmx, leaves.x0[cp])]),
        np.concatenate([leaves.y0[keep], np.where(bottom, cmy, leaves.y0[cp])]),
        np.concatenate([leaves.x1[keep], np.where(right, leaves.x1[cp], cmx)]),
        np.concatenate([leaves.y1[keep], np.where(bottom, leaves.y1[cp], cmy)]),
        np.concatenate([leaves.count[keep], child_count[child_keys]]),
        np.concatenate([leaves.level[keep], leaves.level[cp]]),
        n_keep,
    )
    return leaves, node_of


def _best_per_leaf(node_of: NDArray[np.int64], response: NDArray[np.float64], n_leaves: int) -> NDArray[np.intp]:
    """Sorted indices of each leaf's highest-response point, the first in input order
    among ties (ORB-SLAM keeps the first maximum it meets)."""
    best = np.full(n_leaves, -np.inf)
    np.maximum.at(best, node_of, response)
    idx = np.flatnonzero(response == best[node_of])
    first = np.full(n_leaves, len(node_of), np.intp)
    np.minimum.at(first, node_of[idx], idx)
    return np.sort(first)


def distribute_quadtree(x: NDArray[np.integer], y: NDArray[np.integer], response: NDArray[np.floating],
                        width: int, height: int, n_wanted: int) -> NDArray[np.intp]:
    """``distribute_quadtree_levels`` for one level: indices (sorted) of the kept points."""
    x = np.asarray(x)
    return distribute_quadtree_levels(x, y, response, np.zeros(len(x), np.int64), np.array([width]),
                                      np.array([height]), np.array([n_wanted]))


def _split_round(leaves: "_Leaves", node_of: NDArray[np.intp], px: NDArray, py: NDArray, which: NDArray[np.bool_],
                 fine_cand: NDArray[np.bool_], prev: NDArray, n_wanted: NDArray, heights: NDArray, widths: NDArray
                 ) -> tuple["_Leaves", NDArray[np.intp]]:
    """One round of splits: every ``which`` leaf, plus the last-phase candidates
    ``fine_cand`` taken largest first while their level is below ``n_wanted`` (shared by
    ORB-SLAM's quadtree and STDC-SLAM's improved one, which differ only in the candidates)."""
    n = len(leaves)
    pts = np.flatnonzero((which | fine_cand)[node_of])
    parent = node_of[pts]
    midx = (leaves.x0 + leaves.x1 + 1) >> 1  # ORB-SLAM: UL + ceil((UR - UL) / 2)
    midy = (leaves.y0 + leaves.y1 + 1) >> 1
    key = 4 * parent + (px[pts] >= midx[parent]) + 2 * (py[pts] >= midy[parent])
    fine = np.flatnonzero(fine_cand)
    if len(fine):
        # Largest first (ties: raster order of the top-left corner); split a
        # candidate iff its level had not reached n_wanted before it, which is
        # ORB-SLAM's one-by-one loop with its break.
        n_quarters = np.count_nonzero(np.bincount(key, minlength=4 * n).reshape(n, 4), axis=1)
        lv = leaves.level[fine]
        big = np.int64(max(int(heights.max()), int(widths.max())) + 1)
        sort_key = ((lv * (len(px) + 1) - leaves.count[fine]) * big + leaves.y0[fine]) * big + leaves.x0[fine]
        s = np.argsort(sort_key)
        order, lv = fine[s], lv[s]
        gain = n_quarters[order] - 1
        cum = np.cumsum(gain)
        seg_start = np.ones(len(order), bool)
        seg_start[1:] = lv[1:] != lv[:-1]
        base = np.maximum.accumulate(np.where(seg_start, np.arange(len(order)), 0))
        cum_excl = cum - gain - (cum[base] - gain[base])
        which[order[prev[lv] + cum_excl < n_wanted[lv]]] = True
        moving = which[parent]
        pts, key = pts[moving], key[moving]
    leaves, node_of = _split(leaves, node_of, pts, key, which, midx, midy)
    return leaves, node_of
