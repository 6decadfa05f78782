"""Sparse Levenberg-Marquardt for bundle adjustment: Schur complement on the points, numba.

One LM solve over the active observations of a :class:`~semslam.backend.bundle_adjustment.BAProblem`
with the same cost as the GTSAM factor graph of ``bundle_adjustment._build_graph``:

* residual ``z - h(x)`` per observation, ``h = (u, v)`` (monocular) or ``(u, v, u_r)`` with
  ``u_r = u - bf / z`` (RGB-D as a virtual stereo rig), information ``inv_sigma2 * I``;
* optionally Huber on the whitened residual norm with ORB-SLAM's deltas (sqrt of the 95 %
  chi2), linearised by reweighting (IRLS), which is what GTSAM's ``noiseModel.Robust`` and g2o's
  robust kernels do;
* a point at or behind a camera contributes GTSAM's cheirality residual (``2 fx`` per
  component) with zero Jacobians;
* fixed poses are constants (GTSAM holds them with a 1e-9 prior; here they simply are not
  variables).

LM follows GTSAM's ``LevenbergMarquardtOptimizer`` defaults: damping ``lambda * I`` starting at
1e-5, divided by 10 after a successful step and multiplied by 10 after a failed one, a step is
successful when its model fidelity (actual over linearised cost decrease) exceeds 1e-3, give up
when lambda reaches 1e5, stop when the error decreases by less than 1e-5 (relative or absolute)
or after ``max_iterations`` linearisations.

Each linearisation builds the 6x6 pose blocks, the 3x3 point blocks and one 6x3 pose-point block
per observation, eliminates the points (reduced camera system of size 6 x free poses, dense
Cholesky: local BA has at most a few tens of free keyframes) and back-substitutes them.  Poses
are updated on the left, ``T_cw <- exp(delta) T_cw`` with ``delta = (omega, v)``, as g2o's
``SE3Quat``; GTSAM retracts ``T_wc`` on the right, which is the same update with the sign
flipped, so both minimise the same function over the same manifold.

All kernels are ``nogil``: called from a thread, the solve runs beside tracking.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_only_kernel import relative_pose_jacobian, so3_log

Array = NDArray[np.float64]

# GTSAM LevenbergMarquardtParams defaults.
LAMBDA_INITIAL = 1e-5
LAMBDA_FACTOR = 10.0
LAMBDA_UPPER = 1e5
MIN_MODEL_FIDELITY = 1e-3
REL_TOL = 1e-5
ABS_TOL = 1e-5


@numba.njit(cache=True, nogil=True)
def _residual(R: Array, t: Array, X: Array, u: float, v: float, r: float, fx: float, fy: float,
              cx: float, cy: float, bf: float, out: Array, pc: Array) -> bool:
    """Residual ``z - h`` of one observation into ``out`` (3 entries, the third 0 for mono),
    the point in the camera into ``pc``; False when the point is at/behind the camera."""
    for i in range(3):
        pc[i] = R[i, 0] * X[0] + R[i, 1] * X[1] + R[i, 2] * X[2] + t[i]
    z = pc[2]
    if z <= 1e-9:  # GTSAM's cheirality residual: 2 fx per component, zero Jacobians
        out[0] = 2.0 * fx
        out[1] = 2.0 * fx
        out[2] = 2.0 * fx if r >= 0.0 else 0.0
        return False
    iz = 1.0 / z
    hu = fx * pc[0] * iz + cx
    out[0] = u - hu
    out[1] = v - (fy * pc[1] * iz + cy)
    out[2] = r - (hu - bf * iz) if r >= 0.0 else 0.0
    return True


@numba.njit(cache=True, nogil=True)
def _loss(chi2: float, robust: bool, delta: float) -> float:
    """GTSAM's error of one factor: 0.5 d^2, or Huber's rho(d) with d = sqrt(chi2)."""
    if robust:
        d = np.sqrt(chi2)
        if d > delta:
            return delta * d - 0.5 * delta * delta
    return 0.5 * chi2


@numba.njit(cache=True, nogil=True)
def _total_cost(Rs: Array, ts: Array, X: Array, opose: NDArray[np.intp], opoint: NDArray[np.intp],
                uv: Array, ur: Array, is2: Array, fx: float, fy: float, cx: float, cy: float,
                bf: float, robust: bool, d_mono: float, d_st: float) -> float:
    e = np.empty(3)
    pc = np.empty(3)
    total = 0.0
    for m in range(opose.shape[0]):
        k = opose[m]
        _residual(Rs[k], ts[k], X[opoint[m]], uv[m, 0], uv[m, 1], ur[m], fx, fy, cx, cy, bf, e, pc)
        chi2 = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) * is2[m]
        total += _loss(chi2, robust, d_st if ur[m] >= 0.0 else d_mono)
    return total


@numba.njit(cache=True, nogil=True, inline="always")
def _add_normal_block(J: Array, nr: int, e: Array, w: float, H: Array, g: Array) -> None:
    """``H += w J^T J`` (upper triangle) and ``g += w J^T e`` over the first ``nr`` rows of ``J``."""
    n = J.shape[1]
    for a in range(n):
        for b in range(a, n):
            s = 0.0
            for q in range(nr):
                s += J[q, a] * J[q, b]
            H[a, b] += w * s
        s = 0.0
        for q in range(nr):
            s += J[q, a] * e[q]
        g[a] += w * s


@numba.njit(cache=True, nogil=True)
def _linearize(Rs: Array, ts: Array, X: Array, opose: NDArray[np.intp], opoint: NDArray[np.intp],
               uv: Array, ur: Array, is2: Array, fx: float, fy: float, cx: float, cy: float,
               bf: float, robust: bool, d_mono: float, d_st: float, pose_var: NDArray[np.intp],
               Hpp: Array, bp: Array, Hll: Array, bl: Array, Hpl: Array) -> float:
    """Normal equations (J^T W J, J^T W e) in blocks; returns the cost at the estimate."""
    Hpp[:] = 0.0
    bp[:] = 0.0
    Hll[:] = 0.0
    bl[:] = 0.0
    e = np.empty(3)
    pc = np.empty(3)
    Jh = np.zeros((3, 3))  # d h / d pc
    Jp = np.zeros((3, 6))
    Jl = np.zeros((3, 3))
    total = 0.0
    for m in range(opose.shape[0]):
        k = opose[m]
        j = opoint[m]
        R = Rs[k]
        front = _residual(R, ts[k], X[j], uv[m, 0], uv[m, 1], ur[m], fx, fy, cx, cy, bf, e, pc)
        stereo = ur[m] >= 0.0
        chi2 = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) * is2[m]
        delta = d_st if stereo else d_mono
        total += _loss(chi2, robust, delta)
        f = pose_var[k]
        if not front:
            if f >= 0:
                Hpl[m] = 0.0
            continue
        w = is2[m]
        if robust:
            d = np.sqrt(chi2)
            if d > delta:
                w *= delta / d
        nr = 3 if stereo else 2
        iz = 1.0 / pc[2]
        iz2 = iz * iz
        Jh[0, 0] = fx * iz
        Jh[0, 1] = 0.0
        Jh[0, 2] = -fx * pc[0] * iz2
        Jh[1, 0] = 0.0
        Jh[1, 1] = fy * iz
        Jh[1, 2] = -fy * pc[1] * iz2
        Jh[2, 0] = fx * iz
        Jh[2, 1] = 0.0
        Jh[2, 2] = -fx * pc[0] * iz2 + bf * iz2
        # point: d pc / d X = R
        for a in range(nr):
            for b in range(3):
                Jl[a, b] = Jh[a, 0] * R[0, b] + Jh[a, 1] * R[1, b] + Jh[a, 2] * R[2, b]
        _add_normal_block(Jl, nr, e, w, Hll[j], bl[j])
        if f < 0:
            continue
        # pose (left perturbation): d pc / d omega = -[pc]x, d pc / d v = I
        for a in range(nr):
            Jp[a, 0] = -Jh[a, 1] * pc[2] + Jh[a, 2] * pc[1]
            Jp[a, 1] = Jh[a, 0] * pc[2] - Jh[a, 2] * pc[0]
            Jp[a, 2] = -Jh[a, 0] * pc[1] + Jh[a, 1] * pc[0]
            Jp[a, 3] = Jh[a, 0]
            Jp[a, 4] = Jh[a, 1]
            Jp[a, 5] = Jh[a, 2]
        _add_normal_block(Jp, nr, e, w, Hpp[f], bp[f])
        for a in range(6):
            for b in range(3):
                s = 0.0
                for q in range(nr):
                    s += Jp[q, a] * Jl[q, b]
                Hpl[m, a, b] = w * s
    _mirror_upper(Hpp)
    _mirror_upper(Hll)
    return total


@numba.njit(cache=True, nogil=True)
def _link_residual(Ra: Array, ta: Array, Rb: Array, tb: Array, RZ: Array, tZ: Array, dR: Array,
                   e: Array) -> None:
    """Residual of a relative-pose link ``T_b ~ Z T_a``: ``e = (Log(dR), dt)`` of
    ``dT = Z T_a T_b^-1`` (``dR`` is written too)."""
    M = Ra @ Rb.T
    dR[:, :] = RZ @ M
    d = RZ @ (ta - M @ tb) + tZ
    so3_log(dR, e)
    e[3], e[4], e[5] = d[0], d[1], d[2]


@numba.njit(cache=True, nogil=True)
def _links_cost(Rs: Array, ts: Array, lpose: NDArray[np.intp], lR: Array, lt: Array,
                linfo: Array) -> float:
    """Sum of ``e^T info e`` over the links (no robust kernel: the IMU's are not outliers)."""
    dR = np.empty((3, 3))
    e = np.empty(6)
    total = 0.0
    for m in range(lpose.shape[0]):
        _link_residual(Rs[lpose[m, 0]], ts[lpose[m, 0]], Rs[lpose[m, 1]], ts[lpose[m, 1]], lR[m], lt[m], dR, e)
        total += e @ (linfo[m] @ e)
    return total


@numba.njit(cache=True, nogil=True)
def _linearize_links(Rs: Array, ts: Array, lpose: NDArray[np.intp], lR: Array, lt: Array,
                     linfo: Array, pose_var: NDArray[np.intp], Hpp: Array, bp: Array,
                     Hab: Array) -> float:
    """The links' terms added to the pose blocks (``Hpp``, ``bp``, after ``_linearize``) and
    their pose-pose blocks into ``Hab``; returns their cost. With left increments
    ``T <- exp(xi) T``: ``dT <- exp(Ad_Z xi_a) dT`` and ``dT <- dT exp(-xi_b)``, so
    ``de/dxi_a = [[Jl^-1(phi), 0], [-[dt]x, I]] Ad_Z`` and ``de/dxi_b = [[-Jr^-1(phi), 0],
    [0, -dR]]``, with ``J^-1(phi) = I -+ [phi]x / 2`` (first order in the residual)."""
    dR = np.empty((3, 3))
    e = np.empty(6)
    total = 0.0
    for m in range(lpose.shape[0]):
        a, b = lpose[m, 0], lpose[m, 1]
        _link_residual(Rs[a], ts[a], Rs[b], ts[b], lR[m], lt[m], dR, e)
        L = linfo[m]
        total += e @ (L @ e)
        phi = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
        tx = np.array([[0.0, -e[5], e[4]], [e[5], 0.0, -e[3]], [-e[4], e[3], 0.0]])
        Gl = np.zeros((6, 6))  # de / d(left increment of dT)
        Gl[:3, :3] = np.eye(3) - 0.5 * phi
        Gl[3:, :3] = -tx
        Gl[3:, 3:] = np.eye(3)
        RZ, tZ = lR[m], lt[m]
        Ad = np.zeros((6, 6))
        Ad[:3, :3] = RZ
        Ad[3:, 3:] = RZ
        Ad[3:, :3] = np.array([[0.0, -tZ[2], tZ[1]], [tZ[2], 0.0, -tZ[0]], [-tZ[1], tZ[0], 0.0]]) @ RZ
        Ja = Gl @ Ad
        Jb = np.empty((6, 6))
        relative_pose_jacobian(dR, e, Jb)
        fa, fb = pose_var[a], pose_var[b]
        LJa = L @ Ja
        LJb = L @ Jb
        if fa >= 0:
            Hpp[fa] += Ja.T @ LJa
            bp[fa] -= LJa.T @ e
        if fb >= 0:
            Hpp[fb] += Jb.T @ LJb
            bp[fb] -= LJb.T @ e
        Hab[m] = Ja.T @ LJb
    return total


@numba.njit(cache=True, nogil=True, inline="always")
def _mirror_upper(H: Array) -> None:
    """Copy the upper triangle of each square block ``H[i]`` onto its lower triangle."""
    n = H.shape[1]
    for i in range(H.shape[0]):
        for a in range(n):
            for b in range(a):
                H[i, a, b] = H[i, b, a]


@numba.njit(cache=True, nogil=True)
def _inv3(A: Array, out: Array) -> bool:
    """Inverse of a symmetric 3x3 matrix; False when it is not positive definite."""
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 1], A[1, 2], A[2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    if not (a > 0.0 and a * d - b * b > 0.0 and det > 0.0):
        return False
    idet = 1.0 / det
    out[0, 0] = c00 * idet
    out[0, 1] = out[1, 0] = c01 * idet
    out[0, 2] = out[2, 0] = c02 * idet
    out[1, 1] = (a * f - c * c) * idet
    out[1, 2] = out[2, 1] = (b * c - a * e) * idet
    out[2, 2] = (a * d - b * b) * idet
    return True


@numba.njit(cache=True, nogil=True)
def _cholesky_solve(S: Array, g: Array, x: Array) -> bool:
    """Solve S x = g in place of a copy (S symmetric); False when S is not positive definite."""
    n = S.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        inv = 1.0 / L[j, j]
        for i in range(j + 1, n):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s * inv
    y = np.empty(n)
    for i in range(n):
        s = g[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True


@numba.njit(cache=True, nogil=True)
def _solve_damped(lam: float, Hpp: Array, bp: Array, Hll: Array, bl: Array, Hpl: Array,
                  opose: NDArray[np.intp], pose_var: NDArray[np.intp], pt_ptr: NDArray[np.intp],
                  pt_obs: NDArray[np.intp], dp: Array, dl: Array, lpose: NDArray[np.intp],
                  Hab: Array) -> bool:
    """Step of (H + lam I) delta = b by the Schur complement on the points (the links'
    pose-pose blocks ``Hab`` added to the reduced system)."""
    n_f = Hpp.shape[0]
    n_p = Hll.shape[0]
    S = np.zeros((6 * n_f, 6 * n_f))
    g = np.empty(6 * n_f)
    for f in range(n_f):
        for a in range(6):
            g[6 * f + a] = bp[f, a]
            for b in range(6):
                S[6 * f + a, 6 * f + b] = Hpp[f, a, b]
            S[6 * f + a, 6 * f + a] += lam
    Hinv = np.empty((n_p, 3, 3))
    A = np.empty((3, 3))
    W = np.empty((6, 3))
    for j in range(n_p):
        for a in range(3):
            for b in range(3):
                A[a, b] = Hll[j, a, b]
            A[a, a] += lam
        if not _inv3(A, Hinv[j]):
            return False
        Ai = Hinv[j]
        for ia in range(pt_ptr[j], pt_ptr[j + 1]):
            ma = pt_obs[ia]
            fa = pose_var[opose[ma]]
            if fa < 0:
                continue
            Pa = Hpl[ma]
            for a in range(6):
                for b in range(3):
                    W[a, b] = Pa[a, 0] * Ai[0, b] + Pa[a, 1] * Ai[1, b] + Pa[a, 2] * Ai[2, b]
            for a in range(6):
                g[6 * fa + a] -= W[a, 0] * bl[j, 0] + W[a, 1] * bl[j, 1] + W[a, 2] * bl[j, 2]
            for ib in range(ia, pt_ptr[j + 1]):
                mb = pt_obs[ib]
                fb = pose_var[opose[mb]]
                if fb < 0:
                    continue
                Pb = Hpl[mb]
                if fa <= fb:  # accumulate the upper block triangle only
                    for a in range(6):
                        ra = 6 * fa + a
                        for b in range(6):
                            S[ra, 6 * fb + b] -= W[a, 0] * Pb[b, 0] + W[a, 1] * Pb[b, 1] + W[a, 2] * Pb[b, 2]
                else:
                    for b in range(6):
                        rb = 6 * fb + b
                        for a in range(6):
                            S[rb, 6 * fa + a] -= W[a, 0] * Pb[b, 0] + W[a, 1] * Pb[b, 1] + W[a, 2] * Pb[b, 2]
    for m in range(lpose.shape[0]):  # the links' blocks, into the upper block triangle
        fa, fb = pose_var[lpose[m, 0]], pose_var[lpose[m, 1]]
        if fa < 0 or fb < 0:
            continue
        for a in range(6):
            for b in range(6):
                if fa < fb:
                    S[6 * fa + a, 6 * fb + b] += Hab[m, a, b]
                else:
                    S[6 * fb + b, 6 * fa + a] += Hab[m, a, b]
    for f in range(n_f):  # the diagonal blocks were filled in full from Hpp: mirror the rest
        for g2 in range(f + 1, n_f):
            for a in range(6):
                for b in range(6):
                    S[6 * g2 + b, 6 * f + a] = S[6 * f + a, 6 * g2 + b]
    for f in range(n_f):  # diagonal blocks: both triangles were updated, symmetrise
        for a in range(6):
            for b in range(a):
                v = 0.5 * (S[6 * f + a, 6 * f + b] + S[6 * f + b, 6 * f + a])
                S[6 * f + a, 6 * f + b] = v
                S[6 * f + b, 6 * f + a] = v
    x = np.zeros(6 * n_f)
    if n_f > 0 and not _cholesky_solve(S, g, x):
        return False
    for f in range(n_f):
        for a in range(6):
            dp[f, a] = x[6 * f + a]
    for j in range(n_p):
        r = np.empty(3)
        for a in range(3):
            r[a] = bl[j, a]
        for ia in range(pt_ptr[j], pt_ptr[j + 1]):
            ma = pt_obs[ia]
            fa = pose_var[opose[ma]]
            if fa < 0:
                continue
            for a in range(3):
                s = 0.0
                for b in range(6):
                    s += Hpl[ma, b, a] * dp[fa, b]
                r[a] -= s
        Ai = Hinv[j]
        for a in range(3):
            dl[j, a] = Ai[a, 0] * r[0] + Ai[a, 1] * r[1] + Ai[a, 2] * r[2]
    return True


@numba.njit(cache=True, nogil=True)
def _retract(Rs: Array, ts: Array, X: Array, free_poses: NDArray[np.intp], dp: Array, dl: Array,
             Rn: Array, tn: Array, Xn: Array) -> None:
    """``T_cw <- exp(dp) T_cw`` for the free poses, ``X <- X + dl``."""
    Rn[:] = Rs
    tn[:] = ts
    for f in range(free_poses.shape[0]):
        k = free_poses[f]
        w0, w1, w2 = dp[f, 0], dp[f, 1], dp[f, 2]
        th2 = w0 * w0 + w1 * w1 + w2 * w2
        th = np.sqrt(th2)
        if th < 1e-10:
            A = 1.0 - th2 / 6.0
            B = 0.5 - th2 / 24.0
            C = 1.0 / 6.0 - th2 / 120.0
        else:
            A = np.sin(th) / th
            B = (1.0 - np.cos(th)) / th2
            C = (th - np.sin(th)) / (th2 * th)
        K = np.array([[0.0, -w2, w1], [w2, 0.0, -w0], [-w1, w0, 0.0]])
        K2 = K @ K
        Rd = np.eye(3) + A * K + B * K2
        V = np.eye(3) + B * K + C * K2
        v = dp[f, 3:6].copy()
        td = V @ v
        Rn[k] = Rd @ Rs[k]
        tn[k] = Rd @ ts[k] + td
    Xn[:] = X
    for j in range(dl.shape[0]):
        for a in range(3):
            Xn[j, a] += dl[j, a]


@numba.njit(cache=True, nogil=True)
def levenberg_marquardt(Rs: Array, ts: Array, X: Array, opose: NDArray[np.intp],
                        opoint: NDArray[np.intp], uv: Array, ur: Array, is2: Array, fx: float,
                        fy: float, cx: float, cy: float, bf: float, robust: bool, d_mono: float,
                        d_st: float, pose_var: NDArray[np.intp], free_poses: NDArray[np.intp],
                        pt_ptr: NDArray[np.intp], pt_obs: NDArray[np.intp],
                        max_iterations: int, lpose: NDArray[np.intp], lR: Array, lt: Array,
                        linfo: Array) -> tuple[Array, Array, Array, int, bool, float, float]:
    """LM over the free poses (``pose_var[k] >= 0``) and all points of ``X``.

    ``opoint`` indexes ``X``; ``pt_ptr``/``pt_obs`` list each point's observations (CSR).
    Links ``m`` (none: empty arrays) hold ``T[lpose[m, 1]] ~ Z T[lpose[m, 0]]``, ``Z = (lR[m],
    lt[m])``, with information ``linfo[m]`` (6x6 on (rotation, translation)): the IMU's
    relative motion between consecutive keyframes.
    Returns (R, t, X, iterations, success, initial cost, final cost); success is False when
    no step could be computed at all (every damped system indefinite).
    """
    n_f = free_poses.shape[0]
    n_p = X.shape[0]
    m = opose.shape[0]
    Hpp = np.zeros((n_f, 6, 6))
    bp = np.zeros((n_f, 6))
    Hll = np.zeros((n_p, 3, 3))
    bl = np.zeros((n_p, 3))
    Hpl = np.zeros((m, 6, 3))
    dp = np.zeros((n_f, 6))
    dl = np.zeros((n_p, 3))
    Rn = np.empty_like(Rs)
    tn = np.empty_like(ts)
    Xn = np.empty_like(X)
    Hab = np.zeros((lpose.shape[0], 6, 6))
    Rs = Rs.copy()
    ts = ts.copy()
    X = X.copy()
    lam = LAMBDA_INITIAL
    solved = False
    cost0 = _total_cost(Rs, ts, X, opose, opoint, uv, ur, is2, fx, fy, cx, cy, bf, robust,
                        d_mono, d_st) + _links_cost(Rs, ts, lpose, lR, lt, linfo)
    cost = cost0
    it = 0
    while it < max_iterations:
        it += 1
        cost = _linearize(Rs, ts, X, opose, opoint, uv, ur, is2, fx, fy, cx, cy, bf, robust,
                          d_mono, d_st, pose_var, Hpp, bp, Hll, bl, Hpl)
        cost += _linearize_links(Rs, ts, lpose, lR, lt, linfo, pose_var, Hpp, bp, Hab)
        accepted = False
        stop = False
        while True:
            if not _solve_damped(lam, Hpp, bp, Hll, bl, Hpl, opose, pose_var, pt_ptr, pt_obs,
                                 dp, dl, lpose, Hab):
                lam *= LAMBDA_FACTOR
                if lam >= LAMBDA_UPPER:
                    stop = True
                    break
                continue
            solved = True
            # Linearised decrease 0.5 (d.b + lam |d|^2) of the undamped model.
            db = 0.0
            dd = 0.0
            for f in range(n_f):
                for a in range(6):
                    db += dp[f, a] * bp[f, a]
                    dd += dp[f, a] * dp[f, a]
            for j in range(n_p):
                for a in range(3):
                    db += dl[j, a] * bl[j, a]
                    dd += dl[j, a] * dl[j, a]
            lin = 0.5 * (db + lam * dd)
            _retract(Rs, ts, X, free_poses, dp, dl, Rn, tn, Xn)
            new_cost = _total_cost(Rn, tn, Xn, opose, opoint, uv, ur, is2, fx, fy, cx, cy, bf,
                                   robust, d_mono, d_st) + _links_cost(Rn, tn, lpose, lR, lt, linfo)
            if lin > 1e-300 and (cost - new_cost) / lin > MIN_MODEL_FIDELITY:
                accepted = True
                break
            if lin <= 1e-300:  # nothing left to gain
                stop = True
                break
            lam *= LAMBDA_FACTOR
            if lam >= LAMBDA_UPPER:
                stop = True
                break
        if accepted:
            Rs[:] = Rn
            ts[:] = tn
            X[:] = Xn
            lam = max(lam / LAMBDA_FACTOR, 0.0)
            dec = cost - new_cost
            cost = new_cost
            if dec < ABS_TOL or dec < REL_TOL * (cost + dec):
                break
        if stop:
            break
    return Rs, ts, X, it, solved or n_f + n_p == 0, cost0, cost


@numba.njit(cache=True, nogil=True)
def reprojection_chi2(Rs: Array, ts: Array, X: Array, opose: NDArray[np.intp],
                      opoint: NDArray[np.intp], uv: Array, ur: Array, is2: Array, fx: float,
                      fy: float, cx: float, cy: float, bf: float) -> Array:
    """(M,) ``inv_sigma2 * |z - h|^2`` of every observation, inf where the depth is <= 1e-6."""
    m = opose.shape[0]
    out = np.empty(m)
    for k in range(m):
        R = Rs[opose[k]]
        t = ts[opose[k]]
        P = X[opoint[k]]
        x = R[0, 0] * P[0] + R[0, 1] * P[1] + R[0, 2] * P[2] + t[0]
        y = R[1, 0] * P[0] + R[1, 1] * P[1] + R[1, 2] * P[2] + t[1]
        z = R[2, 0] * P[0] + R[2, 1] * P[1] + R[2, 2] * P[2] + t[2]
        if not z > 1e-6:
            out[k] = np.inf
            continue
        iz = 1.0 / z
        u = fx * x * iz + cx
        du = uv[k, 0] - u
        dv = uv[k, 1] - (fy * y * iz + cy)
        dr = ur[k] - (u - bf * iz) if ur[k] >= 0.0 else 0.0
        out[k] = (du * du + dv * dv + dr * dr) * is2[k]
    return out
