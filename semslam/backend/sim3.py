"""Similarity between two keyframes from matched map points (ORB-SLAM's Sim3Solver and
Optimizer::OptimizeSim3), for loop closing and map merging.

A similarity is a 4x4 matrix ``S_12 = [[s R, t], [0, 1]]`` with ``x1 = s R x2 + t``, where
``x1`` / ``x2`` are the camera-frame coordinates of the same map points in keyframes 1 and
2. RGB-D (and stereo) fix the scale (``with_scale=False`` / ``fix_scale=True``: ``s == 1``
and the matrix is a rigid pose); monocular maps drift in scale, which a loop must correct.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from semslam.geometry.alignment import AlignmentError, umeyama
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.projection import project
from semslam.geometry.se3 import invert, make_pose, so3_exp

Array = NDArray[np.float64]

#: chi2 at 95 % for 2 dof (pixel errors scaled by the keypoint level's inverse sigma^2):
#: the inlier test of ORB-SLAM's Sim3Solver (``mvnMaxError1 = 9.210 * sigmaSquare1``).
CHI2_2DOF = 9.21
#: Below this many inliers after the first round OptimizeSim3 gives up (returns 0).
MIN_OPTIMIZED = 10


class Sim3Fit(NamedTuple):
    """Result of :func:`optimize_similarity`."""

    S12: Array  # refined similarity (the input one when the optimisation gave up)
    inliers: NDArray[np.bool_]  # matches kept (both reprojections under th2)
    n_inliers: int  # 0 when too few matches survived the first round (ORB-SLAM returns 0)


def sim3_parts(S: Array) -> tuple[Array, Array, float]:
    """``(R, t, s)`` of ``S = [[s R, t], [0, 1]]``."""
    A = S[:3, :3]
    s = float(np.cbrt(np.linalg.det(A)))
    return A / s, S[:3, 3].copy(), s


def rigid_part(S: Array) -> Array:
    """The camera pose ``[[R, t / s], [0, 1]]`` of a similarity ``S_cw = [[s R, t], [0, 1]]``:
    what a keyframe keeps of its Sim(3) after a loop correction (ORB-SLAM CorrectLoop /
    OptimizeEssentialGraph: ``eigt *= 1 / s``); it sees every point at the same pixel."""
    R, t, s = sim3_parts(S)
    return make_pose(R, t / s)


def sim3_inverse(S: Array) -> Array:
    """``S^-1 = [[R^T / s, -R^T t / s], [0, 1]]`` (maps frame-1 points into frame 2)."""
    R, t, s = sim3_parts(S)
    return make_pose(R.T / s, -(R.T @ t) / s)


def _hypothesis(R: Array, t: Array, s: float, with_scale: bool) -> tuple[Array, Array]:
    """``S_12`` and ``S_12^-1``; the rigid case goes through ``make_pose`` / ``invert`` as
    ``ransac_se3`` did (same floating-point results)."""
    if not with_scale:
        T = make_pose(R, t)
        return T, invert(T)
    return make_pose(s * R, t), make_pose(R.T / s, -(R.T @ t) / s)


def ransac_similarity(x1: Array, x2: Array, uv1: Array, uv2: Array, inv_s2_1: Array, inv_s2_2: Array,
                      camera: PinholeCamera, rng: np.random.Generator, iterations: int = 300,
                      min_inliers: int = 20, *, with_scale: bool) -> tuple[Array | None, NDArray[np.bool_]]:
    """``S_12`` (4x4, scale in the rotation block) with ``x1 = s R x2 + t`` from matched
    camera-frame points, or ``None`` with the best inlier mask when under ``min_inliers``.

    ORB-SLAM's ``Sim3Solver::iterate``: hypotheses from 3 correspondences (closed form; here
    Umeyama, ORB-SLAM uses Horn, the same least-squares optimum), inliers where both
    reprojections (x2 into image 1 through S, x1 into image 2 through S^-1) have chi2 under
    9.21 with the keypoint level's sigma, stop early above 90 % inliers, and a final refit on
    all inliers. ``with_scale=False`` is the rigid (RGB-D) case: ``s = 1`` exactly.
    """
    n = len(x1)
    best_inl = np.zeros(n, bool)
    best: tuple[Array, Array] | None = None
    if n < max(3, min_inliers):
        return None, best_inl
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy

    def inliers_of(S: Array, S_inv: Array) -> NDArray[np.bool_]:
        p1, z1 = project(S, x2, fx, fy, cx, cy)
        p2, z2 = project(S_inv, x1, fx, fy, cx, cy)
        e1 = ((p1 - uv1) ** 2).sum(1) * inv_s2_1
        e2 = ((p2 - uv2) ** 2).sum(1) * inv_s2_2
        return (z1 > 0) & (z2 > 0) & (e1 < CHI2_2DOF) & (e2 < CHI2_2DOF)

    for _ in range(iterations):
        sample = rng.choice(n, 3, replace=False)
        try:
            R, t, s = umeyama(x2[sample], x1[sample], with_scale=with_scale)
        except AlignmentError:  # colinear or coincident sample: no hypothesis, draw again
            continue
        hyp = _hypothesis(R, t, s, with_scale)
        inl = inliers_of(*hyp)
        if inl.sum() > best_inl.sum():
            best_inl, best = inl, hyp
            if inl.sum() > 0.9 * n:
                break
    if best is None or best_inl.sum() < min_inliers:
        return None, best_inl
    R, t, s = umeyama(x2[best_inl], x1[best_inl], with_scale=with_scale)
    S, S_inv = _hypothesis(R, t, s, with_scale)
    return S, inliers_of(S, S_inv)


def _edge_huber(z: Array) -> Array:
    """Huber on each 2-D reprojection edge, as g2o's RobustKernelHuber (not on each pixel
    coordinate, as scipy's "huber"): residuals come in (u, v) pairs; ``z`` are their squares
    divided by th2. Each coordinate gets the edge's rho' and its share of rho, so cost and
    gradient are exactly those of sum_edges rho(chi2_edge). rho'' is reported as 0: the
    Hessian is then g2o's (J^T rho' J, iteratively reweighted least squares); scipy's
    second-order correction would flatten it for every edge beyond delta, and from a start
    a few degrees off (all edges beyond delta) the trust region then crawls (5 evaluations
    moved a 5 deg / 10 % / 10 cm start by nothing, see tests/test_sim3.py)."""
    ze = z[0::2] + z[1::2]
    inside = ze <= 1.0
    root = np.sqrt(np.maximum(ze, 1e-300))
    rho = np.where(inside, ze, 2.0 * root - 1.0)
    d1 = np.where(inside, 1.0, 1.0 / root)
    share = z / np.repeat(np.maximum(ze, 1e-300), 2)
    return np.stack([np.repeat(rho, 2) * share, np.repeat(d1, 2), np.zeros_like(z)])


def optimize_similarity(S12: Array, x1: Array, x2: Array, uv1: Array, uv2: Array, inv_s2_1: Array,
                        inv_s2_2: Array, camera: PinholeCamera, fix_scale: bool, th2: float = 10.0,
                        iterations: tuple[int, int, int] = (10, 10, 5)) -> Sim3Fit:
    """Refine ``S12`` on the reprojection errors of x2 into image 1 (through S12) and of x1
    into image 2 (through S12^-1): ORB-SLAM's ``Optimizer::OptimizeSim3``.

    Robust (per-edge Huber, delta sqrt(th2), residuals whitened by the level's sigma). Round
    one runs ``iterations[0]`` evaluations; matches with either chi2 over ``th2`` (or a point
    behind a camera) are dropped; under 10 left gives up (``n_inliers == 0``, S12 returned
    as given); round two runs ``iterations[1]`` if some were dropped, else ``iterations[2]``
    (ORB-SLAM: 5, then 10 or 5); the final check flags the matches over th2 again.
    Iterations are scipy ``least_squares`` (trf) function evaluations; the trust region
    spends some on rejected steps where g2o's LM counts only iterations, so round one gets
    10, not 5 (with 5, a start 5 deg / 10 % / 10 cm off a 0.5-scale, 30 deg case kept 29 of
    158 inliers; 8 recovered all, tests/test_sim3.py). Parameters: a rotation vector left of R, the translation and (unless
    ``fix_scale``) the log of the scale.
    """
    R0, t0, s0 = sim3_parts(S12)
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    w1 = np.sqrt(np.asarray(inv_s2_1, float))[:, None]
    w2 = np.sqrt(np.asarray(inv_s2_2, float))[:, None]

    def unpack(p: Array) -> tuple[Array, Array]:
        R = so3_exp(p[:3]) @ R0
        s = s0 if fix_scale else s0 * float(np.exp(p[6]))
        return _hypothesis(R, p[3:6], s, with_scale=True)

    def errors(p: Array, keep: NDArray[np.bool_]) -> tuple[Array, Array, NDArray[np.bool_]]:
        S, S_inv = unpack(p)
        p1, z1 = project(S, x2[keep], fx, fy, cx, cy)
        p2, z2 = project(S_inv, x1[keep], fx, fy, cx, cy)
        return (uv1[keep] - p1) * w1[keep], (uv2[keep] - p2) * w2[keep], (z1 > 0) & (z2 > 0)

    def run(p: Array, keep: NDArray[np.bool_], max_nfev: int) -> Array:
        def fun(q: Array) -> Array:
            e1, e2, _ = errors(q, keep)
            return np.concatenate([e1.ravel(), e2.ravel()])

        return least_squares(fun, p, loss=_edge_huber, f_scale=float(np.sqrt(th2)), method="trf",
                             max_nfev=max(1, max_nfev)).x

    def good(p: Array, keep: NDArray[np.bool_]) -> NDArray[np.bool_]:
        e1, e2, front = errors(p, keep)
        ok = keep.copy()
        ok[keep] = front & ((e1 ** 2).sum(1) <= th2) & ((e2 ** 2).sum(1) <= th2)
        return ok

    p = np.zeros(6 if fix_scale else 7)
    keep = np.ones(len(x1), bool)
    if len(x1) < MIN_OPTIMIZED:
        return Sim3Fit(S12, np.zeros(len(x1), bool), 0)
    p = run(p, keep, iterations[0])
    inl = good(p, keep)
    n_bad = int(keep.sum() - inl.sum())
    if inl.sum() < MIN_OPTIMIZED:
        return Sim3Fit(S12, inl, 0)
    p = run(p, inl, iterations[1] if n_bad > 0 else iterations[2])
    inl = good(p, inl)
    return Sim3Fit(unpack(p)[0], inl, int(inl.sum()))
