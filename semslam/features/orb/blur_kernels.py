"""Compiled (numba) 7-tap fixed-point Gaussian blur of the levels of the stacked pyramid,
the same integer arithmetic as OpenCV's bit-exact ``GaussianBlur`` of 8-bit images.

Why: ORB's descriptor reads a 7x7 sigma-2 blur of every level. OpenCV's call on the
stacked buffer blurs its unused margins too (the buffer is 1.5x the levels' area) and
runs ~1 ns a pixel here (1.3-1.5 ms a frame); this kernel blurs only the levels' pixels,
with a ring of seven horizontally filtered rows that stays in L1 (~0.7 ms). ``nogil``,
cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["gaussian7_levels"]

_I = np.int32


@njit(cache=True, nogil=True, boundscheck=False)
def _horizontal(src, dst, x0, width, c0, c1, c2, c3):
    """dst[x] = sum of the 7 taps around src[x0 + x] (8 fractional bits, exact)."""
    a = src[x0 - 3:x0 + width + 3]  # a slice so the indices below are provably >= 0 (vectorised)
    for x in range(width):
        dst[x] = _I(c0 * (_I(a[x]) + _I(a[x + 6])) + c1 * (_I(a[x + 1]) + _I(a[x + 5]))
                    + c2 * (_I(a[x + 2]) + _I(a[x + 4])) + c3 * _I(a[x + 3]))


@njit(cache=True, nogil=True, boundscheck=False)
def _vertical(r0, r1, r2, r3, r4, r5, r6, dst, x0, width, c0, c1, c2, c3):
    """dst[x0 + x] = the 7 filtered rows' weighted sum, rounded from 16 fractional bits
    like OpenCV's ``ufixedpoint32`` -> ``uint8`` ((v + 2^15) >> 16)."""
    out = dst[x0:x0 + width]
    for x in range(width):
        v = (c0 * (r0[x] + r6[x]) + c1 * (r1[x] + r5[x]) + c2 * (r2[x] + r4[x]) + c3 * r3[x])
        out[x] = np.uint8((v + _I(32768)) >> _I(16))


@njit(cache=True, nogil=True, boundscheck=False)
def gaussian7_levels(buffer, out, rows, widths, heights, pad, coeffs, ring):
    """Blur level ``l`` (``buffer[rows[l]:rows[l] + heights[l], pad:pad + widths[l]]``)
    into the same pixels of ``out`` with the symmetric 7-tap kernel ``coeffs`` = (outer,
    ..., centre) in 8 fractional bits (sum of the 7 taps 256), reading the 3 px of
    padding around the level as its border. ``ring`` is int32 of at least 7 rows x the
    widest level. ``out``'s other pixels are left as they are."""
    c0, c1, c2, c3 = _I(coeffs[0]), _I(coeffs[1]), _I(coeffs[2]), _I(coeffs[3])
    for lv in range(rows.size):
        r, w, h = rows[lv], widths[lv], heights[lv]
        for k in range(h + 6):
            _horizontal(buffer[r - 3 + k], ring[k % 7], pad, w, c0, c1, c2, c3)
            if k >= 6:
                _vertical(ring[(k - 6) % 7], ring[(k - 5) % 7], ring[(k - 4) % 7], ring[(k - 3) % 7],
                          ring[(k - 2) % 7], ring[(k - 1) % 7], ring[k % 7], out[r + k - 6], pad, w,
                          c0, c1, c2, c3)
