"""Motion-only optimisation of a camera pose against fixed map points (ORB-SLAM2 PoseOptimization).

Runs for every frame (twice: after the motion-model / reference-keyframe match and after the local
map search).  :func:`optimize_pose` validates and normalises its inputs here and solves in one
compiled call (``semslam.backend.pose_only_kernel``, numba, ``nogil``): every round, the LM
iterations, the Huber reweighting and the inlier classification.  :func:`optimize_pose_numpy` is
the reference it is tested against: the same Levenberg-Marquardt on SE(3) with analytic
Jacobians, vectorised numpy (about 1 ms a call, most of it numpy call overhead).
:func:`optimize_pose_gtsam` solves the same problem with GTSAM's stock factors and is an
independent reference for tests and benchmarks.

Observation model (ORB-SLAM2 RGB-D): ``(u, v, ur)`` with the virtual right coordinate
``ur = u - bf / z``; ``ur < 0`` marks an observation without depth (2 residuals instead of 3).
Information is ``inv_sigma2 * I``; Huber kernel with delta = sqrt(chi2_95 %) of the residual
dimension.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.backend.gtsam_utils import CHI2_MONO, CHI2_STEREO
from semslam.backend.pose_only_kernel import _se3_exp, optimize_pose_kernel

Array = NDArray[np.float64]

_DELTA2_MONO = CHI2_MONO  # Huber delta^2 (compared against chi2 directly)
_DELTA2_STEREO = CHI2_STEREO
_MIN_DEPTH = 1e-6


@dataclass(frozen=True)
class PoseResult:
    """Optimised ``T_cw``, the final inlier mask, its count, and each observation's chi2.

    ``chi2`` is the (non-robust) ``inv_sigma2 * |residual|^2`` at the final pose, ``inf`` for points
    at or behind the camera.  Outliers are the observations the caller should drop
    (ORB-SLAM's ``mvbOutlier``).
    """

    T_cw: Array
    inliers: NDArray[np.bool_]
    n_inliers: int
    chi2: Array


def se3_exp(xi: Array) -> Array:
    """4x4 ``exp`` of a twist ``xi = (omega, v)`` (rotation first, as GTSAM's Pose3 tangent):
    the compiled kernel's own (one implementation; it runs once per LM step on 6 numbers)."""
    E = np.empty((4, 4))
    _se3_exp(np.ascontiguousarray(xi, dtype=np.float64).reshape(6), E)
    return E


class _Evaluator:
    """Residuals, chi2 and normal equations of all observations at one pose.

    Arrays are stored component-major (``(3, N)``) so every per-observation quantity is a
    contiguous vector.  Residual ``r = obs - proj(T_cw * X)``; the Jacobian of ``proj`` is taken
    w.r.t. a left increment ``T_cw <- exp(xi) T_cw``, ``xi = (omega, v)``, for which
    d(Xc)/d(xi) = [-[Xc]x, I]: a row ``a = d proj / d Xc`` has rotation block ``Xc x a`` and
    translation block ``a``.
    """

    def __init__(self, pts_w: Array, obs: Array, stereo: NDArray[np.bool_], inv_sigma2: Array,
                 fx: float, fy: float, cx: float, cy: float, bf: float) -> None:
        self.P = np.ascontiguousarray(pts_w.T)  # (3, N)
        # (3, N): u - cx, v - cy, ur - u (the last ignored where mono)
        self.obs_c = np.ascontiguousarray(
            np.stack([obs[:, 0] - cx, obs[:, 1] - cy, obs[:, 2] - obs[:, 0]]))
        self.stereo = stereo
        self.sf = stereo.astype(np.float64)  # zeroes the third residual / Jacobian row of mono obs
        self.info = inv_sigma2
        self.fx, self.fy, self.cx, self.cy, self.bf = fx, fy, cx, cy, bf
        self.delta2 = np.where(stereo, _DELTA2_STEREO, _DELTA2_MONO)
        self.delta = np.sqrt(self.delta2)
        n = pts_w.shape[0]
        self.J = np.zeros((6, 3, n))
        self.r = np.empty((3, n))

    def evaluate(self, T: Array) -> None:
        """Fill residuals ``r``, ``chi2`` (inf behind the camera) and ``front`` at pose ``T``."""
        pc = T[:3, :3] @ self.P
        pc += T[:3, 3:4]
        z = pc[2]
        front = z > _MIN_DEPTH
        all_front = bool(front.all())
        iz = 1.0 / z if all_front else 1.0 / np.where(front, z, 1.0)
        xi = pc[0] * iz
        yi = pc[1] * iz
        r = self.r
        # r_u = (u_obs - cx) - fx x/z;  r_ur = r_u + (ur_obs - u_obs) + bf/z  (0 for mono)
        np.subtract(self.obs_c[0], self.fx * xi, out=r[0])
        np.subtract(self.obs_c[1], self.fy * yi, out=r[1])
        np.add(r[0], self.obs_c[2], out=r[2])
        r[2] += self.bf * iz
        r[2] *= self.sf
        chi2 = np.einsum("ij,ij->j", r, r)
        chi2 *= self.info
        if not all_front:
            chi2[~front] = np.inf
        self.iz, self.xi, self.yi, self.front, self.chi2 = iz, xi, yi, front, chi2

    def normal_equations(self, w: Array) -> tuple[Array, Array]:
        """``H = sum w J^T J`` and ``g = sum w J^T r`` at the last evaluated pose.

        ``w`` already includes information, robust weight and the active mask.
        """
        J = self.J  # (6 columns, 3 rows, N): reshapes to (6, 3N) for one matmul
        fx, fy, bf = self.fx, self.fy, self.bf
        iz, xi, yi = self.iz, self.xi, self.yi
        fxi = fx * xi
        fyi = fy * yi
        # u row: a = (fx/z, 0, -fx x/z^2)
        np.multiply(-fxi, yi, out=J[0, 0])
        np.multiply(fxi, xi, out=J[1, 0])
        J[1, 0] += fx
        np.multiply(-fx, yi, out=J[2, 0])
        np.multiply(fx, iz, out=J[3, 0])
        np.multiply(-fxi, iz, out=J[5, 0])
        # v row: a = (0, fy/z, -fy y/z^2)
        np.multiply(-fyi, yi, out=J[0, 1])
        J[0, 1] -= fy
        np.multiply(fyi, xi, out=J[1, 1])
        np.multiply(fy, xi, out=J[2, 1])
        np.multiply(fy, iz, out=J[4, 1])
        np.multiply(-fyi, iz, out=J[5, 1])
        # ur row: u row + d(-bf/z)/dXc = u row + (0, 0, bf/z^2); zeroed for mono observations
        biz = bf * iz
        np.add(J[0, 0], biz * yi, out=J[0, 2])
        np.subtract(J[1, 0], biz * xi, out=J[1, 2])
        J[2, 2] = J[2, 0]
        J[3, 2] = J[3, 0]
        np.add(J[5, 0], biz * iz, out=J[5, 2])
        J[:, 2] *= self.sf
        n3 = 3 * self.r.shape[1]
        Jf = J.reshape(6, n3)
        Jw = (J * w).reshape(6, n3)
        H = Jw @ Jf.T
        g = Jw @ self.r.reshape(n3)
        return H, g


def _weights(ev: _Evaluator, active: NDArray[np.bool_], robust: bool) -> tuple[Array, float]:
    """Per-observation weight ``info * huber_irls * active`` and the (robust) cost of ``active``.

    Huber on s = chi2 (as g2o): rho(s) = s inside delta^2, 2 delta sqrt(s) - delta^2 outside;
    the IRLS weight is rho'(s) = min(1, delta / sqrt(s)) (the same as GTSAM's Huber on the
    whitened residual norm).
    """
    chi2 = np.where(active, ev.chi2, 0.0)
    if not robust:
        return ev.info * active, float(chi2.sum())
    sq = np.sqrt(chi2)
    out = chi2 > ev.delta2
    if not out.any():
        return ev.info * active, float(chi2.sum())
    hw = np.where(out, ev.delta / np.where(out, sq, 1.0), 1.0)
    cost = float(np.where(out, 2.0 * ev.delta * sq - ev.delta2, chi2).sum())
    return ev.info * hw * active, cost


def _lm(ev: _Evaluator, T: Array, active: NDArray[np.bool_], robust: bool,
        iterations: int) -> tuple[Array, bool]:
    """Levenberg-Marquardt (Marquardt-scaled damping) over the ``active`` observations.

    ``ev`` must hold the evaluation at ``T`` on entry and holds it at the returned pose on exit.
    Returns the pose and whether it converged (increment below 1e-7 rad / m): ORB-SLAM always
    runs its 10 g2o iterations, iterations past convergence change nothing but the time.
    """
    active = active & ev.front
    n_act = int(active.sum())
    if n_act < 3:
        return T, True
    lam = 1e-6
    w, cost = _weights(ev, active, robust)
    for _ in range(iterations):
        H, g = ev.normal_equations(w)
        diag = H.diagonal().copy()
        for _try in range(10):
            Hd = H.copy()
            Hd.flat[::7] += lam * diag
            try:
                dx = np.linalg.solve(Hd, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            step = float(np.abs(dx).max())
            if step < 1e-12:  # nothing left to gain: skip the evaluation
                return T, True
            T_new = se3_exp(dx) @ T
            ev.evaluate(T_new)
            act_new = active & ev.front
            if int(act_new.sum()) == n_act:
                w_new, cost_new = _weights(ev, active, robust)
                if cost_new <= cost * (1.0 + 1e-10):  # tolerate round-off near the minimum
                    T, w, cost = T_new, w_new, cost_new
                    lam = max(lam * 0.1, 1e-12)
                    break
            lam *= 10.0
        else:
            ev.evaluate(T)  # no acceptable step: restore the evaluation at the kept pose
            return T, True
        if step < 1e-7 and lam < 1e-3:  # undamped GN step this small: what is left is far less
            return T, True
    return T, False


def _prepare(T_cw0, pts_w, uv, ur, inv_sigma2, fixed_outliers):
    """Inputs as fresh or contiguous float64 / bool arrays of consistent shapes (the compiled
    kernel sees one type signature whatever the caller passes)."""
    T = np.array(T_cw0, dtype=np.float64, order="C")  # a copy: the result never aliases it
    if T.shape != (4, 4):
        raise ValueError(f"T_cw0 must be 4x4, got shape {T.shape}")
    pts = np.ascontiguousarray(pts_w, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    uv = np.ascontiguousarray(np.asarray(uv, dtype=np.float64).reshape(n, 2))
    ur = np.ascontiguousarray(np.asarray(ur, dtype=np.float64).reshape(n))
    inv_sigma2 = np.broadcast_to(np.asarray(inv_sigma2, dtype=np.float64), (n,)).copy()
    fixed = (np.zeros(n, bool) if fixed_outliers is None
             else np.ascontiguousarray(np.asarray(fixed_outliers, bool).reshape(n)))
    return T, pts, uv, ur, inv_sigma2, fixed


def optimize_pose(
    T_cw0: Array,
    pts_w: Array,
    uv: Array,
    ur: Array,
    inv_sigma2: Array,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    fixed_outliers: NDArray[np.bool_] | None = None,
    rounds: int = 4,
    iterations: int = 10,
    robust_rounds: int = 3,
    prior: tuple[Array, Array] | None = None,
) -> PoseResult:
    """ORB-SLAM2 PoseOptimization: ``rounds`` x (LM, then inlier/outlier classification).

    One compiled call (``pose_only_kernel.optimize_pose_kernel``); :func:`optimize_pose_numpy`
    is the reference it equals up to round-off (the same decisions, poses to ~1e-12).

    After each round every observation is re-classified by its chi2 (> 5.991 mono, > 7.815 stereo,
    or non-positive depth -> outlier); outliers are left out of the next round but can come back.
    ``fixed_outliers`` marks observations that never take part and are always reported as
    outliers (e.g. points on semantically dynamic objects) - an extension over ORB-SLAM.
    The Huber kernel is used in the first ``robust_rounds`` rounds: ORB-SLAM2 removes it after the
    third classification (``if(it==2) e->setRobustKernel(0)``), so only its last round is plain
    least squares; pass ``robust_rounds=2`` to drop it for the last two.

    Deviation from ORB-SLAM2: each round continues from the previous round's estimate instead of
    restarting from the input pose (ORB-SLAM re-sets ``pFrame->mTcw``, which it never updates
    inside the loop); at convergence the result is the same and the later rounds cost one or two
    iterations instead of a full re-solve.  Fewer than 3 usable observations return the input
    pose with no inliers (ORB-SLAM returns 0 correspondences).

    ``prior = (T_cw, information)`` adds a Gaussian prior on the pose to every round's cost
    (ORB-SLAM3's inertial tracking marginalised to the pose: the IMU's prediction with its
    spread). Its residual is ``(Log(dR), dt)`` of ``dT = T_prior T_cw^-1``, the information
    6x6 on (rotation, translation) of that residual, in the camera's frame.
    """
    T, pts, uv, ur, info, fixed = _prepare(T_cw0, pts_w, uv, ur, inv_sigma2, fixed_outliers)
    Tp, Lp = (np.eye(4), np.zeros((6, 6))) if prior is None else prior
    T, inliers, n_inliers, chi2 = optimize_pose_kernel(
        T, pts, uv, ur, info, fixed, float(fx), float(fy), float(cx), float(cy), float(bf),
        int(rounds), int(iterations), int(robust_rounds), _DELTA2_MONO, _DELTA2_STEREO,
        np.ascontiguousarray(Tp, dtype=np.float64), np.ascontiguousarray(Lp, dtype=np.float64),
        prior is not None)
    return PoseResult(T, inliers, int(n_inliers), chi2)


def optimize_pose_numpy(
    T_cw0: Array,
    pts_w: Array,
    uv: Array,
    ur: Array,
    inv_sigma2: Array,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    fixed_outliers: NDArray[np.bool_] | None = None,
    rounds: int = 4,
    iterations: int = 10,
    robust_rounds: int = 3,
) -> PoseResult:
    """ORB-SLAM2 PoseOptimization in vectorised numpy: the reference of :func:`optimize_pose`
    (same arguments, same rounds and decisions; see there), kept for the tests and benchmarks.
    """
    T, pts, uv, ur, info, fixed = _prepare(T_cw0, pts_w, uv, ur, inv_sigma2, fixed_outliers)
    n = pts.shape[0]
    stereo = ur >= 0
    obs = np.column_stack([uv, np.where(stereo, ur, 0.0)])
    ev = _Evaluator(pts, obs, stereo, info, float(fx), float(fy), float(cx), float(cy), float(bf))
    ev.evaluate(T)
    n_valid = int((~fixed).sum())
    thr = ev.delta2  # the chi2 thresholds equal the Huber delta^2
    if n_valid < 3:
        inl = np.zeros(n, bool)
        return PoseResult(T, inl, 0, ev.chi2.copy())
    active = ~fixed
    solved: tuple[NDArray[np.bool_], bool] | None = None  # (active set, robust) last converged
    for rnd in range(rounds):
        robust = rnd < robust_rounds
        # A round whose problem is identical to the last converged one would not move: same
        # active set and the same cost (same kernel, or no active residual in Huber's linear zone).
        same = (solved is not None and np.array_equal(solved[0], active)
                and (solved[1] == robust or not np.any(active & (ev.chi2 > thr))))
        if not same:
            T, converged = _lm(ev, T, active, robust, iterations)
            solved = (active, robust) if converged else None
        active = (ev.chi2 <= thr) & ~fixed
        if n_valid < 10:  # ORB-SLAM: `if(optimizer.edges().size()<10) break;`
            break
    return PoseResult(T, active, int(active.sum()), ev.chi2.copy())


def optimize_pose_gtsam(
    T_cw0: Array,
    pts_w: Array,
    uv: Array,
    ur: Array,
    inv_sigma2: Array,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    fixed_outliers: NDArray[np.bool_] | None = None,
    rounds: int = 4,
    iterations: int = 10,
    robust_rounds: int = 3,
) -> PoseResult:
    """Same rounds as :func:`optimize_pose`, solved with GTSAM stock factors (test reference).

    One ``Pose3`` variable (``T_wc``, key 0) and each map point as a ``Point3`` variable pinned
    by ``NonlinearEqualityPoint3`` (GTSAM's camera factors always take a landmark key), with
    ``GenericStereoFactor3D`` (ur >= 0) or ``GenericProjectionFactorCal3_S2`` and the Huber
    ``noiseModel.Robust``.  LM runs to tight tolerances (up to 100 iterations; ``iterations`` is
    not used) so it is a converged reference.
    Slow (a graph per round, N extra variables); not for the tracking loop.
    """
    import gtsam

    from semslam.backend.gtsam_utils import (
        lm_params,
        mono_calibration,
        obs_noise,
        pose3_from_matrix,
        stereo_calibration,
    )

    T, pts, uv, ur, info, fixed = _prepare(T_cw0, pts_w, uv, ur, inv_sigma2, fixed_outliers)
    n = pts.shape[0]
    stereo = ur >= 0
    Ks = stereo_calibration(fx, fy, cx, cy, bf)
    Km = mono_calibration(fx, fy, cx, cy)
    thr = np.where(stereo, CHI2_STEREO, CHI2_MONO)
    # chi2 bookkeeping via the numpy evaluator: it is pure arithmetic, not part of the solve.
    ev = _Evaluator(pts, np.column_stack([uv, np.where(stereo, ur, 0.0)]), stereo, info,
                    float(fx), float(fy), float(cx), float(cy), float(bf))
    ev.evaluate(T)
    n_valid = int((~fixed).sum())
    if n_valid < 3:
        return PoseResult(T, np.zeros(n, bool), 0, ev.chi2.copy())
    active = ~fixed
    pose_wc = pose3_from_matrix(np.linalg.inv(T))
    for rnd in range(rounds):
        robust = rnd < robust_rounds
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        values.insert(0, pose_wc)
        for i in np.flatnonzero(active & ev.front):
            key = int(i) + 1
            if stereo[i]:
                graph.add(gtsam.GenericStereoFactor3D(
                    gtsam.StereoPoint2(uv[i, 0], ur[i], uv[i, 1]),
                    obs_noise(3, float(info[i]), robust), 0, key, Ks))
            else:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    uv[i], obs_noise(2, float(info[i]), robust), 0, key, Km))
            graph.add(gtsam.NonlinearEqualityPoint3(key, pts[i]))
            values.insert(key, pts[i])
        if graph.size() >= 6:
            params = lm_params(100, tight=True)
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
            pose_wc = result.atPose3(0)
        T = np.linalg.inv(pose_wc.matrix())
        ev.evaluate(T)
        active = (ev.chi2 <= thr) & ~fixed
        if n_valid < 10:
            break
    return PoseResult(T, active, int(active.sum()), ev.chi2.copy())


def warm_up() -> None:
    """Compile (or load) the kernel for the types :func:`optimize_pose` passes (listed in
    ``features/jit.py``; here, not in the kernel module, which must not import this one)."""
    pts = np.array([[0.0, 0.0, 2.0], [0.3, -0.2, 2.5], [-0.4, 0.1, 3.0], [0.2, 0.3, 1.5]])
    uv = np.c_[500.0 * pts[:, 0] / pts[:, 2] + 320.0, 500.0 * pts[:, 1] / pts[:, 2] + 240.0]
    ur = uv[:, 0] - 40.0 / pts[:, 2]
    ur[0] = -1.0
    T0 = np.eye(4)
    T0[0, 3] = 0.01
    optimize_pose(T0, pts, uv, ur, np.ones(4), 500.0, 500.0, 320.0, 240.0, 40.0)
