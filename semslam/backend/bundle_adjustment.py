"""Local / global bundle adjustment (ORB-SLAM2 LocalBundleAdjustment, BundleAdjustment).

One function serves both uses: the caller decides which keyframes are free and which are fixed
(local BA: covisible keyframes free, keyframes that also see the local points fixed; global BA:
all keyframes, the first fixed) and passes the observations as flat arrays.

Two solvers minimise the same cost with the same LM schedule: ``solver="schur"`` (default), a
sparse LM with the points eliminated by the Schur complement, compiled with numba
(``backend/schur_ba.py``), and ``solver="gtsam"``, the factor graph below.  They agree to the
solver tolerance (``tests/test_backend.py``); ``benchmarks/backend_timing.py`` measures both:
on ORB-SLAM2's local windows the GTSAM path spends its time building the graph in Python
(one factor object per observation: GTSAM's Python API has a bulk constructor only for
monocular projection factors) and in its generic sparse elimination, the Schur solver ~10x less.

GTSAM modelling:

* poses are ``Pose3`` variables holding ``T_wc`` (GTSAM's camera factors take the camera's pose
  in the world), points are ``Point3`` variables; keys are plain ints (pose k -> k, point j -> K+j);
* ``GenericStereoFactor3D`` with ``Cal3_S2Stereo(fx, fy, 0, cx, cy, baseline=bf/fx)`` for
  observations with ``ur >= 0``, ``GenericProjectionFactorCal3_S2`` otherwise; information
  ``inv_sigma2 * I``, Huber with ORB-SLAM's deltas in the robust stage;
* fixed poses are held by a tight ``PriorFactorPose3`` (sigma 1e-9 rad / m) rather than
  ``NonlinearEqualityPose3``: a Gaussian prior keeps every factor Cholesky-eliminable (the
  equality factor's constrained noise forces the slower QR path), and the sub-nanometre slack it
  leaves is below anything the SLAM can measure.  The returned fixed poses are the inputs
  verbatim, so they do not move at all.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from semslam.backend.gtsam_utils import (
    CHI2_MONO,
    CHI2_STEREO,
    lm_params,
    mono_calibration,
    obs_noise,
    poses_from_rows,
    stereo_calibration,
)
from semslam.backend.schur_ba import levenberg_marquardt, reprojection_chi2
from semslam.geometry.se3 import invert

Array = NDArray[np.float64]

_FIXED_SIGMA = 1e-9

log = logging.getLogger(__name__)


@dataclass
class BAProblem:
    """Keyframe poses, map points and their observations as flat arrays.

    ``obs_pose[m]`` / ``obs_point[m]`` index ``poses_cw`` / ``points_w``; ``ur[m] < 0`` marks an
    observation without depth (monocular); ``inv_sigma2[m] = 1 / scale_factor^(2 octave)``.
    """

    poses_cw: Array  # (K, 4, 4) world -> camera
    pose_fixed: NDArray[np.bool_]  # (K,)
    points_w: Array  # (P, 3)
    obs_pose: NDArray[np.intp]  # (M,)
    obs_point: NDArray[np.intp]  # (M,)
    uv: Array  # (M, 2)
    ur: Array  # (M,)
    inv_sigma2: Array  # (M,)
    fx: float
    fy: float
    cx: float
    cy: float
    bf: float
    # Relative-pose links between keyframes (the IMU's motion between consecutive ones):
    # ``poses_cw[link_pose[l, 1]] ~ link_T[l] @ poses_cw[link_pose[l, 0]]`` with information
    # ``link_info[l]`` (6x6 on the residual (Log(dR), dt) of ``link_T T_a T_b^-1``, in b's frame).
    link_pose: NDArray[np.intp] = field(default_factory=lambda: np.zeros((0, 2), np.intp))
    link_T: Array = field(default_factory=lambda: np.zeros((0, 4, 4)))
    link_info: Array = field(default_factory=lambda: np.zeros((0, 6, 6)))


@dataclass
class BAResult:
    """Optimised poses/points, the observations the caller should keep, and diagnostics.

    ``inlier_obs[m]`` is False for observations ORB-SLAM would erase from the map (chi2 above the
    95 % threshold or the point at/behind the camera at the final estimate).  ``initial_error``
    and ``final_error`` are the mean chi2 over the final inliers at the input and output
    estimates (so both average the same residuals).
    """

    poses_cw: Array
    points_w: Array
    inlier_obs: NDArray[np.bool_]
    initial_error: float
    final_error: float
    time_ms: float
    # Where the time went (CPU ms of the solving thread): "build" (graph / index arrays),
    # "optimize" (the LM solves), "check" (chi2 of every observation); and "iterations" (LM
    # linearisations, both stages).  ``time_ms`` is wall time.
    timings: dict[str, float] = field(default_factory=dict)
    # False when an LM solve threw (e.g. an indeterminant system): the estimate of that
    # stage was left unchanged, and the caller counts it as a failed BA.
    converged: bool = True


def reprojection_errors(problem: BAProblem, poses_cw: Array, points_w: Array) -> Array:
    """(M,) chi2 = inv_sigma2 * |obs - proj|^2 of every observation; inf where depth <= 0.

    Monocular observations (``ur < 0``) contribute the 2 image residuals, the others also the
    virtual right coordinate ``ur = u - bf / z``.
    """
    problem = _normalized(problem)
    poses_cw = np.asarray(poses_cw, dtype=np.float64).reshape(-1, 4, 4)
    return reprojection_chi2(np.ascontiguousarray(poses_cw[:, :3, :3]),
                             np.ascontiguousarray(poses_cw[:, :3, 3]),
                             np.ascontiguousarray(points_w, dtype=np.float64).reshape(-1, 3),
                             problem.obs_pose, problem.obs_point,
                             np.ascontiguousarray(problem.uv), np.ascontiguousarray(problem.ur),
                             np.ascontiguousarray(problem.inv_sigma2), problem.fx, problem.fy,
                             problem.cx, problem.cy, problem.bf)


def _normalized(p: BAProblem) -> BAProblem:
    """The problem with every field as a numpy array of the expected dtype and shape."""
    m = np.asarray(p.obs_pose).size
    return BAProblem(
        poses_cw=np.asarray(p.poses_cw, dtype=np.float64).reshape(-1, 4, 4),
        pose_fixed=np.asarray(p.pose_fixed, dtype=bool).reshape(-1),
        points_w=np.asarray(p.points_w, dtype=np.float64).reshape(-1, 3),
        obs_pose=np.asarray(p.obs_pose, dtype=np.intp).reshape(m),
        obs_point=np.asarray(p.obs_point, dtype=np.intp).reshape(m),
        uv=np.asarray(p.uv, dtype=np.float64).reshape(m, 2),
        ur=np.asarray(p.ur, dtype=np.float64).reshape(m),
        inv_sigma2=np.broadcast_to(np.asarray(p.inv_sigma2, dtype=np.float64), (m,)),
        fx=float(p.fx), fy=float(p.fy), cx=float(p.cx), cy=float(p.cy), bf=float(p.bf),
        link_pose=np.asarray(p.link_pose, dtype=np.intp).reshape(-1, 2),
        link_T=np.asarray(p.link_T, dtype=np.float64).reshape(-1, 4, 4),
        link_info=np.asarray(p.link_info, dtype=np.float64).reshape(-1, 6, 6))


def _chi2_threshold(problem: BAProblem) -> Array:
    return np.where(problem.ur >= 0, CHI2_STEREO, CHI2_MONO)


def _constrained_points(problem: BAProblem, active: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Points that the active observations determine: >= 1 stereo or >= 2 observations.

    Deviation from ORB-SLAM (which keeps any point with an edge and lets g2o's damping hold the
    rest): a point seen once without depth has a free depth direction; GTSAM's LM would have
    to fight an indeterminant system for it, so such points are left out and keep their value.
    """
    n_pts = problem.points_w.shape[0]
    stereo = problem.ur >= 0
    n_obs = np.bincount(problem.obs_point[active], minlength=n_pts)
    n_st = np.bincount(problem.obs_point[active & stereo], minlength=n_pts)
    return (n_st >= 1) | (n_obs >= 2)


def _build_graph(problem: BAProblem, active: NDArray[np.bool_], robust: bool,
                 Ks: gtsam.Cal3_S2Stereo, Km: gtsam.Cal3_S2) -> gtsam.NonlinearFactorGraph:
    """Factor graph of the active observations plus priors on the fixed poses that are used.

    Per-factor Python is kept to one constructor call: noise models come from a per-octave
    cache, monocular factors are inserted in C++ batches per (pose, octave) through
    ``gtsam.utilities.insertProjectionFactors``, and stereo factors are built from plain lists.
    """
    K = problem.poses_cw.shape[0]
    graph = gtsam.NonlinearFactorGraph()
    stereo = problem.ur >= 0
    levels, level_idx = np.unique(problem.inv_sigma2, return_inverse=True)

    st = np.flatnonzero(active & stereo)
    if st.size:
        models = [obs_noise(3, float(s), robust) for s in levels]
        add = graph.push_back
        SF = gtsam.GenericStereoFactor3D
        SP = gtsam.StereoPoint2
        for u, v, r, lv, pk, lk in zip(problem.uv[st, 0].tolist(), problem.uv[st, 1].tolist(),
                                       problem.ur[st].tolist(), level_idx[st].tolist(),
                                       problem.obs_pose[st].tolist(),
                                       (problem.obs_point[st] + K).tolist()):
            add(SF(SP(u, r, v), models[lv], pk, lk, Ks))

    mo = np.flatnonzero(active & ~stereo)
    if mo.size:
        models = [obs_noise(2, float(s), robust) for s in levels]
        group = problem.obs_pose[mo] * len(levels) + level_idx[mo]
        order = np.argsort(group, kind="stable")
        mo, group = mo[order], group[order]
        starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        ends = np.r_[starts[1:], mo.size]
        for s, e in zip(starts.tolist(), ends.tolist()):
            idx = mo[s:e]
            gtsam.utilities.insertProjectionFactors(
                graph, int(problem.obs_pose[idx[0]]),
                (problem.obs_point[idx] + K).astype(np.float64),
                np.ascontiguousarray(problem.uv[idx].T), models[int(level_idx[idx[0]])], Km)

    used = np.zeros(K, bool)
    used[problem.obs_pose[active]] = True
    for (a, b), Z, info in zip(problem.link_pose.tolist(), problem.link_T, problem.link_info):
        if used[a] and used[b]:  # T_wc_a^-1 T_wc_b = Z^-1: GTSAM's residual is Log of the same dT
            graph.push_back(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(invert(Z)),
                                                     gtsam.noiseModel.Gaussian.Information(info)))
    prior = gtsam.noiseModel.Isotropic.Sigma(6, _FIXED_SIGMA)
    for k in np.flatnonzero(used & problem.pose_fixed).tolist():
        graph.push_back(gtsam.PriorFactorPose3(k, gtsam.Pose3(invert(problem.poses_cw[k])), prior))
    return graph


def _values(poses_wc: Array, points_w: Array, pose_keys: Array, point_idx: Array) -> gtsam.Values:
    K = poses_wc.shape[0]
    values = gtsam.Values()
    for k in pose_keys.tolist():
        values.insert(k, gtsam.Pose3(poses_wc[k]))
    for j, p in zip(point_idx.tolist(), points_w[point_idx]):
        values.insert(K + j, p)
    return values


class _Clock:
    """Accumulates the CPU milliseconds (of the solving thread) per phase of one bundle
    adjustment: CPU rather than wall time, as the machine is shared."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {"build": 0.0, "optimize": 0.0, "check": 0.0, "iterations": 0.0}
        self._t = time.thread_time()

    def lap(self, phase: str) -> None:
        t = time.thread_time()
        self.ms[phase] += (t - self._t) * 1e3
        self._t = t


def _optimize_gtsam(problem: BAProblem, poses_cw: Array, points_w: Array,
                    active: NDArray[np.bool_], robust: bool, iterations: int,
                    clock: _Clock) -> tuple[Array, Array, bool]:
    """One GTSAM LM solve over the active observations (already restricted to determined
    points); returns updated (poses_cw, points_w) and whether the solve succeeded (on
    failure the inputs come back unchanged)."""
    K = poses_cw.shape[0]
    pose_keys = np.unique(problem.obs_pose[active])
    point_idx = np.unique(problem.obs_point[active])
    Ks = stereo_calibration(problem.fx, problem.fy, problem.cx, problem.cy, problem.bf)
    Km = mono_calibration(problem.fx, problem.fy, problem.cx, problem.cy)
    graph = _build_graph(problem, active, robust, Ks, Km)
    values = _values(invert(poses_cw), points_w, pose_keys, point_idx)
    # Schur-style elimination order: points first (each only touches its few cameras), then poses.
    ordering = gtsam.Ordering()
    for key in (point_idx + K).tolist():
        ordering.push_back(key)
    for key in pose_keys.tolist():
        ordering.push_back(key)
    params = lm_params(iterations)
    params.setOrdering(ordering)
    # Measured on the 10-KF / 3000-point case: sequential Cholesky ~30 ms per solve against
    # ~45 ms multifrontal (the frontal cliques are tiny 3x3 point blocks).
    params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
    clock.lap("build")
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = optimizer.optimize()
    except RuntimeError as exc:  # e.g. an indeterminant system LM's damping could not rescue
        # ORB-SLAM's g2o never throws; a failed BA must not take the mapping thread down.
        log.warning("bundle adjustment failed (%s); estimate left unchanged",
                    str(exc).strip()[:200])
        clock.lap("optimize")
        return poses_cw, points_w, False
    clock.ms["iterations"] += optimizer.iterations()
    clock.lap("optimize")

    poses_cw = poses_cw.copy()
    points_w = points_w.copy()
    free = pose_keys[~problem.pose_fixed[pose_keys]]
    if free.size:
        # Values iterate in key order, so extracted pose rows follow pose_keys, points point_idx.
        wc = poses_from_rows(gtsam.utilities.extractPose3(result))
        poses_cw[free] = invert(wc[~problem.pose_fixed[pose_keys]])
    points_w[point_idx] = gtsam.utilities.extractPoint3(result)
    clock.lap("build")
    return poses_cw, points_w, True


def _optimize_schur(problem: BAProblem, poses_cw: Array, points_w: Array,
                    active: NDArray[np.bool_], robust: bool, iterations: int,
                    clock: _Clock) -> tuple[Array, Array, bool]:
    """The same solve as :func:`_optimize_gtsam` by ``schur_ba.levenberg_marquardt``."""
    obs = np.flatnonzero(active)
    opose = problem.obs_pose[obs]
    point_idx, opoint = np.unique(problem.obs_point[obs], return_inverse=True)
    used = np.unique(opose)
    free = used[~problem.pose_fixed[used]]
    pose_var = np.full(poses_cw.shape[0], -1, np.intp)
    pose_var[free] = np.arange(free.size)
    pt_obs = np.argsort(opoint, kind="stable").astype(np.intp)
    pt_ptr = np.zeros(point_idx.size + 1, np.intp)
    np.cumsum(np.bincount(opoint, minlength=point_idx.size), out=pt_ptr[1:])
    clock.lap("build")
    R, t, X, n_it, ok, _, _ = levenberg_marquardt(
        np.ascontiguousarray(poses_cw[:, :3, :3]), np.ascontiguousarray(poses_cw[:, :3, 3]),
        np.ascontiguousarray(points_w[point_idx]), opose.astype(np.intp), opoint.astype(np.intp),
        np.ascontiguousarray(problem.uv[obs]), np.ascontiguousarray(problem.ur[obs]),
        np.ascontiguousarray(problem.inv_sigma2[obs]), problem.fx, problem.fy, problem.cx,
        problem.cy, problem.bf, robust, float(np.sqrt(CHI2_MONO)), float(np.sqrt(CHI2_STEREO)),
        pose_var, free.astype(np.intp), pt_ptr, pt_obs, int(iterations), problem.link_pose,
        np.ascontiguousarray(problem.link_T[:, :3, :3]), np.ascontiguousarray(problem.link_T[:, :3, 3]),
        np.ascontiguousarray(problem.link_info))
    clock.ms["iterations"] += n_it
    clock.lap("optimize")
    if not ok:
        log.warning("bundle adjustment failed (no positive definite damped system); "
                    "estimate left unchanged")
        return poses_cw, points_w, False
    poses_cw = poses_cw.copy()
    points_w = points_w.copy()
    poses_cw[free, :3, :3] = R[free]
    poses_cw[free, :3, 3] = t[free]
    points_w[point_idx] = X
    clock.lap("build")
    return poses_cw, points_w, True


def _optimize(problem: BAProblem, poses_cw: Array, points_w: Array, active: NDArray[np.bool_],
              robust: bool, iterations: int, solver: str,
              clock: _Clock) -> tuple[Array, Array, bool]:
    """One LM solve over the active observations whose points they determine."""
    pts_ok = _constrained_points(problem, active)
    active = active & pts_ok[problem.obs_point]
    if iterations <= 0 or not active.any():
        return poses_cw, points_w, True
    solve = _optimize_schur if solver == "schur" else _optimize_gtsam
    return solve(problem, poses_cw, points_w, active, robust, iterations, clock)


SOLVERS = ("schur", "gtsam")


def bundle_adjust(problem: BAProblem, iterations: tuple[int, int] = (5, 10), robust: bool = True,
                  remove_outliers: bool = True, solver: str = "schur") -> BAResult:
    """ORB-SLAM2 (local) bundle adjustment: robust LM, outlier removal, plain LM.

    Stage 1 runs ``iterations[0]`` LM iterations (Huber if ``robust``).  With
    ``remove_outliers`` (local BA), observations with chi2 above 5.991 / 7.815 or non-positive
    depth are dropped and stage 2 runs ``iterations[1]`` more without the kernel.  Without it
    (ORB-SLAM's global BA, 10 robust iterations there) a single stage with the whole budget
    ``iterations[0] + iterations[1]`` runs.  In both cases
    ``inlier_obs`` reports the observations that pass the chi2 / depth test at the end, which
    the caller erases from the map as ORB-SLAM does with ``vToErase``.

    Free poses without any observation and points not determined by their observations are
    returned unchanged.  Both solvers stop earlier than the iteration budget once the relative
    error decrease falls below 1e-5 (GTSAM's default; g2o always runs the full count).
    ``solver`` is ``"schur"`` (numba, default) or ``"gtsam"``.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown bundle adjustment solver {solver!r} (one of {SOLVERS})")
    t0 = time.perf_counter()
    clock = _Clock()
    problem = _normalized(problem)
    poses0 = problem.poses_cw
    points0 = problem.points_w
    thr = _chi2_threshold(problem)
    m = problem.obs_pose.shape[0]

    active = np.ones(m, bool)
    n1 = iterations[0] if remove_outliers else iterations[0] + iterations[1]
    clock.lap("build")
    poses, points, ok = _optimize(problem, poses0, points0, active, robust, n1, solver, clock)
    if remove_outliers:
        chi2 = reprojection_errors(problem, poses, points)
        active = chi2 <= thr
        clock.lap("check")
        poses, points, ok2 = _optimize(problem, poses, points, active, False, iterations[1],
                                       solver, clock)
        ok = ok and ok2

    chi2 = reprojection_errors(problem, poses, points)
    inlier = chi2 <= thr
    chi2_0 = reprojection_errors(problem, poses0, points0)
    sel = inlier & np.isfinite(chi2_0)
    initial = float(chi2_0[sel].mean()) if sel.any() else float("nan")
    final = float(chi2[sel].mean()) if sel.any() else float("nan")
    clock.lap("check")
    return BAResult(poses, points, inlier, initial, final, (time.perf_counter() - t0) * 1e3,
                    timings=dict(clock.ms), converged=ok)


def warm_up() -> None:
    """Load the compiled Schur solver (numba's on-disk cache; compiled on the very first use
    on a machine) and GTSAM with a two-keyframe problem, so a SLAM run's first bundle
    adjustment does not pay for it."""
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = -0.1
    pts = np.array([[0.0, 0.0, 2.0], [0.3, -0.2, 2.5], [-0.4, 0.1, 3.0]])
    pc = pts[None] + poses[:, None, :3, 3]
    pc = pc.reshape(-1, 3)
    uv = np.c_[500.0 * pc[:, 0] / pc[:, 2] + 320.0, 500.0 * pc[:, 1] / pc[:, 2] + 240.0]
    ur = uv[:, 0] - 40.0 / pc[:, 2]
    problem = BAProblem(poses, np.array([True, False]), pts, np.repeat([0, 1], 3),
                        np.tile([0, 1, 2], 2), uv, ur, np.ones(6),
                        500.0, 500.0, 320.0, 240.0, 40.0)
    bundle_adjust(problem)
