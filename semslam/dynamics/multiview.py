"""Multi-view geometry check for moving content (DDL-SLAM Algorithm 1, after DynaSLAM).

Keypoints with depth from the reference keyframes that overlap most with the current
frame are back-projected and projected into the current frame with its (low-cost,
semantically masked) pose estimate. Where the current frame measures the surface clearly
*in front of* the projected point, something moved in between: a dynamic seed. Points seen
under a parallax angle above 30 degrees are skipped (likely self-occlusion, DynaSLAM).
Seeds are then grown over the current depth image: depth-continuous regions (split at
depth jumps) whose tested points are mostly dynamic become the dynamic mask. This finds
movers no semantic class covers (a pushed box, a moved chair).

Pure functions of arrays; the caller chooses the keyframes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import DynamicsConfig
from semslam.geometry.camera import PinholeCamera


@dataclass
class MultiViewResult:
    mask: NDArray[np.bool_]
    seeds: NDArray[np.float64]  # (K, 2) pixel positions of dynamic seeds
    n_tested: int


def dynamic_seeds(
    T_cw: NDArray[np.float64],
    depth: NDArray[np.float32],
    camera: PinholeCamera,
    refs: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]],
    params: DynamicsConfig = DynamicsConfig(),
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """Project reference keypoints (``refs``: per keyframe ``(T_cw, xy_undistorted, depth)``)
    into the current frame. Returns (pixels of all tested points, dynamic flags, their
    projected depths)."""
    h, w = depth.shape
    center = -T_cw[:3, :3].T @ T_cw[:3, 3]
    all_uv, all_dyn, all_z = [], [], []
    cos_max = np.cos(np.radians(params.parallax_deg))
    for T_ref, xy, z in refs:
        ok = z > 0
        if not ok.any():
            continue
        pc = camera.backproject(xy[ok], z[ok])
        R, t = T_ref[:3, :3], T_ref[:3, 3]
        pw = (pc - t) @ R
        ref_center = -R.T @ t
        pcur = pw @ T_cw[:3, :3].T + T_cw[:3, 3]
        zp = pcur[:, 2]
        front = zp > 0.1
        pw, pcur, zp = pw[front], pcur[front], zp[front]
        uv = camera.project(pcur)
        u = np.rint(uv[:, 0]).astype(np.intp)
        v = np.rint(uv[:, 1]).astype(np.intp)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        pw, zp, uv, u, v = pw[inside], zp[inside], uv[inside], u[inside], v[inside]
        r1 = pw - ref_center
        r2 = pw - center
        cosang = np.einsum("ij,ij->i", r1, r2) / np.maximum(np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1), 1e-12)
        zm = depth[v, u]
        tested = (cosang >= cos_max) & (zm > 0)
        thr = params.depth_threshold_m + params.depth_threshold_rel * zp
        dyn = tested & (zp - zm > thr)
        all_uv.append(uv[tested])
        all_dyn.append(dyn[tested])
        all_z.append(zp[tested])
    if not all_uv:
        return np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0)
    return np.concatenate(all_uv), np.concatenate(all_dyn), np.concatenate(all_z)


def grow_regions(depth: NDArray[np.float32], uv: NDArray[np.float64], dynamic: NDArray[np.bool_],
                 params: DynamicsConfig = DynamicsConfig()) -> NDArray[np.bool_]:
    """Depth-continuous regions where enough tested points are dynamic (full resolution)."""
    h, w = depth.shape
    if not dynamic.any():
        return np.zeros((h, w), bool)
    s = max(int(params.downscale), 1)
    d = depth[::s, ::s]
    valid = d > 0
    # Split at depth jumps between 4-neighbours.
    edge = np.zeros_like(valid)
    dx = np.abs(np.diff(d, axis=1)) > params.edge_m
    dy = np.abs(np.diff(d, axis=0)) > params.edge_m
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    n, labels = cv2.connectedComponents((valid & ~edge).view(np.uint8), connectivity=4)
    u = np.clip((uv[:, 0] / s).astype(np.intp), 0, d.shape[1] - 1)
    v = np.clip((uv[:, 1] / s).astype(np.intp), 0, d.shape[0] - 1)
    lab = labels[v, u]
    tested = np.bincount(lab, minlength=n)
    dyn = np.bincount(lab, weights=dynamic.astype(float), minlength=n)
    ratio = dyn / np.maximum(tested, 1)
    is_dyn = (dyn >= params.min_seeds) & (ratio >= params.min_dynamic_ratio)
    is_dyn[0] = False  # label 0 = edges and holes
    small = is_dyn[labels]
    # Edge pixels next to a dynamic region belong to it (silhouettes).
    small = cv2.dilate(small.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (valid | small)
    return cv2.resize(small.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def multiview_mask(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                   refs: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]],
                   params: DynamicsConfig = DynamicsConfig()) -> MultiViewResult:
    uv, dyn, _ = dynamic_seeds(T_cw, depth, camera, refs, params)
    return MultiViewResult(grow_regions(depth, uv, dyn, params), uv[dyn], len(uv))
