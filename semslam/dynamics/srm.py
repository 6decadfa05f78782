"""STDC-SLAM's Segmentation Refinement Module (SRM, Hu et al. 2022, Sec. III-B, Algorithm 1).

Segmentation nets cut dynamic objects short at their borders; SRM grows the dynamic set
along continuous depth. For every dynamic pixel i and every pixel j in the
``window x window`` square centred at i (17x17 in the paper), j becomes dynamic when

    |d_i - d_j| <= tau                    (tau = 0.1 m in the paper, after Blitz-SLAM)

so D^o is a subset of D^n and nothing is added across a depth jump larger than tau. One
pass, no iteration: a pixel is added only if a pixel of the *input* set is within the
window, so the mask grows by at most ``window // 2`` pixels.

Notes on the paper and choices made here:

* The paper says the 17x17 mask holds "389 points"; a 17x17 window has 17 * 17 = 289.
* Pixels without depth (0, negative or not finite) neither propagate (a dynamic pixel
  without depth adds nothing) nor get added (a static pixel without depth stays static):
  "no measurement" is not "same depth". Input dynamic pixels without depth stay dynamic.
* The window is clipped at the image border.
* Depth is taken as float32 (semslam's depth type; other dtypes are converted first) and
  the comparison is evaluated as ``abs(float64(d_i) - float64(d_j)) <= float64(tau)`` in
  both implementations, so the fast one equals the brute-force one bit for bit.

``refine_brute_force`` is Algorithm 1 as written (for tests). ``refine_segmentation`` is
exact and fast: a window min-filter and max-filter (cv2.erode / cv2.dilate) over the
depths of the dynamic pixels decide almost every pixel - a pixel whose depth is within
tau of the window's nearest-below or nearest-above extreme has a witness, one whose depth
lies outside [min - tau, max + tau] of the window has none, since rounding is monotone.
Only pixels whose depth lies strictly inside the window's dynamic depth range but more
than tau from both extremes (e.g. between a person and the wall behind where the mask
bleeds onto the wall) are checked exactly against all window pixels, in chunks.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from semslam.dynamics.masks import bounding_box

# Pixels decided by the exact window check at once (x window^2 float32 values in memory).
_CHUNK = 4096


def _check_inputs(dynamic: NDArray[np.bool_], depth: NDArray[np.floating], window: int, tau: float) -> None:
    if dynamic.ndim != 2 or depth.shape != dynamic.shape:
        raise ValueError(f"dynamic mask {dynamic.shape} and depth {depth.shape} must be the same HxW")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be odd and >= 1, got {window}")
    if not tau >= 0.0:
        raise ValueError(f"tau must be >= 0, got {tau}")


def valid_depth(depth: NDArray[np.floating]) -> NDArray[np.bool_]:
    """Where the sensor measured something: finite and > 0."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth) & (depth > 0)


def refine_brute_force(
    dynamic: NDArray[np.bool_], depth: NDArray[np.floating], window: int = 17, tau: float = 0.1
) -> NDArray[np.bool_]:
    """Algorithm 1 literally: loop over dynamic pixels, add window pixels within tau in depth."""
    _check_inputs(dynamic, depth, window, tau)
    dyn = dynamic.astype(bool)
    depth = np.asarray(depth, np.float32)
    valid = valid_depth(depth)
    d = np.where(valid, depth, 0).astype(np.float64)
    out = dyn.copy()
    h, w = dyn.shape
    r = window // 2
    tau64 = float(tau)
    for y, x in np.argwhere(dyn & valid):
        ys, xs = slice(max(0, y - r), min(h, y + r + 1)), slice(max(0, x - r), min(w, x + r + 1))
        out[ys, xs] |= valid[ys, xs] & (np.abs(d[ys, xs] - d[y, x]) <= tau64)
    return out


def refine_segmentation(
    dynamic: NDArray[np.bool_], depth: NDArray[np.floating], window: int = 17, tau: float = 0.1
) -> NDArray[np.bool_]:
    """SRM: D^n from the dynamic mask D^o and a depth image in metres (0 = no depth).

    Exactly ``refine_brute_force``; a few ms at 640x480 on real depth.
    """
    _check_inputs(dynamic, depth, window, tau)
    dyn = np.asarray(dynamic, dtype=bool)
    out = dyn.copy()
    r = window // 2
    box = bounding_box(dyn, r)
    if box is None:
        return out
    # Work inside the bounding box of everything a dynamic pixel can reach.
    y0, y1, x0, x1 = box
    raw = np.asarray(depth[y0:y1, x0:x1], np.float32)
    valid = valid_depth(raw)
    d = np.where(valid, raw, np.float32(0))
    s = dyn[y0:y1, x0:x1] & valid  # seeds: dynamic pixels with depth
    if not s.any():
        return out

    kernel = np.ones((window, window), np.uint8)
    lo = cv2.erode(np.where(s, d, np.float32(np.inf)), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    hi = cv2.dilate(np.where(s, d, np.float32(0)), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0.0)

    # Candidates: static, with depth, and a seed within the window (hi > 0).
    cand = hi > 0
    cand &= valid
    cand &= ~dyn[y0:y1, x0:x1]
    py, px = np.nonzero(cand)
    if py.size == 0:
        return out
    dj, mn, mx = d[py, px], lo[py, px], hi[py, px]
    tau64 = float(tau)
    # Witness test: is the window's nearest-below or nearest-above seed within tau?
    # Screened in float32 (exact but for differences within 2^-21 of tau), those
    # rechecked in float64, the precision of the definition.
    tau_lo, tau_hi = np.float32(tau64 * (1.0 - 2.0**-21)), np.float32(tau64 * (1.0 + 2.0**-21))
    e_mn, e_mx = np.abs(mn - dj), np.abs(mx - dj)
    add = (e_mn <= tau_lo) | (e_mx <= tau_lo)
    close = np.flatnonzero(~add & ((e_mn <= tau_hi) | (e_mx <= tau_hi)))
    if close.size:
        dj64 = dj[close].astype(np.float64)
        add[close] = (np.abs(mn[close] - dj64) <= tau64) | (np.abs(mx[close] - dj64) <= tau64)
    # Neither extreme is a witness. If d_j is below the minimum or above the maximum, no
    # seed can be (monotone rounding); otherwise a seed inside the range might be.
    amb = np.flatnonzero(~add & (mn < dj) & (dj < mx))
    if amb.size:
        add[amb] = _exact_window_check(d, s, py[amb], px[amb], dj[amb].astype(np.float64), r, tau64)
    out[y0 + py[add], x0 + px[add]] = True
    return out


def _exact_window_check(
    d: NDArray[np.float32],
    seeds: NDArray[np.bool_],
    py: NDArray[np.intp],
    px: NDArray[np.intp],
    dj: NDArray[np.float64],
    r: int,
    tau: float,
) -> NDArray[np.bool_]:
    """For each (py, px): is there a seed in its window with |d_i - d_j| <= tau?

    Gathers the window's seed depths (chunked) and compares in float32, which is exact
    except within a relative 2^-22 of tau; rows with a difference that close are redone
    in float64, so the result is the float64 predicate.
    """
    # Seed depths padded by r; +inf marks "no seed" (never within tau, never borderline).
    padded = np.full((d.shape[0] + 2 * r, d.shape[1] + 2 * r), np.inf, np.float32)
    inner = padded[r : r + d.shape[0], r : r + d.shape[1]]
    inner[seeds] = d[seeds]
    windows = sliding_window_view(padded, (2 * r + 1, 2 * r + 1))  # (H, W, win, win), no copy
    # float32 |a - b| has relative error <= 2^-24: below tau_lo it is surely <= tau, above
    # tau_hi surely > tau.
    tau_lo = np.float32(tau * (1.0 - 2.0**-21))
    tau_hi = np.float32(tau * (1.0 + 2.0**-21))
    dj32 = dj.astype(np.float32)
    hit = np.empty(py.size, bool)
    for a in range(0, py.size, _CHUNK):
        b = min(py.size, a + _CHUNK)
        vals = windows[py[a:b], px[a:b]].reshape(b - a, -1)  # gathered copy
        vals -= dj32[a:b, None]
        np.abs(vals, out=vals)
        hit[a:b] = (vals <= tau_lo).any(axis=1)
        close = np.flatnonzero(~hit[a:b] & (vals <= tau_hi).any(axis=1))
        for k in close:  # rare: a difference within rounding of tau
            row = windows[py[a + k], px[a + k]].astype(np.float64)
            hit[a + k] = bool((np.abs(row - dj[a + k]) <= tau).any())
    return hit
