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
    projected depths).

    All keyframes' points are transformed in one batch: each point is moved straight from
    its keyframe into the current camera (``T_cw @ T_ref^-1``), and the parallax angle is
    measured there (rays from the two camera centres to the point; rotations keep angles).
    """
    h, w = depth.shape
    pcurs, centres = [], []
    for T_ref, xy, z in refs:
        ok = z > 0
        if not ok.any():
            continue
        R = T_cw[:3, :3] @ T_ref[:3, :3].T  # ref camera -> current camera
        t = T_cw[:3, 3] - R @ T_ref[:3, 3]  # = the ref camera centre, in the current camera
        pcurs.append(camera.backproject(xy[ok], z[ok]) @ R.T + t)
        centres.append(np.broadcast_to(t, (len(pcurs[-1]), 3)))
    if not pcurs:
        return np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0)
    pcur = np.concatenate(pcurs)
    t_ref = np.concatenate(centres)
    zp = pcur[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * pcur[:, 0] / zp + camera.cx
        v = camera.fy * pcur[:, 1] / zp + camera.cy
    ui = np.rint(u)
    vi = np.rint(v)
    keep = (zp > 0.1) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    pcur, t_ref, zp, u, v = pcur[keep], t_ref[keep], zp[keep], u[keep], v[keep]
    ui, vi = ui[keep].astype(np.intp), vi[keep].astype(np.intp)
    r1 = pcur - t_ref  # from the ref camera centre to the point
    n12 = np.sqrt(np.einsum("ij,ij->i", r1, r1) * np.einsum("ij,ij->i", pcur, pcur))
    cosang = np.einsum("ij,ij->i", r1, pcur) / np.maximum(n12, 1e-12)
    zm = depth[vi, ui]
    tested = (cosang >= np.cos(np.radians(params.parallax_deg))) & (zm > 0)
    zp, zm = zp[tested], zm[tested]
    dyn = zp - zm > params.depth_threshold_m + params.depth_threshold_rel * zp
    return np.stack([u[tested], v[tested]], axis=1), dyn, zp


def grow_regions(depth: NDArray[np.float32], uv: NDArray[np.float64], dynamic: NDArray[np.bool_],
                 params: DynamicsConfig = DynamicsConfig()) -> NDArray[np.bool_]:
    """Depth-continuous regions where enough tested points are dynamic (full resolution)."""
    h, w = depth.shape
    if np.count_nonzero(dynamic) < params.min_seeds:  # no region can qualify
        return np.zeros((h, w), bool)
    s = max(int(params.downscale), 1)
    d = np.ascontiguousarray(depth[::s, ::s])
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
    if not is_dyn.any():
        return np.zeros((h, w), bool)
    small = is_dyn[labels]
    # Edge pixels next to a dynamic region belong to it (silhouettes).
    small = cv2.dilate(small.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (valid | small)
    return cv2.resize(small.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def multiview_mask(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                   refs: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]],
                   params: DynamicsConfig = DynamicsConfig()) -> MultiViewResult:
    uv, dyn, _ = dynamic_seeds(T_cw, depth, camera, refs, params)
    return MultiViewResult(grow_regions(depth, uv, dyn, params), uv[dyn], len(uv))
