"""Multi-view geometry check for moving content (DDL-SLAM Algorithm 1, after DynaSLAM).

Keypoints with depth from the reference keyframes that overlap most with the current
frame are back-projected and projected into the current frame with its (low-cost,
semantically masked) pose estimate. Where the current frame measures the surface clearly
*in front of* the projected point, something moved in between: a dynamic seed. Points seen
under a parallax angle above 30 degrees are skipped (likely self-occlusion, DynaSLAM).
Seeds are then grown over the current depth image: depth-continuous regions (split at
depth jumps) whose tested points are mostly dynamic become the dynamic mask. This finds
movers no semantic class covers (a pushed box, a moved chair).

A refinement of ours, measured on the rendered sequences: a static object in front of
the background also hides background points that a reference keyframe saw beside it, once
the camera has moved (a desk leg, a chair post): seeds that are wrong, on static objects.
Seen from the reference camera, the static occluder stands displaced from the hidden point
by a parallax of ``f * b * (1/z_front - 1/z_back)`` pixels (``b``: the camera displacement
across the ray); if an edge of the occluder lies within that displacement of the seed, in
its direction, the seed is ambiguous and not counted either way. On 16 frames of
static_xyz with exact poses (5 reference views 8-40 frames back), regions were found in 9
(up to 2.1 % of the image); with this test in none at downscale 2 and in 1 at downscale 4,
while the box of walking_box stays found (``tests/test_multiview_box.py``).

Depth-continuous regions also leak: a walking person's feet join the floor in depth, and
a region found dynamic then takes the floor with it. Regions are therefore eroded by a few
pixels before they are labelled (thin bridges break) and grown back once found dynamic: on
walking_xyz, with the poses SLAM estimates, the static area masked fell from 0.85 % to
0.06 % of the image on average (12 % to 0 % at most) at downscale 4.

Which keyframes: DynaSLAM and DDL-SLAM take those that overlap most with the current frame.
When the map inserts keyframes on consecutive frames (tracking weakens while a mover covers
the view) those are a frame or two old, and a mover that slowed down, stood still or just
started moving has not moved the ~0.2 m the depth test needs since: on the full
``walking_box`` render the box, left standing, was mapped and then lifted, and tracking
followed it (15.1 cm ATE). ``pick_references`` prefers the best-overlapping keyframes at
least ``multiview_min_age_s`` old (0.64 cm with 0.7 s; README, Dynamic scenes).

Pure functions of arrays; ``reference_views`` picks the keyframes to compare against from
the reference keyframe's covisibility.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import DynamicsConfig
from semslam.dynamics.multiview_kernels import occluder_on_segments, project_and_test
from semslam.geometry.camera import PinholeCamera

#: Seeds within the parallax bound plus this many pixels of a depth edge are ambiguous.
PARALLAX_MARGIN_PX = 2.0
#: Regions are eroded by this many full-resolution pixels (at least one pixel at the check's
#: resolution) before they are labelled, and grown back once found dynamic.
BRIDGE_PX = 4
#: Samples along each seed's occluder segment at most.
MAX_STEPS = 16
#: The reference keyframes are picked among the tracking reference keyframe and this many
#: minus one of its best covisibles: those overlap most with the frame.
CANDIDATES = 30

Reference = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]


@dataclass
class MultiViewResult:
    mask: NDArray[np.bool_]
    seeds: NDArray[np.float64]  # (K, 2) pixel positions of dynamic seeds
    n_tested: int


@dataclass
class TestedPoints:
    """Reference keypoints projected into the current frame and tested there."""

    uv: NDArray[np.float64]  # (N, 2) pixels
    z_proj: NDArray[np.float64]  # depth of the projected point
    z_meas: NDArray[np.float32]  # depth the current frame measures at that pixel
    ref_centre: NDArray[np.float64]  # (N, 3) the reference camera's centre, current camera frame
    dynamic: NDArray[np.bool_]  # measured clearly in front of the projected point


def pick_references(stamps: Sequence[float], now: float, n: int, min_age_s: float) -> list[int]:
    """Indices of the ``n`` reference keyframes to test against, from candidates given best
    overlap first (their timestamps ``stamps``): those at least ``min_age_s`` older than
    ``now`` in that order, then, if too few, the younger ones in that order."""
    old = [i for i, t in enumerate(stamps) if t <= now - min_age_s]
    young = [i for i, t in enumerate(stamps) if t > now - min_age_s]
    return (old + young)[:n]


class ReferenceKeyframe(Protocol):
    """What the check reads of a keyframe (``slam.map.KeyFrame``)."""

    bad: bool
    timestamp: float
    T_cw: NDArray[np.float64]
    xy: NDArray[np.float64]
    depth: NDArray[np.float32]

    def best_covisibles(self, n: int) -> Sequence["ReferenceKeyframe"]: ...


class _Candidate(Protocol):
    bad: bool
    timestamp: float

    def best_covisibles(self, n: int) -> Sequence[Any]: ...


RK = TypeVar("RK", bound=_Candidate)


def reference_keyframes(ref: RK, now: float, n: int, min_age_s: float) -> list[RK]:
    """The ``n`` keyframes to test a frame at ``now`` against: among ``ref`` (the tracking
    reference keyframe) and its best covisibles, those with the highest overlap, preferring
    those old enough for a mover to have moved since (``pick_references``)."""
    cands = [k for k in (ref, *ref.best_covisibles(CANDIDATES - 1)) if not k.bad]
    pick = pick_references([k.timestamp for k in cands], now, n, min_age_s)
    return [cands[i] for i in pick]


def reference_views(ref: ReferenceKeyframe, now: float, n: int, min_age_s: float) -> list[Reference]:
    """``reference_keyframes``' pose, keypoints and depths."""
    return [(k.T_cw, k.xy, k.depth) for k in reference_keyframes(ref, now, n, min_age_s)]


def project_references(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                       refs: list[Reference], params: DynamicsConfig = DynamicsConfig()) -> TestedPoints:
    """Project reference keypoints (``refs``: per keyframe ``(T_cw, xy_undistorted, depth)``)
    into the current frame and test their depth there: a point is tested where it lands in
    the image more than 0.1 m in front of the camera, seen under a parallax angle up to
    ``params.parallax_deg`` and on a measured pixel; it is dynamic where the current depth
    is clearly in front of it. One compiled pass (``multiview_kernels``)."""
    if not refs:
        e = np.zeros(0)
        return TestedPoints(np.zeros((0, 2)), e, e.astype(np.float32), np.zeros((0, 3)), np.zeros(0, bool))
    Rs = np.empty((len(refs), 3, 3))
    ts = np.empty((len(refs), 3))
    for k, (T_ref, _, _) in enumerate(refs):
        Rs[k] = T_cw[:3, :3] @ T_ref[:3, :3].T  # ref camera -> current camera
        ts[k] = T_cw[:3, 3] - Rs[k] @ T_ref[:3, 3]  # = the ref camera centre, in the current camera
    xy = np.concatenate([np.asarray(r[1], np.float64).reshape(-1, 2) for r in refs])
    z = np.concatenate([np.asarray(r[2], np.float64).reshape(-1) for r in refs])
    ref_of = np.repeat(np.arange(len(refs)), [len(r[2]) for r in refs])
    uv, zp, zm, centre, dyn = project_and_test(Rs, ts, xy, z, ref_of, depth, (camera.fx, camera.fy, camera.cx, camera.cy),
                                               float(np.cos(np.radians(params.parallax_deg))),
                                               params.depth_threshold_m, params.depth_threshold_rel)
    return TestedPoints(uv, zp, zm, centre, dyn)


def project_references_reference(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                                 refs: list[Reference], params: DynamicsConfig = DynamicsConfig()) -> TestedPoints:
    """``project_references`` in numpy array passes: the reference the compiled kernel is
    tested against (``multiview_kernels``).

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
        e = np.zeros(0)
        return TestedPoints(np.zeros((0, 2)), e, e.astype(np.float32), np.zeros((0, 3)), np.zeros(0, bool))
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
    return TestedPoints(np.stack([u[tested], v[tested]], axis=1), zp, zm, t_ref[tested], dyn)


def dynamic_seeds(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                  refs: list[Reference], params: DynamicsConfig = DynamicsConfig(),
                  ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """(pixels of all tested points, dynamic flags, their projected depths)."""
    pts = project_references(T_cw, depth, camera, refs, params)
    return pts.uv, pts.dynamic, pts.z_proj


def _depth_edges(d: NDArray[np.float32], valid: NDArray[np.bool_], edge_m: float,
                 ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """(pixels next to a depth jump or a hole: region borders; pixels next to a jump between
    two measured pixels or inside a hole wider than one pixel: where occluders end)."""
    border = np.zeros_like(valid)
    jump = np.zeros_like(valid)
    dx = np.abs(np.diff(d, axis=1)) > edge_m
    dy = np.abs(np.diff(d, axis=0)) > edge_m
    for diff, pair, sl_a, sl_b in ((dx, valid[:, 1:] & valid[:, :-1], np.s_[:, 1:], np.s_[:, :-1]),
                                   (dy, valid[1:, :] & valid[:-1, :], np.s_[1:, :], np.s_[:-1, :])):
        border[sl_a] |= diff
        border[sl_b] |= diff
        both = diff & pair
        jump[sl_a] |= both
        jump[sl_b] |= both
    holes = cv2.morphologyEx((~valid).view(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).view(bool)
    return border, jump | holes


def _static_occlusion(points: TestedPoints, dynamic: NDArray[np.bool_], occl: NDArray[np.bool_], s: int,
                      camera: PinholeCamera) -> NDArray[np.bool_]:
    """Seeds a static occluder could explain (see the module doc).

    For a seed at pixel ``p``, the surface measured there (depth ``z_meas``) and the
    reference point behind it (``z_proj``) lie on one ray of the current camera. Seen from
    the reference camera, the front surface point is displaced from the back one by
    ``delta`` pixels; if the front surface is static it then covered the back point only if
    it ends within ``delta`` of ``p`` in the direction of ``-delta``: an edge of an occluder
    (``occl``, at 1/``s`` resolution, at least 3 pixels wide) along that segment makes the
    seed ambiguous. The segment is sampled every 2 pixels of ``occl`` or closer (up to
    ``MAX_STEPS`` samples: segments longer than ``2 * s * MAX_STEPS`` are sampled coarser).
    """
    out = np.zeros(len(dynamic), bool)
    k = np.nonzero(dynamic)[0]
    if len(k) == 0:
        return out
    uv = points.uv[k]
    ray = np.stack([(uv[:, 0] - camera.cx) / camera.fx, (uv[:, 1] - camera.cy) / camera.fy,
                    np.ones(len(k))], axis=1)
    t = points.ref_centre[k]
    front = ray * points.z_meas[k, None].astype(np.float64) - t  # in the reference camera
    back = ray * points.z_proj[k, None] - t  # (its rotation moves both alike: left out)
    f = np.array([camera.fx, camera.fy])
    delta = f * (front[:, :2] / np.maximum(front[:, 2:], 1e-3) - back[:, :2] / np.maximum(back[:, 2:], 1e-3))
    length = np.maximum(np.linalg.norm(delta, axis=1), 1e-9)
    reach = (length + PARALLAX_MARGIN_PX) / length  # a little beyond the displaced point
    steps = int(np.clip(np.ceil((length.max() + PARALLAX_MARGIN_PX) / (2.0 * s)), 1, MAX_STEPS))
    out[k] = occluder_on_segments(uv, delta, reach, np.linspace(0.0, 1.0, steps + 1), occl, s)
    return out


def occluder_on_segments_reference(uv: NDArray[np.float64], delta: NDArray[np.float64], reach: NDArray[np.float64],
                                   lin: NDArray[np.float64], occl: NDArray[np.bool_], s: int) -> NDArray[np.bool_]:
    """``multiview_kernels.occluder_on_segments`` in numpy (a seeds x samples array): the
    reference the compiled kernel is tested against."""
    lam = lin[None, :, None] * reach[:, None, None]
    q = (uv[:, None, :] - lam * delta[:, None, :]) / s
    hl, wl = occl.shape
    qu = np.clip(np.rint(q[..., 0]).astype(np.intp), 0, wl - 1)
    qv = np.clip(np.rint(q[..., 1]).astype(np.intp), 0, hl - 1)
    return occl[qv, qu].any(axis=1)


def grow_regions(depth: NDArray[np.float32], uv: NDArray[np.float64], dynamic: NDArray[np.bool_],
                 params: DynamicsConfig = DynamicsConfig(), points: TestedPoints | None = None,
                 camera: PinholeCamera | None = None) -> NDArray[np.bool_]:
    """Depth-continuous regions where enough tested points are dynamic (full resolution).

    With ``points`` and ``camera``, seeds a static occluder could explain are left out
    (see the module doc).
    """
    h, w = depth.shape
    if np.count_nonzero(dynamic) < params.min_seeds:  # no region can qualify
        return np.zeros((h, w), bool)
    s = max(int(params.downscale), 1)
    d = np.ascontiguousarray(depth[::s, ::s])
    valid = d > 0
    border, occl = _depth_edges(d, valid, params.edge_m)
    occl = cv2.dilate(occl.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    inner = (valid & ~border).view(np.uint8)
    r = max(1, round(BRIDGE_PX / s))  # erode first: thin bridges (feet on the floor) break
    inner = cv2.erode(inner, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    n, labels = cv2.connectedComponents(inner, connectivity=4)
    hl, wl = d.shape
    u = np.clip((uv[:, 0] / s).astype(np.intp), 0, wl - 1)
    v = np.clip((uv[:, 1] / s).astype(np.intp), 0, hl - 1)
    counted = np.ones(len(uv), bool)
    if points is not None and camera is not None:
        counted = ~_static_occlusion(points, dynamic, occl, s, camera)
        if np.count_nonzero(dynamic & counted) < params.min_seeds:
            return np.zeros((h, w), bool)
    u, v, dyn_c = u[counted], v[counted], dynamic[counted]
    lab = labels[v, u]
    tested = np.bincount(lab, minlength=n)
    ndyn = np.bincount(lab, weights=dyn_c.astype(float), minlength=n)
    is_dyn = (ndyn >= params.min_seeds) & (ndyn >= params.min_dynamic_ratio * tested)
    is_dyn[0] = False  # label 0 = edges and holes
    if not is_dyn.any():
        return np.zeros((h, w), bool)
    small = is_dyn[labels]
    # The eroded rim and the edge pixels next to a dynamic region belong to it (silhouettes).
    k = 2 * r + 3
    small = cv2.dilate(small.view(np.uint8), np.ones((k, k), np.uint8)).astype(bool) & (valid | small)
    return cv2.resize(small.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def multiview_mask(T_cw: NDArray[np.float64], depth: NDArray[np.float32], camera: PinholeCamera,
                   refs: list[Reference], params: DynamicsConfig = DynamicsConfig()) -> MultiViewResult:
    pts = project_references(T_cw, depth, camera, refs, params)
    mask = grow_regions(depth, pts.uv, pts.dynamic, params, pts, camera)
    return MultiViewResult(mask, pts.uv[pts.dynamic], len(pts.uv))
