"""Compiled motion-only pose optimisation: the whole of ``pose_only.optimize_pose`` in one call.

``optimize_pose_kernel`` runs every round of ORB-SLAM2's PoseOptimization as
``pose_only.optimize_pose_numpy`` (the reference, which the tests compare with) does:
Levenberg-Marquardt with Marquardt-scaled damping, Huber IRLS in the first ``robust_rounds``
rounds, chi2 re-classification after each round, ``fixed`` observations never used, the
``n_valid < 10`` break, the skip of a round whose problem equals the last converged one, and the
same convergence tests.  Numba, ``nogil`` (tracking does not hold the GIL while it solves),
``cache=True`` (compiled once per machine; ``warm_up`` loads it before the first frame).

Arithmetic is written in the reference's order where that is cheap: residuals, chi2, the Huber
weights, the 6-vector exponential and the LM cost, which is summed the way numpy sums a float64
vector (pairwise blocks of 8, buffers of 8192), so the accept/reject test ``cost_new <= cost *
(1 + 1e-10)`` sees the same numbers.  The 3x3 / 4x4 products and the normal equations
(``H = J^T W J`` by BLAS in numpy, per observation here) and the 6x6 solve (LAPACK ``gesv`` there,
Gaussian elimination with partial pivoting here) differ by round-off only, so poses agree to
~1e-12, not bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

_MIN_DEPTH = 1e-6
_NP_BUFSIZE = 8192  # numpy's ufunc buffer: a reduction sums chunks of this many
_PW_BLOCKSIZE = 128  # numpy's pairwise-summation leaf size


@numba.njit(cache=True, nogil=True)
def _pairwise_sum(a: Array, lo: int, n: int) -> float:
    """``a[lo:lo+n]`` summed as numpy's ``pairwise_sum`` does (8 accumulators per leaf)."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    if n <= _PW_BLOCKSIZE:
        r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
        r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
        m = n - n % 8
        i = 8
        while i < m:
            j = lo + i
            r0 += a[j]
            r1 += a[j + 1]
            r2 += a[j + 2]
            r3 += a[j + 3]
            r4 += a[j + 4]
            r5 += a[j + 5]
            r6 += a[j + 6]
            r7 += a[j + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[lo + i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum(a, lo, n2) + _pairwise_sum(a, lo + n2, n - n2)


@numba.njit(cache=True, nogil=True)
def _np_sum(a: Array) -> float:
    """``float(a.sum())`` of a contiguous float64 vector, bit for bit (numpy 1.26)."""
    res = 0.0
    n = a.shape[0]
    for lo in range(0, n, _NP_BUFSIZE):
        res += _pairwise_sum(a, lo, min(_NP_BUFSIZE, n - lo))
    return res


@numba.njit(cache=True, nogil=True)
def _se3_exp(dx: Array, E: Array) -> None:
    """4x4 ``exp`` of a twist ``dx = (omega, v)`` into ``E`` (``pose_only.se3_exp`` wraps it):
    R = I + a [w]x + b [w]x^2, t = (I + b [w]x + c [w]x^2) v, with [w]x^2 = w w^T - th2 I."""
    w0, w1, w2, v0, v1, v2 = dx[0], dx[1], dx[2], dx[3], dx[4], dx[5]
    th2 = w0 * w0 + w1 * w1 + w2 * w2
    if th2 < 1e-16:
        a, b, c = 1.0, 0.5, 1.0 / 6.0
    else:
        th = math.sqrt(th2)
        sn = math.sin(th)
        a = sn / th
        b = (1.0 - math.cos(th)) / th2
        c = (th - sn) / (th2 * th)
    q00, q11, q22 = w0 * w0 - th2, w1 * w1 - th2, w2 * w2 - th2
    q01, q02, q12 = w0 * w1, w0 * w2, w1 * w2
    E[0, 0] = 1 + b * q00
    E[0, 1] = -a * w2 + b * q01
    E[0, 2] = a * w1 + b * q02
    E[1, 0] = a * w2 + b * q01
    E[1, 1] = 1 + b * q11
    E[1, 2] = -a * w0 + b * q12
    E[2, 0] = -a * w1 + b * q02
    E[2, 1] = a * w0 + b * q12
    E[2, 2] = 1 + b * q22
    V00, V01, V02 = 1 + c * q00, -b * w2 + c * q01, b * w1 + c * q02
    V10, V11, V12 = b * w2 + c * q01, 1 + c * q11, -b * w0 + c * q12
    V20, V21, V22 = -b * w1 + c * q02, b * w0 + c * q12, 1 + c * q22
    E[0, 3] = V00 * v0 + V01 * v1 + V02 * v2
    E[1, 3] = V10 * v0 + V11 * v1 + V12 * v2
    E[2, 3] = V20 * v0 + V21 * v1 + V22 * v2
    E[3, 0] = 0.0
    E[3, 1] = 0.0
    E[3, 2] = 0.0
    E[3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def _matmul4(A: Array, B: Array, out: Array) -> None:
    for i in range(4):
        for j in range(4):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j] + A[i, 3] * B[3, j]


@numba.njit(cache=True, nogil=True)
def so3_log(R: Array, out: Array) -> None:
    """``Log`` of a rotation matrix (away from a half turn) into ``out[:3]``: the angle from
    the trace, the axis from the antisymmetric part (also the bundle adjustment's links')."""
    c = min(max(0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0), -1.0), 1.0)
    th = math.acos(c)
    k = 0.5 if th < 1e-8 else 0.5 * th / math.sin(th)
    out[0] = k * (R[2, 1] - R[1, 2])
    out[1] = k * (R[0, 2] - R[2, 0])
    out[2] = k * (R[1, 0] - R[0, 1])


@numba.njit(cache=True, nogil=True)
def relative_pose_jacobian(dR: Array, e: Array, J: Array) -> None:
    """``de/dxi`` into ``J`` (6x6) for ``e = (Log(dR), dt)`` of ``dT = Z T^-1`` under
    ``T <- exp(xi) T`` (so ``dT <- dT exp(-xi)``): ``[[-Jr^-1(phi), 0], [0, -dR]]`` with
    ``Jr^-1(phi) ~ I + [phi]x / 2`` (first order in the residual). The pose prior's, and the
    bundle adjustment links' later pose."""
    J[:, :] = 0.0
    J[0, 0] = J[1, 1] = J[2, 2] = -1.0
    J[0, 1], J[0, 2] = 0.5 * e[2], -0.5 * e[1]
    J[1, 0], J[1, 2] = -0.5 * e[2], 0.5 * e[0]
    J[2, 0], J[2, 1] = 0.5 * e[1], -0.5 * e[0]
    for i in range(3):
        for j in range(3):
            J[3 + i, 3 + j] = -dR[i, j]


@numba.njit(cache=True, nogil=True)
def _prior_terms(T: Array, Tp: Array, Lp: Array, H: Array, g: Array, add: bool) -> float:
    """Cost ``e^T Lp e`` of a Gaussian prior on the pose, with ``e`` = (Log(dR), dt) of
    ``dT = Tp T^-1`` (rotation on SO(3), translation in the camera's frame); with ``add``
    its terms go into the normal equations. For ``T <- exp(xi) T``, ``dT <- dT exp(-xi)``:
    ``de/d(omega) = -Jr^-1(phi) ~ -(I + [phi]x / 2)``, ``de/dv = -dR``."""
    dR = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            dR[i, j] = Tp[i, 0] * T[j, 0] + Tp[i, 1] * T[j, 1] + Tp[i, 2] * T[j, 2]
    e = np.empty(6)
    for i in range(3):
        e[3 + i] = Tp[i, 3] - (dR[i, 0] * T[0, 3] + dR[i, 1] * T[1, 3] + dR[i, 2] * T[2, 3])
    so3_log(dR, e)
    cost = 0.0
    for i in range(6):
        for j in range(6):
            cost += e[i] * Lp[i, j] * e[j]
    if not add:
        return cost
    J = np.empty((6, 6))
    relative_pose_jacobian(dR, e, J)
    LJ = Lp @ J
    H += J.T @ LJ
    g -= LJ.T @ e
    return cost


@numba.njit(cache=True, nogil=True)
def _evaluate(T: Array, P: Array, oc: Array, sf: Array, info: Array, fx: float, fy: float,
              bf: float, ev: Array, front: NDArray[np.bool_], chi2: Array) -> None:
    """Residuals at pose ``T`` (``_Evaluator.evaluate``, the same arithmetic): ``ev`` rows iz,
    x/z, y/z, r_u, r_v, r_ur (0 for mono); ``chi2`` (inf at/behind the camera) and ``front``.
    ``P`` and ``oc`` are component-major (3, N), so the loop vectorises."""
    R00, R01, R02, t0 = T[0, 0], T[0, 1], T[0, 2], T[0, 3]
    R10, R11, R12, t1 = T[1, 0], T[1, 1], T[1, 2], T[1, 3]
    R20, R21, R22, t2 = T[2, 0], T[2, 1], T[2, 2], T[2, 3]
    for k in range(P.shape[1]):
        X, Y, Z = P[0, k], P[1, k], P[2, k]
        px = R00 * X + R01 * Y + R02 * Z + t0
        py = R10 * X + R11 * Y + R12 * Z + t1
        z = R20 * X + R21 * Y + R22 * Z + t2
        f = z > _MIN_DEPTH
        iz = 1.0 / (z if f else 1.0)
        xn = px * iz
        yn = py * iz
        ru = oc[0, k] - fx * xn
        rv = oc[1, k] - fy * yn
        rr = (ru + oc[2, k] + bf * iz) * sf[k]
        ev[0, k] = iz
        ev[1, k] = xn
        ev[2, k] = yn
        ev[3, k] = ru
        ev[4, k] = rv
        ev[5, k] = rr
        front[k] = f
        c = (ru * ru + rv * rv + rr * rr) * info[k]
        chi2[k] = c if f else np.inf


@numba.njit(cache=True, nogil=True)
def _cost(chi2: Array, act: NDArray[np.bool_], robust: bool, delta: Array, delta2: Array,
          buf: Array) -> float:
    """Cost of the active observations (``_weights``' second value): Huber (as g2o, on chi2)
    when ``robust``, else the plain chi2 sum."""
    for k in range(chi2.shape[0]):
        c = chi2[k] if act[k] else 0.0
        if robust and c > delta2[k]:
            c = 2.0 * delta[k] * math.sqrt(c) - delta2[k]
        buf[k] = c
    return _np_sum(buf)


@numba.njit(cache=True, nogil=True)
def _irls_weights(chi2: Array, act: NDArray[np.bool_], info: Array, robust: bool, delta: Array,
                  delta2: Array, w: Array) -> None:
    """``_weights``' first value: ``info * huber_irls`` on the active observations, else 0."""
    for k in range(chi2.shape[0]):
        wk = 0.0
        if act[k]:
            wk = info[k]
            if robust and chi2[k] > delta2[k]:
                wk = info[k] * (delta[k] / math.sqrt(chi2[k]))
        w[k] = wk


# Reassociation lets LLVM vectorise the 27 sums across observations (2x faster); H and g differ
# from a sequential sum by round-off only, as numpy's BLAS sums differ from both.
@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _normal_equations(ev: Array, w: Array, sf: Array, fx: float, fy: float, bf: float, H: Array,
                      g: Array) -> None:
    """``H = sum w J^T J``, ``g = sum w J^T r`` (``_Evaluator.normal_equations``), ``w`` from
    :func:`_irls_weights` (0 leaves an observation out).

    Rows ``u``, ``v``, ``s`` (the virtual right coordinate, weighted by 0 for mono) with
    columns (rotation 0..2, translation 0..2); ``u4 = v3 = s4 = 0``.  The 21 + 6 sums stay in
    registers and the loop has no branch.
    """
    h00 = h01 = h02 = h03 = h04 = h05 = 0.0
    h11 = h12 = h13 = h14 = h15 = 0.0
    h22 = h23 = h24 = h25 = 0.0
    h33 = h34 = h35 = 0.0
    h44 = h45 = 0.0
    h55 = 0.0
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    for k in range(ev.shape[1]):
        wk = w[k]
        ws = wk * sf[k]
        iz, xn, yn = ev[0, k], ev[1, k], ev[2, k]
        ru, rv, rs = ev[3, k], ev[4, k], ev[5, k]
        fxi = fx * xn
        fyi = fy * yn
        u0 = -fxi * yn
        u1 = fxi * xn + fx
        u2 = -fx * yn
        u3 = fx * iz
        u5 = -fxi * iz
        v0 = -fyi * yn - fy
        v1 = fyi * xn
        v2 = fy * xn
        v4 = fy * iz
        v5 = -fyi * iz
        biz = bf * iz  # the s row of a mono observation is weighted by ws = 0
        s0 = u0 + biz * yn
        s1 = u1 - biz * xn
        s5 = u5 + biz * iz
        s2 = u2
        s3 = u3
        wu0, wu1, wu2, wu3, wu5 = wk * u0, wk * u1, wk * u2, wk * u3, wk * u5
        wv0, wv1, wv2, wv4, wv5 = wk * v0, wk * v1, wk * v2, wk * v4, wk * v5
        ws0, ws1, ws2, ws3, ws5 = ws * s0, ws * s1, ws * s2, ws * s3, ws * s5
        h00 += wu0 * u0 + wv0 * v0 + ws0 * s0
        h01 += wu0 * u1 + wv0 * v1 + ws0 * s1
        h02 += wu0 * u2 + wv0 * v2 + ws0 * s2
        h03 += wu0 * u3 + ws0 * s3
        h04 += wv0 * v4
        h05 += wu0 * u5 + wv0 * v5 + ws0 * s5
        h11 += wu1 * u1 + wv1 * v1 + ws1 * s1
        h12 += wu1 * u2 + wv1 * v2 + ws1 * s2
        h13 += wu1 * u3 + ws1 * s3
        h14 += wv1 * v4
        h15 += wu1 * u5 + wv1 * v5 + ws1 * s5
        h22 += wu2 * u2 + wv2 * v2 + ws2 * s2
        h23 += wu2 * u3 + ws2 * s3
        h24 += wv2 * v4
        h25 += wu2 * u5 + wv2 * v5 + ws2 * s5
        h33 += wu3 * u3 + ws3 * s3
        h35 += wu3 * u5 + ws3 * s5
        h44 += wv4 * v4
        h45 += wv4 * v5
        h55 += wu5 * u5 + wv5 * v5 + ws5 * s5
        g0 += wu0 * ru + wv0 * rv + ws0 * rs
        g1 += wu1 * ru + wv1 * rv + ws1 * rs
        g2 += wu2 * ru + wv2 * rv + ws2 * rs
        g3 += wu3 * ru + ws3 * rs
        g4 += wv4 * rv
        g5 += wu5 * ru + wv5 * rv + ws5 * rs
    H[0, 0], H[0, 1], H[0, 2], H[0, 3], H[0, 4], H[0, 5] = h00, h01, h02, h03, h04, h05
    H[1, 1], H[1, 2], H[1, 3], H[1, 4], H[1, 5] = h11, h12, h13, h14, h15
    H[2, 2], H[2, 3], H[2, 4], H[2, 5] = h22, h23, h24, h25
    H[3, 3], H[3, 4], H[3, 5] = h33, h34, h35
    H[4, 4], H[4, 5] = h44, h45
    H[5, 5] = h55
    for a in range(6):
        for b in range(a):
            H[a, b] = H[b, a]
    g[0], g[1], g[2], g[3], g[4], g[5] = g0, g1, g2, g3, g4, g5


@numba.njit(cache=True, nogil=True)
def _solve6(A: Array, b: Array, x: Array) -> bool:
    """``x = A^-1 b`` by Gaussian elimination with partial pivoting (``A``, ``b`` overwritten);
    False where a pivot is exactly zero (where ``np.linalg.solve`` raises ``LinAlgError``)."""
    n = 6
    for c in range(n):
        p = c
        best = abs(A[c, c])
        for r in range(c + 1, n):
            v = abs(A[r, c])
            if v > best:
                best = v
                p = r
        if best == 0.0:
            return False
        if p != c:
            for j in range(c, n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
            b[c], b[p] = b[p], b[c]
        piv = A[c, c]
        for r in range(c + 1, n):
            f = A[r, c] / piv
            if f != 0.0:
                for j in range(c + 1, n):
                    A[r, j] -= f * A[c, j]
                b[r] -= f * b[c]
    for c in range(n - 1, -1, -1):
        s = b[c]
        for j in range(c + 1, n):
            s -= A[c, j] * x[j]
        x[c] = s / A[c, c]
    return True


@numba.njit(cache=True, nogil=True)
def _lm(T: Array, active: NDArray[np.bool_], robust: bool, iterations: int, P: Array,
        oc: Array, sf: Array, info: Array, delta: Array, delta2: Array,
        fx: float, fy: float, bf: float, ev: Array, front: NDArray[np.bool_], chi2: Array,
        act: NDArray[np.bool_], buf: Array, Tp: Array, Lp: Array, prior: bool) -> bool:
    """``pose_only._lm``: LM over the ``active`` observations in front of the camera (and the
    pose prior ``Tp``, information ``Lp``, when ``prior``); ``T`` and the evaluation (``ev``,
    ``front``, ``chi2``) updated in place; returns converged."""
    n = P.shape[1]
    n_act = 0
    for k in range(n):
        act[k] = active[k] and front[k]
        n_act += act[k]
    if n_act < 3:
        return True
    lam = 1e-6
    cost = _cost(chi2, act, robust, delta, delta2, buf)
    H = np.empty((6, 6))
    g = np.empty(6)
    if prior:
        cost += _prior_terms(T, Tp, Lp, H, g, False)
    Hd = np.empty((6, 6))
    gd = np.empty(6)
    dx = np.empty(6)
    E = np.empty((4, 4))
    T_new = np.empty((4, 4))
    step = 0.0
    for _ in range(iterations):
        # the evaluation is at T here: the weights of the last accepted step are recomputed
        _irls_weights(chi2, act, info, robust, delta, delta2, buf)
        _normal_equations(ev, buf, sf, fx, fy, bf, H, g)
        if prior:
            _prior_terms(T, Tp, Lp, H, g, True)
        accepted = False
        for _try in range(10):
            for i in range(6):
                gd[i] = g[i]
                for j in range(6):
                    Hd[i, j] = H[i, j]
                Hd[i, i] += lam * H[i, i]
            if not _solve6(Hd, gd, dx):
                lam *= 10.0
                continue
            step = 0.0  # max |dx|, NaN if any is (as np.max)
            for i in range(6):
                a = abs(dx[i])
                if a > step or a != a:
                    step = a
                    if a != a:
                        break
            if step < 1e-12:  # nothing left to gain (as the reference, no re-evaluation)
                return True
            _se3_exp(dx, E)
            _matmul4(E, T, T_new)
            _evaluate(T_new, P, oc, sf, info, fx, fy, bf, ev, front, chi2)
            n_new = 0
            for k in range(n):
                n_new += act[k] and front[k]
            if n_new == n_act:
                cost_new = _cost(chi2, act, robust, delta, delta2, buf)
                if prior:
                    cost_new += _prior_terms(T_new, Tp, Lp, H, g, False)
                if cost_new <= cost * (1.0 + 1e-10):
                    T[:, :] = T_new
                    cost = cost_new
                    lam = max(lam * 0.1, 1e-12)
                    accepted = True
                    break
            lam *= 10.0
        if not accepted:  # restore the evaluation at the kept pose
            _evaluate(T, P, oc, sf, info, fx, fy, bf, ev, front, chi2)
            return True
        if step < 1e-7 and lam < 1e-3:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def optimize_pose_kernel(T0: Array, pts: Array, uv: Array, ur: Array, info: Array,
                         fixed: NDArray[np.bool_], fx: float, fy: float, cx: float, cy: float,
                         bf: float, rounds: int, iterations: int, robust_rounds: int,
                         thr_mono: float, thr_stereo: float, Tp: Array, Lp: Array, prior: bool
                         ) -> tuple[Array, NDArray[np.bool_], int, Array]:
    """``pose_only.optimize_pose_numpy`` compiled: returns ``(T_cw, inliers, n_inliers, chi2)``.

    Inputs are contiguous float64 (``fixed`` bool); ``thr_*`` are the chi2 thresholds, which
    are also the Huber ``delta^2``. With ``prior`` every round's cost also has the Gaussian
    prior ``Tp`` (a ``T_cw``) with information ``Lp`` (6x6, tangent (omega, v) of ``T_cw``'s
    left increment), an extension the numpy reference does not have.
    """
    n = pts.shape[0]
    T = T0.copy()
    sf = np.empty(n)  # 1.0 stereo, 0.0 mono: zeroes the third residual and its weight
    P = np.ascontiguousarray(pts.T)  # (3, N), as ``_Evaluator``
    oc = np.empty((3, n))
    delta2 = np.empty(n)
    delta = np.empty(n)
    for k in range(n):
        s = ur[k] >= 0
        sf[k] = 1.0 if s else 0.0
        oc[0, k] = uv[k, 0] - cx
        oc[1, k] = uv[k, 1] - cy
        oc[2, k] = (ur[k] if s else 0.0) - uv[k, 0]
        delta2[k] = thr_stereo if s else thr_mono
        delta[k] = math.sqrt(delta2[k])
    ev = np.empty((6, n))
    front = np.empty(n, np.bool_)
    chi2 = np.empty(n)
    _evaluate(T, P, oc, sf, info, fx, fy, bf, ev, front, chi2)
    n_valid = 0
    for k in range(n):
        n_valid += not fixed[k]
    active = np.empty(n, np.bool_)
    if n_valid < 3:
        active[:] = False
        return T, active, 0, chi2
    for k in range(n):
        active[k] = not fixed[k]
    act = np.empty(n, np.bool_)
    buf = np.empty(n)
    solved = np.empty(n, np.bool_)  # active set of the last converged round
    have_solved = False
    solved_robust = False
    for rnd in range(rounds):
        robust = rnd < robust_rounds
        # skip a round whose problem equals the last converged one (same active set, same cost)
        same = have_solved
        if same:
            for k in range(n):
                if solved[k] != active[k]:
                    same = False
                    break
        if same and solved_robust != robust:
            for k in range(n):
                if active[k] and chi2[k] > delta2[k]:
                    same = False
                    break
        if not same:
            converged = _lm(T, active, robust, iterations, P, oc, sf, info, delta, delta2,
                            fx, fy, bf, ev, front, chi2, act, buf, Tp, Lp, prior)
            have_solved = converged
            if converged:
                solved[:] = active
                solved_robust = robust
        for k in range(n):
            active[k] = chi2[k] <= delta2[k] and not fixed[k]
        if n_valid < 10:  # ORB-SLAM: `if(optimizer.edges().size()<10) break;`
            break
    n_inl = 0
    for k in range(n):
        n_inl += active[k]
    return T, active, n_inl, chi2

