"""Compiled (numba) BORDER_REFLECT_101 padding of the levels of the stacked pyramid.

Why: four numpy slice copies per level, two of them 3-column strided ones, cost ~85 us
per frame; one loop over all levels ~10 us. ``nogil``, cached on disk."""

from __future__ import annotations

from numba import njit

__all__ = ["reflect_pad_levels"]


@njit(cache=True, nogil=True)
def reflect_pad_levels(buffer, rows, widths, heights, pad):
    """Fill the ``pad`` px around each level (``buffer[rows[l]:rows[l] + heights[l],
    pad:pad + widths[l]]``) with BORDER_REFLECT_101 of the level: rows first, then
    columns over the padded rows, so the corners are reflected twice like OpenCV's
    ``copyMakeBorder``. Levels must be larger than ``pad`` both ways."""
    for lv in range(rows.size):
        r, w, h = rows[lv], widths[lv], heights[lv]
        for k in range(1, pad + 1):
            for x in range(pad, pad + w):
                buffer[r - k, x] = buffer[r + k, x]
                buffer[r + h - 1 + k, x] = buffer[r + h - 1 - k, x]
        for y in range(r - pad, r + h + pad):
            for k in range(1, pad + 1):
                buffer[y, pad - k] = buffer[y, pad + k]
                buffer[y, pad + w - 1 + k] = buffer[y, pad + w - 1 - k]
