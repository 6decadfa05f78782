"""Tests of the optimisation back end (pose-only, BA, pose graph) on synthetic data."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.backend import (
    BAProblem,
    bundle_adjust,
    correct_points_with_poses,
    optimize_pose,
    optimize_pose_graph,
    optimize_pose_gtsam,
    reprojection_errors,
)
from semslam.backend.pose_only import se3_exp
from semslam.geometry.se3 import invert

FX, FY, CX, CY, BF = 525.0, 525.0, 319.5, 239.5, 40.0
CAM = (FX, FY, CX, CY, BF)
W, H = 640, 480


def rot_err(R: np.ndarray) -> float:
    """Rotation angle (rad) of R, accurate near zero (unlike arccos of the trace)."""
    return float(np.linalg.norm(Rotation.from_matrix(R).as_rotvec()))


def pose_err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) of A relative to B, both T_cw."""
    E = A @ invert(B)
    return float(np.linalg.norm(E[:3, 3])), rot_err(E[:3, :3])


def frame(rng, n, noise=0.0, outliers=0.0, mono_frac=0.2):
    """One frame: true T_cw, world points, (noisy) observations; returns the outlier mask too."""
    T = se3_exp(np.r_[rng.normal(0, 0.2, 3), rng.normal(0, 0.5, 3)])
    u = rng.uniform(0, W, n)
    v = rng.uniform(0, H, n)
    z = rng.uniform(0.5, 6.0, n)
    pc = np.column_stack([(u - CX) / FX * z, (v - CY) / FY * z, z])
    pw = (pc - T[:3, 3]) @ T[:3, :3]
    inv = 1.2 ** (-2.0 * rng.integers(0, 8, n))
    sig = 1.0 / np.sqrt(inv)
    uv = np.column_stack([u, v]) + rng.normal(0, noise, (n, 2)) * sig[:, None]
    ur = u - BF / z + rng.normal(0, noise, n) * sig
    ur[rng.random(n) < mono_frac] = -1.0
    bad = rng.random(n) < outliers
    uv[bad] += rng.uniform(25, 80, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
    return T, pw, uv, ur, inv, bad


def perturb(T, rng, rot_deg=2.0, trans=0.03):
    d = np.r_[rng.normal(size=3), rng.normal(size=3)]
    d[:3] *= np.radians(rot_deg) / np.linalg.norm(d[:3])
    d[3:] *= trans / np.linalg.norm(d[3:])
    return se3_exp(d) @ T


# --------------------------------------------------------------------------- pose-only


def test_se3_exp_matches_gtsam():
    for xi in (np.array([0.3, -0.2, 0.5, 1, 2, 3]), np.array([1e-9, 0, 2e-9, 1, 2, 3]),
               np.zeros(6)):
        np.testing.assert_allclose(se3_exp(xi), gtsam.Pose3.Expmap(xi).matrix(), atol=1e-12)


@pytest.mark.parametrize("mono_frac", [0.2, 1.0])
def test_pose_only_recovers_noise_free(mono_frac):
    rng = np.random.default_rng(1)
    T, pw, uv, ur, inv, _ = frame(rng, 400, mono_frac=mono_frac)
    res = optimize_pose(perturb(T, rng), pw, uv, ur, inv, *CAM)
    dt, dr = pose_err(res.T_cw, T)
    assert dt < 1e-3 and np.degrees(dr) < 0.01
    assert res.inliers.all() and res.n_inliers == 400
    assert np.all(res.chi2 < 1e-6)


def test_pose_only_flags_outliers():
    rng = np.random.default_rng(2)
    T, pw, uv, ur, inv, bad = frame(rng, 500, noise=0.5, outliers=0.2)
    res = optimize_pose(perturb(T, rng), pw, uv, ur, inv, *CAM)
    dt, dr = pose_err(res.T_cw, T)
    assert dt < 5e-3 and np.degrees(dr) < 0.2
    assert not res.inliers[bad].any()  # every gross outlier flagged
    assert res.inliers[~bad].mean() > 0.95  # and (almost) no good observation lost
    assert res.n_inliers == int(res.inliers.sum())


def test_pose_only_fixed_outliers_are_ignored():
    rng = np.random.default_rng(3)
    T, pw, uv, ur, inv, _ = frame(rng, 300)
    fixed = np.zeros(300, bool)
    fixed[:30] = True
    uv = uv.copy()
    uv[:30] += 300.0  # would wreck the pose if used (and be re-admitted by chi2 otherwise)
    res = optimize_pose(perturb(T, rng), pw, uv, ur, inv, *CAM, fixed_outliers=fixed)
    assert not res.inliers[:30].any() and res.inliers[30:].all()
    assert pose_err(res.T_cw, T)[0] < 1e-6


@pytest.mark.parametrize("mono_frac", [0.2, 1.0])
def test_pose_only_numpy_equals_gtsam(mono_frac):
    rng = np.random.default_rng(4)
    T, pw, uv, ur, inv, _ = frame(rng, 150, noise=0.5, mono_frac=mono_frac)
    T0 = perturb(T, rng)
    a = optimize_pose(T0, pw, uv, ur, inv, *CAM)
    b = optimize_pose_gtsam(T0, pw, uv, ur, inv, *CAM)
    dt, dr = pose_err(a.T_cw, b.T_cw)
    assert dt < 1e-6 and dr < 1e-6
    np.testing.assert_array_equal(a.inliers, b.inliers)
    # both recover the truth up to the noise
    assert pose_err(a.T_cw, T)[0] < 5e-3 and pose_err(b.T_cw, T)[0] < 5e-3


def test_pose_only_too_few_observations():
    rng = np.random.default_rng(5)
    T, pw, uv, ur, inv, _ = frame(rng, 2)
    T0 = perturb(T, rng)
    res = optimize_pose(T0, pw, uv, ur, inv, *CAM)
    assert res.n_inliers == 0 and np.array_equal(res.T_cw, T0)


# --------------------------------------------------------------------------- bundle adjustment


def ba_scene(rng, n_kf=6, n_pts=300, noise=0.5, mono=False, n_fixed=1, outlier_frac=0.0):
    """Keyframes on an arc around a box of points -> (problem, true poses, true points, bad)."""
    poses = []
    for k in range(n_kf):
        a = -0.3 + 0.6 * k / (n_kf - 1)
        T_wc = np.eye(4)
        T_wc[:3, :3] = Rotation.from_rotvec([0, -a, 0]).as_matrix()
        T_wc[:3, 3] = [2.5 * np.sin(-a), 0.1 * np.sin(k), 2.5 - 2.5 * np.cos(a)]
        poses.append(invert(T_wc))
    poses_t = np.array(poses)
    pts = np.column_stack([rng.uniform(-1.2, 1.2, n_pts), rng.uniform(-0.8, 0.8, n_pts),
                           rng.uniform(1.5, 3.5, n_pts)])
    pc = np.einsum("kij,pj->kpi", poses_t[:, :3, :3], pts) + poses_t[:, None, :3, 3]
    u = FX * pc[..., 0] / pc[..., 2] + CX
    v = FY * pc[..., 1] / pc[..., 2] + CY
    vis = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    kk, pp = np.nonzero(vis)
    m = kk.size
    inv = 1.2 ** (-2.0 * rng.integers(0, 4, m))
    sig = 1.0 / np.sqrt(inv)
    z = pc[kk, pp, 2]
    uv = np.column_stack([u[kk, pp], v[kk, pp]]) + rng.normal(0, noise, (m, 2)) * sig[:, None]
    ur = u[kk, pp] - BF / z + rng.normal(0, noise, m) * sig
    ur[rng.random(m) < (1.0 if mono else 0.2)] = -1.0
    bad = rng.random(m) < outlier_frac
    uv[bad] += rng.uniform(30, 80, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
    fixed = np.zeros(n_kf, bool)
    fixed[:n_fixed] = True
    poses0 = poses_t.copy()
    for k in np.flatnonzero(~fixed):
        poses0[k] = perturb(poses_t[k], rng, rot_deg=1.0, trans=0.02)
    pts0 = pts + rng.normal(size=pts.shape) * 0.03 / np.sqrt(3)
    prob = BAProblem(poses0, fixed, pts0, kk, pp, uv, ur, inv, *CAM)
    return prob, poses_t, pts, bad


def _pose_errors(poses, poses_t):
    return np.array([pose_err(a, b) for a, b in zip(poses, poses_t)])


@pytest.mark.parametrize("mono", [False, True])
def test_bundle_adjust_exact_on_noise_free_data(mono):
    rng = np.random.default_rng(9)
    prob, poses_t, pts_t, _ = ba_scene(rng, mono=mono, n_fixed=2 if mono else 1, noise=0.0)
    res = bundle_adjust(prob)
    e = _pose_errors(res.poses_cw, poses_t)
    assert e[:, 0].max() < 1e-9 and e[:, 1].max() < 1e-9
    n_obs = np.bincount(prob.obs_point, minlength=len(pts_t))
    assert np.abs(res.points_w - pts_t)[n_obs >= 2].max() < 1e-9
    # points nobody observes are returned as given
    assert np.array_equal(res.points_w[n_obs == 0], prob.points_w[n_obs == 0])


@pytest.mark.parametrize("mono", [False, True])
def test_bundle_adjust_converges(mono):
    rng = np.random.default_rng(10)
    # with depth one fixed keyframe fixes the gauge; without, a second one fixes the scale
    prob, poses_t, pts_t, _ = ba_scene(rng, mono=mono, n_fixed=2 if mono else 1)
    res = bundle_adjust(prob)
    chi2_truth = reprojection_errors(prob, poses_t, pts_t)
    assert res.final_error < 0.02 * res.initial_error
    # noise floor: the optimum fits at least as well as the truth (which carries the noise)
    assert res.final_error <= chi2_truth[res.inlier_obs].mean()
    e0 = _pose_errors(prob.poses_cw, poses_t)
    e1 = _pose_errors(res.poses_cw, poses_t)
    free = ~prob.pose_fixed
    # closer to the truth (what is left is the estimation noise of 0.5 px on this geometry)
    assert np.all(e1[free] < e0[free])
    assert e1[free, 0].mean() < 0.7 * e0[free, 0].mean()
    assert e1[free, 1].mean() < 0.7 * e0[free, 1].mean()
    # ... and it is the least-squares optimum: starting from the truth lands on the same estimate
    from_truth = bundle_adjust(BAProblem(poses_t.copy(), prob.pose_fixed, pts_t.copy(),
                                         prob.obs_pose, prob.obs_point, prob.uv, prob.ur,
                                         prob.inv_sigma2, *CAM))
    assert _pose_errors(res.poses_cw, from_truth.poses_cw).max() < 1e-6
    assert np.array_equal(res.poses_cw[prob.pose_fixed], prob.poses_cw[prob.pose_fixed])
    seen = np.bincount(prob.obs_point, minlength=len(pts_t)) >= 2
    d0 = np.linalg.norm(prob.points_w - pts_t, axis=1)[seen].mean()
    d1 = np.linalg.norm(res.points_w - pts_t, axis=1)[seen].mean()
    assert d1 < 0.7 * d0
    assert res.inlier_obs.mean() > 0.97 and res.time_ms > 0


def test_bundle_adjust_reports_outliers():
    rng = np.random.default_rng(11)
    prob, poses_t, _, bad = ba_scene(rng, outlier_frac=0.05)
    assert bad.sum() > 20
    res = bundle_adjust(prob)
    assert not res.inlier_obs[bad].any()
    assert res.inlier_obs[~bad].mean() > 0.97
    e0 = _pose_errors(prob.poses_cw, poses_t)[1:]
    e1 = _pose_errors(res.poses_cw, poses_t)[1:]
    assert np.all(e1 < e0)


def test_bundle_adjust_global_mode_and_local_fixed_set():
    """Global BA (no outlier stage) and a local BA with several fixed keyframes."""
    rng = np.random.default_rng(12)
    prob, poses_t, _, _ = ba_scene(rng, n_fixed=3)
    res = bundle_adjust(prob, iterations=(10, 0), remove_outliers=False)
    assert res.final_error < res.initial_error
    assert np.array_equal(res.poses_cw[:3], prob.poses_cw[:3])
    e0 = _pose_errors(prob.poses_cw, poses_t)[3:, 0]
    e1 = _pose_errors(res.poses_cw, poses_t)[3:, 0]
    assert np.all(e1 < e0)


@pytest.mark.parametrize("case", ["stereo", "mono", "outliers", "global", "fixed3"])
def test_schur_solver_equals_gtsam(case):
    """The numba Schur-complement LM and the GTSAM factor graph minimise the same cost with
    the same schedule: same estimate, same inliers, same iteration count."""
    rng = np.random.default_rng(40)
    kw = {"stereo": {}, "mono": {"mono": True, "n_fixed": 2}, "outliers": {"outlier_frac": 0.05},
          "global": {}, "fixed3": {"n_fixed": 3}}[case]
    prob, poses_t, pts_t, _ = ba_scene(rng, **kw)
    mode = {"iterations": (10, 0), "remove_outliers": False} if case == "global" else {}
    a = bundle_adjust(prob, solver="gtsam", **mode)
    b = bundle_adjust(prob, solver="schur", **mode)
    assert a.converged and b.converged
    assert _pose_errors(a.poses_cw, b.poses_cw).max() < 1e-9
    seen = np.bincount(prob.obs_point, minlength=len(pts_t)) >= 1
    assert np.abs(a.points_w - b.points_w)[seen].max() < 1e-8
    np.testing.assert_array_equal(a.inlier_obs, b.inlier_obs)
    assert b.final_error == pytest.approx(a.final_error, rel=1e-9)
    assert b.timings["iterations"] == a.timings["iterations"]
    assert np.array_equal(b.poses_cw[prob.pose_fixed], prob.poses_cw[prob.pose_fixed])
    # and both are closer to the ground truth than the start
    free = ~prob.pose_fixed
    assert np.all(_pose_errors(b.poses_cw, poses_t)[free, 0] < _pose_errors(prob.poses_cw, poses_t)[free, 0])


def test_schur_solver_keeps_undetermined_points_and_unknown_solver():
    rng = np.random.default_rng(41)
    prob, _, _, _ = ba_scene(rng, n_kf=4, n_pts=60, mono=True, n_fixed=2)
    # a point seen once without depth is not determined: returned as given
    keep = ~((prob.obs_point == 0) & (prob.obs_pose != 2))
    single = BAProblem(prob.poses_cw, prob.pose_fixed, prob.points_w, prob.obs_pose[keep],
                       prob.obs_point[keep], prob.uv[keep], prob.ur[keep],
                       np.asarray(prob.inv_sigma2)[keep], *CAM)
    res = bundle_adjust(single)
    assert np.array_equal(res.points_w[0], prob.points_w[0])
    with pytest.raises(ValueError, match="solver"):
        bundle_adjust(prob, solver="g2o")


def test_reprojection_errors():
    rng = np.random.default_rng(13)
    prob, poses_t, pts_t, _ = ba_scene(rng, noise=0.0)
    chi2 = reprojection_errors(prob, poses_t, pts_t)
    assert chi2.shape == prob.obs_pose.shape and np.all(chi2 < 1e-12)
    # a point moved behind its cameras gets an infinite error
    pts = pts_t.copy()
    pts[0] = [0.0, 0.0, -50.0]
    chi2 = reprojection_errors(prob, poses_t, pts)
    assert np.all(np.isinf(chi2[prob.obs_point == 0]))


# --------------------------------------------------------------------------- pose graph


def loop_graph(n=20, drift_deg=1.0, seed=20):
    """Circle of n poses (T_wc); odometry with a yaw drift, and one exact loop-closure edge."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((n, 4, 4))
    for i in range(n):
        a = 2 * np.pi * i / n
        truth[i] = np.eye(4)
        truth[i, :3, :3] = Rotation.from_rotvec([0, -a, 0]).as_matrix()
        truth[i, :3, 3] = [4 * np.cos(a), 0.0, 4 * np.sin(a)]
    edges, meas = [], []
    drift = se3_exp(np.r_[0, np.radians(drift_deg), 0, 0.01, 0, 0])
    for i in range(n - 1):
        noise = se3_exp(np.r_[rng.normal(0, 1e-4, 3), rng.normal(0, 1e-4, 3)])
        edges.append((i, i + 1))
        meas.append(invert(truth[i]) @ truth[i + 1] @ drift @ noise)
    edges.append((0, n - 1))
    meas.append(invert(truth[0]) @ truth[n - 1])
    init = [truth[0]]
    for i in range(n - 1):
        init.append(init[-1] @ meas[i])
    return truth, np.array(init), np.array(edges), np.array(meas)


def _edge_residuals(poses, edges, meas):
    out = []
    for (i, j), T in zip(edges, meas):
        E = invert(T) @ invert(poses[i]) @ poses[j]
        out.append(np.linalg.norm(E[:3, 3]) + rot_err(E[:3, :3]))
    return np.array(out)


def test_pose_graph_closes_loop():
    truth, init, edges, meas = loop_graph()
    out = optimize_pose_graph(init, edges, meas, fixed=[0])
    assert np.array_equal(out[0], init[0])
    r0 = _edge_residuals(init, edges, meas)
    r1 = _edge_residuals(out, edges, meas)
    assert r1[-1] < 0.1 * r0[-1]  # end-to-start (loop closure) error reduced by > 90 %
    odo = r1[:-1]
    assert odo.max() < 3.0 * odo.mean()  # the correction is spread, not dumped on one edge
    assert odo.min() > 0.2 * odo.mean()
    # and the trajectory is closer to the truth than the drifted one
    def pos_err(p: np.ndarray) -> float:
        return float(np.linalg.norm(p[:, :3, 3] - truth[:, :3, 3], axis=1).mean())

    assert pos_err(out) < 0.5 * pos_err(init)


def test_pose_graph_information_and_weights_agree():
    _, init, edges, meas = loop_graph(n=12, seed=21)
    w = np.linspace(1.0, 3.0, len(edges))
    a = optimize_pose_graph(init, edges, meas, w, [0])  # (E,) weights
    b = optimize_pose_graph(init, edges, meas, w[:, None, None] * np.eye(6), [0])  # (E, 6, 6)
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_pose_graph_untouched_nodes_and_fixed_set():
    _, init, edges, meas = loop_graph(n=10, seed=22)
    extra = np.concatenate([init, init[:1] @ se3_exp(np.r_[0, 0, 0, 1.0, 0, 0])[None]])
    out = optimize_pose_graph(extra, edges, meas, fixed=[0, 5])
    assert np.array_equal(out[10], extra[10])  # no edge: unchanged
    assert np.array_equal(out[[0, 5]], extra[[0, 5]])


def test_correct_points_with_poses():
    rng = np.random.default_rng(30)
    before = np.array([se3_exp(np.r_[rng.normal(0, 0.3, 3), rng.normal(0, 1, 3)])
                       for _ in range(4)])
    after = np.array([se3_exp(np.r_[rng.normal(0, 0.1, 3), rng.normal(0, 0.2, 3)]) @ T
                      for T in before])
    pts = rng.normal(0, 2, (50, 3))
    ref = rng.integers(-1, 4, 50)
    out = correct_points_with_poses(pts, ref, before, after)
    for p, q, r in zip(pts, out, ref):
        if r < 0:
            np.testing.assert_array_equal(q, p)
        else:  # same coordinates in the reference camera before and after
            pc_b = invert(before[r]) @ np.r_[p, 1.0]
            pc_a = invert(after[r]) @ np.r_[q, 1.0]
            np.testing.assert_allclose(pc_a, pc_b, atol=1e-12)
    # analytic: a keyframe translated by d carries its points along by d
    shifted = before.copy()
    shifted[:, :3, 3] += [0.5, -1.0, 2.0]
    moved = correct_points_with_poses(pts, np.zeros(50, int), before, shifted)
    np.testing.assert_allclose(moved - pts, np.tile([0.5, -1.0, 2.0], (50, 1)), atol=1e-12)
