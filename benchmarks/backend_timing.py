"""Timings of the optimisation back end on synthetic RGB-D data (TUM-like camera, bf = 40).

Run: ``.venv/bin/python benchmarks/backend_timing.py [--repeat N]``.  Prints one JSON object
(machine-readable) followed by a small table.  Cases:

* pose-only optimisation (numpy vs GTSAM reference) with 300 / 1000 observations, 0.5 px noise and
  10 % gross outliers;
* local BA: 10 keyframes (7 free, 3 fixed), 3000 points, ~15000 observations, 20 % without depth;
* pose graph: 200 nodes on a loop, odometry + covisibility-like + one loop-closure edge.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from semslam.backend.bundle_adjustment import BAProblem, bundle_adjust
from semslam.backend.pose_graph import optimize_pose_graph
from semslam.backend.pose_only import optimize_pose, optimize_pose_gtsam, se3_exp
from semslam.geometry.se3 import invert

FX = FY = 525.0
CX, CY = 319.5, 239.5
BF = 40.0
W, H = 640, 480


def pose_only_case(n: int, rng: np.random.Generator, noise: float = 0.5, outliers: float = 0.1):
    """(T_true, T_init, pts_w, uv, ur, inv_sigma2) for a single frame."""
    T = se3_exp(np.r_[rng.normal(0, 0.1, 3), rng.normal(0, 0.3, 3)])
    u = rng.uniform(0, W, n)
    v = rng.uniform(0, H, n)
    z = rng.uniform(0.5, 6.0, n)
    pc = np.column_stack([(u - CX) / FX * z, (v - CY) / FY * z, z])
    pw = (pc - T[:3, 3]) @ T[:3, :3]
    inv = 1.2 ** (-2.0 * rng.integers(0, 8, n))
    sig = 1.0 / np.sqrt(inv)
    uv = np.column_stack([u, v]) + rng.normal(0, noise, (n, 2)) * sig[:, None]
    ur = u - BF / z + rng.normal(0, noise, n) * sig
    ur[rng.random(n) < 0.2] = -1.0
    bad = rng.random(n) < outliers
    uv[bad] += rng.uniform(20, 60, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
    T0 = se3_exp(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.03, 3)]) @ T
    return T, T0, pw, uv, ur, inv


def local_ba_case(rng: np.random.Generator, n_kf: int = 10, n_pts: int = 3000, n_fixed: int = 3,
                  obs_per_point: float = 5.0, noise: float = 0.5) -> BAProblem:
    """Keyframes on a 1.5 m arc looking at a box of points; perturbed poses and points."""
    poses = []
    for k in range(n_kf):
        a = -0.25 + 0.5 * k / max(n_kf - 1, 1)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        c = np.array([3.0 * np.sin(-a), 0.05 * np.sin(k), 3.0 - 3.0 * np.cos(a)])
        T_wc = np.eye(4)
        T_wc[:3, :3] = R.T
        T_wc[:3, 3] = c
        poses.append(invert(T_wc))
    poses_true = np.array(poses)
    pts = np.column_stack([rng.uniform(-2.5, 2.5, n_pts), rng.uniform(-1.8, 1.8, n_pts),
                           rng.uniform(3.0, 6.0, n_pts)])
    pc = np.einsum("kij,pj->kpi", poses_true[:, :3, :3], pts) + poses_true[:, None, :3, 3]
    u = FX * pc[..., 0] / pc[..., 2] + CX
    v = FY * pc[..., 1] / pc[..., 2] + CY
    vis = (pc[..., 2] > 0.1) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    keep_p = obs_per_point / np.maximum(vis.sum(0), 1)
    vis &= rng.random(vis.shape) < keep_p[None, :]
    kk, pp = np.nonzero(vis)
    inv = 1.2 ** (-2.0 * rng.integers(0, 8, kk.size))
    sig = 1.0 / np.sqrt(inv)
    z = pc[kk, pp, 2]
    uv = np.column_stack([u[kk, pp], v[kk, pp]]) + rng.normal(0, noise, (kk.size, 2)) * sig[:, None]
    ur = u[kk, pp] - BF / z + rng.normal(0, noise, kk.size) * sig
    ur[rng.random(kk.size) < 0.2] = -1.0
    fixed = np.zeros(n_kf, bool)
    fixed[:n_fixed] = True
    poses0 = poses_true.copy()
    for k in np.flatnonzero(~fixed):
        poses0[k] = se3_exp(np.r_[rng.normal(0, np.radians(1.0) / np.sqrt(3), 3),
                                  rng.normal(0, 0.02 / np.sqrt(3), 3)]) @ poses0[k]
    pts0 = pts + rng.normal(0, 0.03 / np.sqrt(3), pts.shape)
    return BAProblem(poses0, fixed, pts0, kk, pp, uv, ur, inv, FX, FY, CX, CY, BF)


def pose_graph_case(rng: np.random.Generator, n: int = 200):
    """Circle of ``n`` poses; drifted odometry, sparse extra edges and one loop closure."""
    ang = 2 * np.pi * np.arange(n) / n
    poses = np.zeros((n, 4, 4))
    for i, a in enumerate(ang):
        poses[i] = se3_exp(np.r_[0, a, 0, 0, 0, 0])
        poses[i, :3, 3] = [5 * np.cos(a), 0.0, 5 * np.sin(a)]
    edges, meas = [], []
    for i in range(n):
        for d in (1, 2):
            j = i + d
            if j < n:
                edges.append((i, j))
                meas.append(invert(poses[i]) @ poses[j]
                            @ se3_exp(np.r_[rng.normal(0, 2e-3, 3), rng.normal(0, 5e-3, 3)]))
    edges.append((0, n - 1))
    meas.append(invert(poses[0]) @ poses[n - 1])
    edges = np.array(edges)
    meas = np.array(meas)
    init = [poses[0]]
    for i in range(1, n):  # chain the drifted odometry
        k = np.flatnonzero((edges[:, 0] == i - 1) & (edges[:, 1] == i))[0]
        init.append(init[-1] @ meas[k])
    return np.array(init), edges, meas


def _time(fn, repeat: int) -> float:
    fn()  # warm-up
    t = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t) / repeat * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    out: dict[str, float] = {}
    cam = (FX, FY, CX, CY, BF)
    for n in (300, 1000):
        _, T0, pw, uv, ur, inv = pose_only_case(n, rng)
        args_n = (T0, pw, uv, ur, inv, *cam)
        out[f"pose_only_numpy_{n}_ms"] = _time(
            lambda a=args_n: optimize_pose(*a), args.repeat * 10)
        out[f"pose_only_gtsam_{n}_ms"] = _time(
            lambda a=args_n: optimize_pose_gtsam(*a), max(args.repeat // 10, 1))
    prob = local_ba_case(rng)
    out["local_ba_n_obs"] = int(prob.obs_pose.size)
    res = bundle_adjust(prob)
    out["local_ba_ms"] = _time(lambda: bundle_adjust(prob), max(args.repeat // 4, 2))
    out["local_ba_error_initial"] = res.initial_error
    out["local_ba_error_final"] = res.final_error
    init, edges, meas = pose_graph_case(rng)
    out["pose_graph_200_ms"] = _time(lambda: optimize_pose_graph(init, edges, meas, fixed=[0]),
                                     args.repeat)
    print(json.dumps(out, indent=1))
    print(f"{'case':<32}{'ms':>10}")
    for k, v in out.items():
        if k.endswith("_ms"):
            print(f"{k[:-3]:<32}{v:>10.2f}")


if __name__ == "__main__":
    main()
