"""The compiled pose-only optimisation (``optimize_pose``) equals its numpy reference
(``optimize_pose_numpy``): same inliers, chi2 and pose up to round-off, on random problems and
the degenerate ones (few observations, points behind the camera, fixed outliers)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.backend.pose_only import PoseResult, optimize_pose, optimize_pose_numpy, se3_exp
from semslam.backend.pose_only import warm_up
from semslam.backend.pose_only_kernel import _np_sum

FX, FY, CX, CY, BF = 525.0, 525.0, 319.5, 239.5, 40.0
CAM = (FX, FY, CX, CY, BF)
W, H = 640, 480


def problem(rng: np.random.Generator, n: int, noise: float, outliers: float, mono_frac: float,
            behind: float = 0.0):
    """A frame: perturbed initial pose, world points, observations (stereo and mono mixed)."""
    T = se3_exp(np.r_[rng.normal(0, 0.3, 3), rng.normal(0, 1.0, 3)])
    u = rng.uniform(0, W, n)
    v = rng.uniform(0, H, n)
    z = rng.uniform(0.3, 8.0, n)
    z[rng.random(n) < behind] *= -1.0  # at the true pose these are behind the camera
    pc = np.column_stack([(u - CX) / FX * z, (v - CY) / FY * z, z])
    pw = (pc - T[:3, 3]) @ T[:3, :3]
    inv = 1.2 ** (-2.0 * rng.integers(0, 8, n))
    sig = 1.0 / np.sqrt(inv)
    uv = np.column_stack([u, v]) + rng.normal(0, noise, (n, 2)) * sig[:, None]
    ur = u - BF / np.abs(z) + rng.normal(0, noise, n) * sig
    ur[rng.random(n) < mono_frac] = -1.0
    bad = rng.random(n) < outliers
    uv[bad] += rng.uniform(10, 120, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
    d = np.r_[rng.normal(size=3), rng.normal(size=3)]
    d[:3] *= np.radians(rng.uniform(0, 6)) / np.linalg.norm(d[:3])
    d[3:] *= rng.uniform(0, 0.15) / np.linalg.norm(d[3:])
    return se3_exp(d) @ T, pw, uv, ur, inv


def assert_same(a: PoseResult, b: PoseResult, tol: float = 1e-9) -> None:
    np.testing.assert_array_equal(a.inliers, b.inliers)
    assert a.n_inliers == b.n_inliers == int(b.inliers.sum())
    np.testing.assert_allclose(a.T_cw, b.T_cw, rtol=0, atol=tol)
    fin = np.isfinite(b.chi2)
    np.testing.assert_array_equal(np.isfinite(a.chi2), fin)
    assert np.all(a.chi2[~fin] == np.inf) and np.all(b.chi2[~fin] == np.inf)
    np.testing.assert_allclose(a.chi2[fin], b.chi2[fin], rtol=1e-7, atol=1e-9)


def both(*args, **kwargs) -> tuple[PoseResult, PoseResult]:
    return optimize_pose(*args, **kwargs), optimize_pose_numpy(*args, **kwargs)


def test_sum_is_numpys_sum():
    """The LM cost is summed as numpy sums it, so the accept test sees the same numbers."""
    rng = np.random.default_rng(0)
    for n in [0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 256, 257, 300, 801, 8191, 8192,
              8193, 20000]:
        a = rng.exponential(size=n) * 10.0 ** rng.uniform(-8, 8, n)
        a[rng.random(n) < 0.3] = 0.0
        assert _np_sum(a) == float(a.sum()), n


@pytest.mark.parametrize("seed", range(40))
def test_kernel_equals_numpy_random(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 900))
    T0, pw, uv, ur, inv = problem(rng, n, noise=rng.uniform(0, 1.5), outliers=rng.uniform(0, 0.35),
                                  mono_frac=rng.choice([0.0, 0.3, 1.0]),
                                  behind=0.05 if seed % 4 == 0 else 0.0)
    fixed = rng.random(n) < 0.15 if seed % 2 else None
    kw = {}
    if seed % 5 == 1:
        kw = {"rounds": int(rng.integers(1, 6)), "iterations": int(rng.integers(1, 12)),
              "robust_rounds": int(rng.integers(0, 5))}
    a, b = both(T0, pw, uv, ur, inv, *CAM, fixed_outliers=fixed, **kw)
    assert_same(a, b)


@pytest.mark.parametrize("seed", range(30))
def test_kernel_equals_numpy_far_start(seed):
    """A start tens of degrees / decimetres off: LM rejects steps (cost up, points going behind
    the camera), raises the damping, and sometimes finds no acceptable step at all."""
    rng = np.random.default_rng(1000 + seed)
    n = int(rng.integers(3, 300))
    T0, pw, uv, ur, inv = problem(rng, n, noise=1.0, outliers=0.3, mono_frac=0.5)
    T0 = se3_exp(np.r_[rng.normal(0, 0.4, 3), rng.normal(0, 0.5, 3)]) @ T0
    assert_same(*both(T0, pw, uv, ur, inv, *CAM))


def test_kernel_equals_numpy_singular_normal_equations():
    """Zero information: H = 0, every solve is singular (numpy's LinAlgError), LM gives up
    and keeps the input pose."""
    rng = np.random.default_rng(14)
    T0, pw, uv, ur, inv = problem(rng, 50, noise=0.5, outliers=0.0, mono_frac=0.3)
    a, b = both(T0, pw, uv, ur, 0.0, *CAM)
    assert_same(a, b)
    assert np.array_equal(a.T_cw, T0) and a.n_inliers == 50


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 9, 10, 11])
def test_kernel_equals_numpy_few_observations(n):
    """Fewer than 3 usable: the input pose, no inliers; fewer than 10: one round only."""
    rng = np.random.default_rng(100 + n)
    T0, pw, uv, ur, inv = problem(rng, n, noise=0.5, outliers=0.2, mono_frac=0.3)
    a, b = both(T0, pw, uv, ur, inv, *CAM)
    assert_same(a, b)
    if n < 3:
        assert a.n_inliers == 0 and np.array_equal(a.T_cw, T0)


@pytest.mark.parametrize("n_free", [0, 2, 3, 9, 10])
def test_kernel_equals_numpy_fixed_leaves_few(n_free):
    """``fixed_outliers`` leaving fewer than 3 / 10 valid observations."""
    rng = np.random.default_rng(200 + n_free)
    T0, pw, uv, ur, inv = problem(rng, 60, noise=0.5, outliers=0.1, mono_frac=0.3)
    fixed = np.ones(60, bool)
    fixed[rng.choice(60, n_free, replace=False)] = False
    a, b = both(T0, pw, uv, ur, inv, *CAM, fixed_outliers=fixed)
    assert_same(a, b)
    assert not a.inliers[fixed].any()


def test_kernel_equals_numpy_points_behind_the_camera():
    """Points behind the camera get chi2 = inf, never take part and are outliers."""
    rng = np.random.default_rng(7)
    T0, pw, uv, ur, inv = problem(rng, 300, noise=0.5, outliers=0.05, mono_frac=0.3, behind=0.2)
    a, b = both(T0, pw, uv, ur, inv, *CAM)
    assert_same(a, b)
    assert np.isinf(a.chi2).sum() > 30 and not a.inliers[np.isinf(a.chi2)].any()
    # all but two behind: fewer than 3 in front, LM does not run, the pose is the input
    behind = np.flatnonzero(np.isinf(a.chi2))
    front = np.flatnonzero(np.isfinite(a.chi2))[:2]
    sel = np.r_[behind, front]
    a, b = both(T0, pw[sel], uv[sel], ur[sel], inv[sel], *CAM)
    assert_same(a, b)
    assert np.array_equal(a.T_cw, T0)


def test_kernel_equals_numpy_all_mono_and_all_stereo():
    for mono in (0.0, 1.0):
        rng = np.random.default_rng(int(mono) + 11)
        T0, pw, uv, ur, inv = problem(rng, 500, noise=0.8, outliers=0.15, mono_frac=mono)
        assert_same(*both(T0, pw, uv, ur, inv, *CAM))


def test_kernel_equals_numpy_noise_free_and_at_the_solution():
    """Convergence tests at the minimum: exact data, and starting at the optimum found."""
    rng = np.random.default_rng(12)
    T0, pw, uv, ur, inv = problem(rng, 400, noise=0.0, outliers=0.0, mono_frac=0.2)
    a, b = both(T0, pw, uv, ur, inv, *CAM)
    assert_same(a, b)
    assert np.all(a.chi2 < 1e-6)
    a2, b2 = both(a.T_cw, pw, uv, ur, inv, *CAM)
    assert_same(a2, b2)


def test_kernel_input_normalisation():
    """Scalar ``inv_sigma2``, non-contiguous and float32 / list inputs give the same result,
    and the input pose is not modified."""
    rng = np.random.default_rng(13)
    T0, pw, uv, ur, inv = problem(rng, 200, noise=0.5, outliers=0.1, mono_frac=0.3)
    obs = np.column_stack([ur, uv])  # (n, 3): column views are non-contiguous
    T_copy = T0.copy()
    ref = optimize_pose_numpy(T0, pw, uv, ur, 1.0, *CAM)
    a = optimize_pose(T0, np.asfortranarray(pw), obs[:, 1:], obs[:, 0], 1.0, *CAM,
                      fixed_outliers=[False] * 200)
    assert_same(a, ref)
    assert np.array_equal(T0, T_copy)
    b = optimize_pose(T0.tolist(), pw.astype(np.float32), uv, ur, np.float32(1.0), *CAM)
    c = optimize_pose_numpy(T0.tolist(), pw.astype(np.float32), uv, ur, np.float32(1.0), *CAM)
    assert_same(b, c)
    with pytest.raises(ValueError):
        optimize_pose(T0[:3], pw, uv, ur, inv, *CAM)


def test_warm_up_runs():
    warm_up()


def _prior_residuals(T0: np.ndarray, pw: np.ndarray, uv: np.ndarray, Tp: np.ndarray, info: np.ndarray):
    """The pose prior's cost as plain residuals for scipy: reprojections of mono points and
    the prior's (Log(dR), dt) of ``Tp T^-1`` whitened by ``info``."""
    from scipy.spatial.transform import Rotation

    L = np.linalg.cholesky(info).T

    def fun(x: np.ndarray) -> np.ndarray:
        T = se3_exp(x) @ T0
        pc = pw @ T[:3, :3].T + T[:3, 3]
        proj = np.column_stack([FX * pc[:, 0] / pc[:, 2] + CX, FY * pc[:, 1] / pc[:, 2] + CY])
        D = Tp @ np.linalg.inv(T)
        return np.r_[(uv - proj).ravel(), L @ np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]]]
    return fun


def test_pose_prior_minimises_the_prior_cost():
    """With a prior the kernel's pose is the least-squares solution of reprojections plus the
    prior (scipy on the same residuals, an independent solver); as its information grows the
    pose goes to the prior's, as it vanishes to the pose without it."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(3)
    T0, pw, uv, _, _ = problem(rng, 25, 2.0, 0.0, 1.0)
    ur = -np.ones(len(pw))
    Tp = se3_exp(np.r_[0.01, -0.02, 0.005, 0.03, -0.02, 0.01]) @ T0
    info = np.diag([1e5] * 3 + [1e4] * 3)
    got = optimize_pose(T0, pw, uv, ur, 1.0, *CAM, rounds=1, robust_rounds=0, prior=(Tp, info))
    x = least_squares(_prior_residuals(T0, pw, uv, Tp, info), np.zeros(6), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(got.T_cw, se3_exp(x) @ T0, atol=1e-7)
    free = optimize_pose(T0, pw, uv, ur, 1.0, *CAM, rounds=1, robust_rounds=0)
    assert np.abs(free.T_cw - got.T_cw).max() > 1e-3  # the prior moved it
    tight = optimize_pose(T0, pw, uv, ur, 1.0, *CAM, rounds=1, robust_rounds=0, prior=(Tp, info * 1e8))
    np.testing.assert_allclose(tight.T_cw, Tp, atol=1e-5)
    loose = optimize_pose(T0, pw, uv, ur, 1.0, *CAM, rounds=1, robust_rounds=0, prior=(Tp, info * 1e-12))
    np.testing.assert_allclose(loose.T_cw, free.T_cw, atol=1e-8)
