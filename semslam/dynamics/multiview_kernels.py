"""Compiled kernel behind the multi-view check's projection (numba, ``nogil``, ``cache=True``).

``project_and_test`` is ``multiview.project_references_reference`` in one pass: every
reference keypoint back-projected, moved into the current camera, projected, its parallax
angle and the current depth tested. The numpy version makes ~40 array passes over ~5000
points (1.1 ms a frame on the tracking thread, sequential walking_xyz); this one makes one.
The tests compare it with the numpy version on random inputs (the same points tested and
flagged; positions equal to rounding).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True)
def _project_and_test(R: NDArray[np.float64], t: NDArray[np.float64], xy: NDArray[np.float64],
                      z: NDArray[np.float64], ref_of: NDArray[np.int64], depth: NDArray[np.float32],
                      fx: float, fy: float, cx: float, cy: float, cos_min: float, thr_abs: float,
                      thr_rel: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32],
                                               NDArray[np.float64], NDArray[np.bool_], int]:
    n = len(z)
    h, w = depth.shape
    uv = np.empty((n, 2))
    zp_out = np.empty(n)
    zm_out = np.empty(n, np.float32)
    centre = np.empty((n, 3))
    dyn = np.empty(n, np.bool_)
    m = 0
    for i in range(n):
        zi = z[i]
        if not zi > 0:
            continue
        k = ref_of[i]
        x = (xy[i, 0] - cx) / fx * zi
        y = (xy[i, 1] - cy) / fy * zi
        p0 = x * R[k, 0, 0] + y * R[k, 0, 1] + zi * R[k, 0, 2] + t[k, 0]
        p1 = x * R[k, 1, 0] + y * R[k, 1, 1] + zi * R[k, 1, 2] + t[k, 1]
        p2 = x * R[k, 2, 0] + y * R[k, 2, 1] + zi * R[k, 2, 2] + t[k, 2]
        if not p2 > 0.1:
            continue
        u = fx * p0 / p2 + cx
        v = fy * p1 / p2 + cy
        ui = np.rint(u)
        vi = np.rint(v)
        if not (ui >= 0 and ui < w and vi >= 0 and vi < h):
            continue
        r0, r1, r2 = p0 - t[k, 0], p1 - t[k, 1], p2 - t[k, 2]
        n12 = np.sqrt((r0 * r0 + r1 * r1 + r2 * r2) * (p0 * p0 + p1 * p1 + p2 * p2))
        cosang = (r0 * p0 + r1 * p1 + r2 * p2) / max(n12, 1e-12)
        zm = depth[int(vi), int(ui)]
        if not (cosang >= cos_min and zm > 0):
            continue
        uv[m, 0] = u
        uv[m, 1] = v
        zp_out[m] = p2
        zm_out[m] = zm
        centre[m, 0], centre[m, 1], centre[m, 2] = t[k, 0], t[k, 1], t[k, 2]
        dyn[m] = p2 - np.float64(zm) > thr_abs + thr_rel * p2
        m += 1
    return uv, zp_out, zm_out, centre, dyn, m


def project_and_test(R: NDArray[np.float64], t: NDArray[np.float64], xy: NDArray[np.float64], z: NDArray[np.float64],
                     ref_of: NDArray[np.int64], depth: NDArray[np.float32], camera_fx_fy_cx_cy: tuple[float, ...],
                     cos_min: float, thr_abs: float, thr_rel: float
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32], NDArray[np.float64],
                                NDArray[np.bool_]]:
    """(uv, projected depth, measured depth, reference centre, dynamic) of the points that
    pass the tests. ``R`` (K, 3, 3) / ``t`` (K, 3): reference camera -> current camera;
    ``xy`` (N, 2) undistorted pixels, ``z`` (N,) their depths, ``ref_of`` (N,) their
    reference; ``depth`` the current frame's depth in metres."""
    fx, fy, cx, cy = (float(c) for c in camera_fx_fy_cx_cy)
    uv, zp, zm, centre, dyn, m = _project_and_test(
        np.ascontiguousarray(R, np.float64), np.ascontiguousarray(t, np.float64), np.ascontiguousarray(xy, np.float64),
        np.ascontiguousarray(z, np.float64), np.ascontiguousarray(ref_of, np.int64),
        np.ascontiguousarray(depth, np.float32), fx, fy, cx, cy, float(cos_min), float(thr_abs), float(thr_rel))
    return uv[:m], zp[:m], zm[:m], centre[:m], dyn[:m]


@numba.njit(cache=True, nogil=True)
def _occluder_on_segments(uv: NDArray[np.float64], delta: NDArray[np.float64], reach: NDArray[np.float64],
                          lin: NDArray[np.float64], occl: NDArray[np.bool_], s: float) -> NDArray[np.bool_]:
    hl, wl = occl.shape
    out = np.zeros(len(uv), np.bool_)
    for i in range(len(uv)):
        for j in range(len(lin)):
            lam = lin[j] * reach[i]
            qu = int(min(max(np.rint((uv[i, 0] - lam * delta[i, 0]) / s), 0), wl - 1))
            qv = int(min(max(np.rint((uv[i, 1] - lam * delta[i, 1]) / s), 0), hl - 1))
            if occl[qv, qu]:
                out[i] = True
                break
    return out


def occluder_on_segments(uv: NDArray[np.float64], delta: NDArray[np.float64], reach: NDArray[np.float64],
                         lin: NDArray[np.float64], occl: NDArray[np.bool_], s: int) -> NDArray[np.bool_]:
    """For each seed, whether ``occl`` (at 1/``s`` resolution) is set at any sample
    ``uv - lin[j] * reach * delta`` of its segment (nearest pixel, clipped to the image):
    ``multiview._static_occlusion``'s sampling without its (seeds x samples) arrays."""
    return _occluder_on_segments(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(delta, np.float64),
                                 np.ascontiguousarray(reach, np.float64), np.ascontiguousarray(lin, np.float64),
                                 np.ascontiguousarray(occl, np.bool_), float(s))


def warm_up() -> None:
    """Compile for the types the multi-view check uses (see ``semslam.features.jit``)."""
    project_and_test(np.eye(3)[None], np.zeros((1, 3)), np.ones((1, 2)), np.ones(1), np.zeros(1, np.int64),
                     np.ones((2, 2), np.float32), (1.0, 1.0, 0.5, 0.5), 0.5, 0.1, 0.0)
    occluder_on_segments(np.ones((1, 2)), np.ones((1, 2)), np.ones(1), np.linspace(0.0, 1.0, 2),
                         np.zeros((2, 2), bool), 2)
