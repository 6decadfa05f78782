"""Compiled forward splatting: ``forward_warp.warp_static``'s per-source loop in one pass.

The numpy reference (``forward_warp.warp_static_numpy``, which the tests compare with) spends
~15 array operations per projected point; this kernel projects, tests and splats each point
once, into buffers that hold the target's dynamic pixels only (``slot``: flat pixel -> index
among them, -1 elsewhere), small enough to stay in cache. Numba, ``nogil`` (the mapping
thread does not hold the GIL while it warps), ``cache=True``.

The target's lens distortion is OpenCV's Brown-Conrady model (k1 k2 p1 p2 k3), applied to
points already inside the dynamic pixels' undistorted bounding box (so the polynomial never
folds far-off points back into the image); ``test_inpainting`` checks it against
``cv2.projectPoints`` through the reference.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

#: ``win`` holds src_id << ROW_BITS | row of the nearest candidate (-1: none).
ROW_BITS = 40


@numba.njit(cache=True, nogil=True)
def splat_source(pts: NDArray[np.float32], tile_ptr: NDArray[np.int64], tiles: NDArray[np.int64],
                 T: NDArray[np.float64], intr: NDArray[np.float64], dist: NDArray[np.float64],
                 box: NDArray[np.float64], height: int, width: int, quad: bool, min_z: float,
                 slot: NDArray[np.int32], observed: NDArray[np.float32], tol_abs: float, tol_rel: float,
                 src_id: int, zbuf: NDArray[np.float32], seen: NDArray[np.bool_], win: NDArray[np.int64],
                 cand_slot: NDArray[np.int32], cand_z: NDArray[np.float32], cand_row: NDArray[np.int32]) -> int:
    """Splat the points of one source's ``tiles`` (rows tile_ptr[t]:tile_ptr[t + 1]) into the
    target's dynamic-pixel buffers; returns how many candidates it wrote to ``cand_*``.

    ``T``: source to target (4x4); ``intr``: fx fy cx cy; ``dist``: k1 k2 p1 p2 k3 (all zero:
    none); ``box``: x0 x1 y0 y1 around the dynamic pixels in normalised coordinates. A
    candidate lands on dynamic pixels only (``seen``), is dropped when it lies in front of
    ``observed`` (> 0) by more than tol_abs + tol_rel * observed, lowers ``zbuf`` (recording
    itself in ``win``) and is listed in ``cand_*`` (room: 4 per point for ``quad``, else 1)
    for ``accumulate``.
    """
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    distorted = k1 != 0.0 or k2 != 0.0 or p1 != 0.0 or p2 != 0.0 or k3 != 0.0
    n_off = 4 if quad else 1
    tag = np.int64(src_id) << ROW_BITS
    n = 0
    for t in tiles:
        for r in range(tile_ptr[t], tile_ptr[t + 1]):
            px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
            z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
            if z <= min_z:
                continue
            x = (T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]) / z
            y = (T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]) / z
            if x < box[0] or x > box[1] or y < box[2] or y > box[3]:
                continue
            if distorted:
                r2 = x * x + y * y
                radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                x, y = xd, yd
            u = fx * x + cx
            v = fy * y + cy
            if u < -0.5 or u >= width - 0.5 or v < -0.5 or v >= height - 0.5:
                continue
            if quad:
                u0, v0 = int(np.floor(u)), int(np.floor(v))
            else:
                u0, v0 = int(u + 0.5), int(v + 0.5)
            zf = np.float32(z)
            for k in range(n_off):
                ui, vi = u0 + (k & 1), v0 + (k >> 1)
                if ui < 0 or ui >= width or vi < 0 or vi >= height:
                    continue
                s = slot[vi * width + ui]
                if s < 0:
                    continue
                seen[s] = True
                o = observed[s]
                if o > 0.0 and zf < o - (tol_abs + tol_rel * o):
                    continue
                if zf < zbuf[s]:
                    zbuf[s] = zf
                    win[s] = tag | r
                cand_slot[n] = s
                cand_z[n] = zf
                cand_row[n] = r
                n += 1
    return n


@numba.njit(cache=True, nogil=True)
def accumulate(cand_slot: NDArray[np.int32], cand_z: NDArray[np.float32], cand_row: NDArray[np.int32],
               rgb: NDArray[np.uint8], zbuf: NDArray[np.float32], tol_abs: float, tol_rel: float,
               acc: NDArray[np.float32]) -> None:
    """Add (1, z, r, g, b) of every candidate within the tolerance of its pixel's nearest
    depth (``zbuf`` after all sources were splatted) to that pixel's ``acc`` row."""
    for i in range(cand_slot.shape[0]):
        s = cand_slot[i]
        near = zbuf[s]
        z = cand_z[i]
        if z <= near + (tol_abs + tol_rel * near):
            r = cand_row[i]
            acc[s, 0] += 1.0
            acc[s, 1] += z
            acc[s, 2] += rgb[r, 0]
            acc[s, 3] += rgb[r, 1]
            acc[s, 4] += rgb[r, 2]
