"""The IMU's keyframe links: bundle adjustment with relative-pose links (against an
independent least-squares solve of the same cost, and GTSAM's BetweenFactorPose3), and the
chain of predicted motions that links consecutive keyframes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from semslam.backend.bundle_adjustment import BAProblem, bundle_adjust
from semslam.backend.pose_only import se3_exp
from semslam.core.types import Keypoints
from semslam.geometry.se3 import invert
from semslam.slam.orb.inertial_links import MotionChain, add_links, link_to
from semslam.slam.orb.map import KeyFrame

FX, FY, CX, CY = 500.0, 500.0, 320.0, 240.0
N_POSES, N_POINTS = 4, 40


def _mono_problem(rng: np.random.Generator, links: bool) -> tuple[BAProblem, np.ndarray]:
    """Four monocular keyframes (the first fixed) seeing 40 points, 1 px noise, starting a few
    cm off; with ``links`` consecutive poses are linked by their true motion plus 1 mrad / 3 mm
    noise (what the IMU measures). Returns the problem and the true poses."""
    true = np.stack([np.eye(4)] + [se3_exp(np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3)])
                                   for _ in range(N_POSES - 1)])
    pts = rng.uniform([-2, -2, 3], [2, 2, 6], (N_POINTS, 3))
    pc = np.einsum("kij,pj->kpi", true[:, :3, :3], pts) + true[:, None, :3, 3]
    uv = np.stack([FX * pc[..., 0] / pc[..., 2] + CX, FY * pc[..., 1] / pc[..., 2] + CY], -1).reshape(-1, 2)
    uv += rng.normal(0, 1.0, uv.shape)
    init = true.copy()
    for k in range(1, N_POSES):
        init[k] = se3_exp(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.03, 3)]) @ true[k]
    m = N_POSES * N_POINTS
    problem = BAProblem(init, np.array([True] + [False] * (N_POSES - 1)), pts + rng.normal(0, 0.05, pts.shape),
                        np.repeat(np.arange(N_POSES), N_POINTS), np.tile(np.arange(N_POINTS), N_POSES), uv,
                        -np.ones(m), np.ones(m), FX, FY, CX, CY, 40.0)
    if links:
        problem.link_pose = np.array([[k, k + 1] for k in range(N_POSES - 1)], np.intp)
        problem.link_T = np.stack([se3_exp(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 3e-3, 3)])
                                   @ true[k + 1] @ invert(true[k]) for k in range(N_POSES - 1)])
        problem.link_info = np.stack([np.diag([1e6] * 3 + [1 / 3e-3 ** 2] * 3)] * (N_POSES - 1))
    return problem, true


def _least_squares(problem: BAProblem) -> np.ndarray:
    """The same cost (reprojections, links' (Log(dR), dt) whitened) minimised by scipy."""
    init, free = problem.poses_cw, np.flatnonzero(~problem.pose_fixed)
    whiten = [np.linalg.cholesky(info).T for info in problem.link_info]

    def poses(x: np.ndarray) -> np.ndarray:
        out = init.copy()
        for i, k in enumerate(free):
            out[k] = se3_exp(x[6 * i:6 * i + 6]) @ init[k]
        return out

    def fun(x: np.ndarray) -> np.ndarray:
        T = poses(x)
        X = problem.points_w + x[6 * free.size:].reshape(-1, 3)
        Tk = T[problem.obs_pose]
        pc = np.einsum("mij,mj->mi", Tk[:, :3, :3], X[problem.obs_point]) + Tk[:, :3, 3]
        res = [(problem.uv - np.column_stack([FX * pc[:, 0] / pc[:, 2] + CX, FY * pc[:, 1] / pc[:, 2] + CY])).ravel()]
        for (a, b), Z, W in zip(problem.link_pose, problem.link_T, whiten):
            D = Z @ T[a] @ invert(T[b])
            res.append(W @ np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]])
        return np.concatenate(res)

    x = least_squares(fun, np.zeros(6 * free.size + problem.points_w.size), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    return poses(x)


def test_links_in_the_schur_solver_minimise_their_cost():
    """Both solvers reach the minimum of the same cost (scipy's, independently; GTSAM's
    BetweenFactorPose3 differs from the links' residual at second order only), and the links hold a monocular BA to
    metres: closer to the true poses than without them."""
    rng = np.random.default_rng(1)
    problem, true = _mono_problem(rng, links=True)
    ref = _least_squares(problem)
    schur = bundle_adjust(problem, iterations=(100, 0), robust=False, remove_outliers=False)
    graph = bundle_adjust(problem, iterations=(100, 0), robust=False, remove_outliers=False, solver="gtsam")
    # scipy's finite-difference Jacobians leave it ~1e-5 from the minimum the two solvers share.
    np.testing.assert_allclose(schur.poses_cw, ref, atol=5e-5)
    np.testing.assert_allclose(schur.poses_cw, graph.poses_cw, atol=1e-6)
    plain, _ = _mono_problem(np.random.default_rng(1), links=False)
    without = bundle_adjust(plain, iterations=(100, 0), robust=False, remove_outliers=False)
    err_with = np.abs(schur.poses_cw - true)[:, :3, 3].max()
    err_without = np.abs(without.poses_cw - true)[:, :3, 3].max()
    assert err_with < 0.005 < err_without, (err_with, err_without)


def _keyframe(kf_id: int, T_cw: np.ndarray, map_id: int = 0) -> KeyFrame:
    empty = Keypoints(np.zeros((0, 2), np.float32), np.zeros(0, np.int32), np.zeros(0, np.float32),
                      np.zeros(0, np.float32), np.zeros((0, 32), np.uint8))
    return KeyFrame(kf_id, kf_id, float(kf_id), T_cw, empty, np.zeros((0, 2)), np.zeros(0, np.float32),
                    np.zeros(0), [], map_id=map_id)


def test_chain_links_keyframes_and_composes_over_culled_ones():
    rng = np.random.default_rng(2)
    motions = [se3_exp(np.r_[rng.normal(0, 0.02, 3), rng.normal(0, 0.02, 3)]) for _ in range(6)]
    cov = np.diag([1e-6] * 3 + [1e-4] * 3)
    chain = MotionChain()
    a = _keyframe(0, np.eye(4))
    chain.new_keyframe(a)
    T = np.eye(4)
    for M in motions[:3]:
        chain.frame(M, cov)
        T = M @ T
    b = _keyframe(1, T.copy())
    chain.new_keyframe(b)
    assert b.inertial_link is not None and b.inertial_link.previous is a
    np.testing.assert_allclose(b.inertial_link.T, motions[2] @ motions[1] @ motions[0], atol=1e-12)
    assert b.inertial_link.sigma_rotation == pytest.approx(3e-3)  # spreads add up
    assert b.inertial_link.sigma_translation == pytest.approx(3e-2)
    for M in motions[3:]:
        chain.frame(M, cov)
        T = M @ T
    c = _keyframe(2, T.copy())
    chain.new_keyframe(c)
    assert chain.n_links == 2
    # b culled: c's link reaches a, composed; a fixed and c free give one link in a problem.
    b.bad = True
    found = link_to(c, {a: 0, c: 1})
    assert found is not None and found[0] == 0
    np.testing.assert_allclose(found[1].T @ a.T_cw, c.T_cw, atol=1e-12)
    assert found[1].sigma_translation == pytest.approx(6e-2)
    problem = BAProblem(np.stack([a.T_cw, c.T_cw]), np.array([True, False]), np.zeros((0, 3)), np.zeros(0, np.intp),
                        np.zeros(0, np.intp), np.zeros((0, 2)), np.zeros(0), np.zeros(0), FX, FY, CX, CY, 40.0)
    add_links(problem, [a, c])
    np.testing.assert_array_equal(problem.link_pose, [[0, 1]])
    # A live keyframe outside the problem ends the link; a frame without a measured motion
    # breaks the chain; a keyframe in another map is never linked.
    b.bad = False
    assert link_to(c, {a: 0, c: 1}) is None
    chain.frame(None, None)
    d = _keyframe(3, np.eye(4))
    chain.new_keyframe(d)
    assert d.inertial_link is None
    chain.frame(motions[0], cov)
    e = _keyframe(4, np.eye(4), map_id=1)
    chain.new_keyframe(e)
    assert e.inertial_link is None and chain.n_links == 2
