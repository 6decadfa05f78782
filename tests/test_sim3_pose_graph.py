"""The Sim(3) essential graph (``backend.pose_graph.optimize_sim3_pose_graph``, ORB-SLAM's
OptimizeEssentialGraph for a monocular map) on analytic chains.

A camera goes round a circle of N keyframes; a monocular estimate of it drifts in scale by
a factor (1 + d) per step, so the odometry edges (relative poses of the drifted estimate,
scale 1) each carry the drift, and one loop edge (last -> first keyframe, a Sim(3) as the
loop's RANSAC measures it) says how much scale accumulated. Checked against the ground
truth chain, independent of GTSAM:

- with every edge exact, the optimiser returns the ground truth chain itself (this pins the
  conversion between our ``[[s R, t], [0, 1]]`` and GTSAM's ``Similarity3``);
- with the drifted odometry, the log-scales of the nodes are the least-squares spread of
  the loop's scale discrepancy over the cycle's N edges: node i gets
  ``-i (N - 1) log(1 + d) / N`` (the 1-D problem solved by hand; the translations couple to
  it only at second order), and the positions come back near the truth.
"""

from __future__ import annotations

import numpy as np

from semslam.backend.pose_graph import optimize_pose_graph, optimize_sim3_pose_graph
from semslam.backend.sim3 import rigid_part
from semslam.backend.sim3 import sim3_inverse, sim3_parts
from semslam.geometry.se3 import invert, make_pose, so3_exp

N = 20
DRIFT = 0.02  # scale drift per step


def _chain() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ground truth positions, the drifted estimate's rigid T_wc, the ground truth Sim(3)
    nodes S_wc (scale 1 / lambda_i: what maps the drifted units back to metres) and the
    per-node drift lambda_i."""
    ang = np.linspace(0.0, 2 * np.pi, N + 1)[:-1]
    R = [so3_exp(np.array([0.1 * np.sin(a), 0.0, a])) for a in ang]
    c = 2.0 * np.stack([[np.cos(a), np.sin(a), 0.05 * np.sin(3 * a)] for a in ang])
    lam = (1.0 + DRIFT) ** np.arange(N)
    ce = c.copy()
    for i in range(N - 1):
        ce[i + 1] = ce[i] + lam[i] * (c[i + 1] - c[i])
    est = np.stack([make_pose(R[i], ce[i]) for i in range(N)])
    truth = np.stack([make_pose(R[i] / lam[i], c[i]) for i in range(N)])
    return c, est, truth, lam


def _edges() -> np.ndarray:
    return np.array([(i, i + 1) for i in range(N - 1)] + [(N - 1, 0)], np.intp)


def test_exact_edges_give_back_the_ground_truth_chain() -> None:
    _, est, truth, _ = _chain()
    edges = _edges()
    meas = np.stack([sim3_inverse(truth[i]) @ truth[j] for i, j in edges])
    out = optimize_sim3_pose_graph(est, edges, meas, fixed=[0])
    # Started from the drifted rigid chain (all scales 1, last keyframe 0.47 m off).
    assert np.abs(est - truth).max() > 0.4
    np.testing.assert_allclose(out, truth, atol=1e-6)
    assert np.array_equal(out[0], est[0])  # the fixed node verbatim


def test_loop_scale_correction_spreads_over_the_chain() -> None:
    c, est, truth, lam = _chain()
    edges = _edges()
    meas = [invert(est[i]) @ est[j] for i, j in edges[:-1]]  # odometry: the drifted estimate
    meas.append(sim3_inverse(truth[N - 1]) @ truth[0])  # the loop: a Sim(3), measured exactly
    out = optimize_sim3_pose_graph(est, edges, np.stack(meas), fixed=[0])
    log_s = np.log([sim3_parts(S)[2] for S in out])
    step = (N - 1) * np.log1p(DRIFT) / N  # least squares over the cycle, by hand
    expected = -np.arange(N) * step
    # Measured: max deviation 0.0031 of a total correction of 0.36 (translation coupling).
    np.testing.assert_allclose(log_s, expected, atol=0.006)
    assert np.all(np.diff(log_s) < 0)  # every step takes a share, none the whole
    before = np.linalg.norm(est[:, :3, 3] - c, axis=1).max()
    after = np.linalg.norm(out[:, :3, 3] - c, axis=1).max()
    assert before > 0.9 and after < 0.06, (before, after)  # measured 0.94 -> 0.043 m


def test_rigid_part_keeps_what_the_camera_sees() -> None:
    rng = np.random.default_rng(3)
    T = make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    S = make_pose(0.7 * T[:3, :3], 0.7 * T[:3, 3])  # T_cw with the world scaled by 1 / 0.7
    np.testing.assert_allclose(rigid_part(S), T, atol=1e-12)
    X = rng.normal(size=(10, 3)) + [0, 0, 5]
    x_s = X @ S[:3, :3].T + S[:3, 3]
    x_t = X @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(x_s[:, :2] / x_s[:, 2:], x_t[:, :2] / x_t[:, 2:], atol=1e-12)


def test_unit_scale_graph_matches_the_se3_one() -> None:
    # Rigid measurements and a rigid start: the Sim(3) graph lands where the SE(3) one does
    # (scale stays 1: nothing asks for another).
    c, est, _, _ = _chain()
    rng = np.random.default_rng(0)
    truth_rigid = np.stack([make_pose(rigid_part(e)[:3, :3], p) for e, p in zip(est, c)])
    edges = _edges()
    meas = np.stack([invert(truth_rigid[i]) @ truth_rigid[j] for i, j in edges])
    start = truth_rigid.copy()
    start[1:, :3, 3] += rng.normal(scale=0.05, size=(N - 1, 3))
    se3 = optimize_pose_graph(start, edges, meas, fixed=[0])
    sim3 = optimize_sim3_pose_graph(start, edges, meas, fixed=[0])
    np.testing.assert_allclose(sim3, se3, atol=1e-6)

