"""Timings of the optimisation back end and of local mapping's use of the map lock.

Run ``.venv/bin/python benchmarks/backend_timing.py MODE ...``; every mode prints one JSON
object (machine-readable) followed by a table.  Timings are medians over repeats, CPU time
where a single thread does the work (the machine is shared and has 2 cores), wall time where
waiting is what is measured.

``synthetic [--repeat N]`` (the default): synthetic RGB-D data (TUM-like camera, bf = 40):

* pose-only optimisation (numba kernel vs its numpy reference vs GTSAM) with 300 / 1000
  observations, 0.5 px noise and 10 % gross outliers (``benchmarks/pose_only_timing.py`` has
  more sizes);
* local BA: 10 keyframes (7 free, 3 fixed), 3000 points, ~15000 observations, 20 % without
  depth, with both solvers (``schur``: numba, ``gtsam``);
* pose graph: 200 nodes on a loop, odometry + covisibility-like + one loop-closure edge.

``windows SEQ [--frames N] [--cache FILE]``: the local BA problems ORB-SLAM2's window really
produces.  A sequential run (``--preset orb``) over the first N frames of SEQ records every
local BA problem (cached in FILE), then each is solved with the Schur solver and with GTSAM
under several optimiser settings (LM with sequential / multifrontal Cholesky and a Schur or
COLAMD ordering, Gauss-Newton, Dogleg), split into graph building and optimisation.

``slam SEQ [--preset P] [--runs R] [--frames N]``: threaded runs through the pipeline with
``Map.lock`` replaced by a proxy that records how long each thread waited for it and held it.
Reports tracking's lock wait (median / p95 / max), local mapping's critical sections, the split
of local BA time (gather, IPC to the worker process, graph build, optimise, check, apply),
local mapping's steps (wall and CPU), ms/frame and ATE.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from semslam.backend.bundle_adjustment import BAProblem, bundle_adjust
from semslam.backend.pose_graph import optimize_pose_graph
from semslam.backend.pose_only import (
    optimize_pose,
    optimize_pose_gtsam,
    optimize_pose_numpy,
    se3_exp,
)
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


def _cpu_ms(fn, repeat: int) -> float:
    """Median CPU time (this thread, ms) of ``fn`` over ``repeat`` calls after one warm-up."""
    fn()
    out = []
    for _ in range(repeat):
        t = time.thread_time()
        fn()
        out.append((time.thread_time() - t) * 1e3)
    return float(np.median(out))


def _stats(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0, "median": 0.0, "p95": 0.0, "max": 0.0}
    a = np.asarray(values, dtype=np.float64)
    return {"n": int(a.size), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
            "max": float(a.max())}


def _table(rows: list[tuple[str, Any]]) -> None:
    print(f"{'case':<48}{'value':>12}")
    for k, v in rows:
        print(f"{k:<48}{v:>12.2f}" if isinstance(v, (int, float)) else f"{k:<48}{v!s:>12}")


# --------------------------------------------------------------------------- synthetic


def synthetic(args: argparse.Namespace) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    out: dict[str, Any] = {}
    cam = (FX, FY, CX, CY, BF)
    for n in (300, 1000):
        _, T0, pw, uv, ur, inv = pose_only_case(n, rng)
        args_n = (T0, pw, uv, ur, inv, *cam)
        out[f"pose_only_kernel_{n}_ms"] = _cpu_ms(lambda a=args_n: optimize_pose(*a), args.repeat * 10)
        out[f"pose_only_numpy_{n}_ms"] = _cpu_ms(lambda a=args_n: optimize_pose_numpy(*a),
                                                 args.repeat * 10)
        out[f"pose_only_gtsam_{n}_ms"] = _cpu_ms(lambda a=args_n: optimize_pose_gtsam(*a),
                                                 max(args.repeat // 10, 1))
    prob = local_ba_case(rng)
    out["local_ba_n_obs"] = int(prob.obs_pose.size)
    for solver in ("schur", "gtsam"):
        res = bundle_adjust(prob, solver=solver)
        out[f"local_ba_{solver}_ms"] = _cpu_ms(lambda s=solver: bundle_adjust(prob, solver=s),
                                               max(args.repeat // 4, 2))
        out[f"local_ba_{solver}_error_initial"] = res.initial_error
        out[f"local_ba_{solver}_error_final"] = res.final_error
    init, edges, meas = pose_graph_case(rng)
    out["pose_graph_200_ms"] = _cpu_ms(lambda: optimize_pose_graph(init, edges, meas, fixed=[0]),
                                       args.repeat)
    return out


# --------------------------------------------------------------------------- real windows


def record_windows(seq: Path, frames: int, preset: str,
                   overrides: list[str] | None = None) -> list[BAProblem]:
    """Every local BA problem of a sequential run over the first ``frames`` frames."""
    import tempfile

    from semslam.backend.worker import BundleAdjustmentRunner
    from semslam.config import load_config
    from semslam.io.sequence import open_sequence
    from semslam.pipeline import run_slam

    problems: list[BAProblem] = []
    original = BundleAdjustmentRunner.run

    def recording(self, problem, **kwargs):
        if not kwargs:  # local BA (global BA passes its schedule)
            problems.append(problem)
        return original(self, problem, **kwargs)

    BundleAdjustmentRunner.run = recording
    try:
        cfg = load_config(preset, ["slam.sequential=true", *(overrides or [])])
        with tempfile.TemporaryDirectory() as tmp:
            run_slam(open_sequence(seq), cfg, tmp, max_frames=frames, progress=False, report=False)
    finally:
        BundleAdjustmentRunner.run = original
    return problems


def _gtsam_variant(problem: BAProblem, variant: str, iterations: tuple[int, int] = (5, 10)
                   ) -> dict[str, float]:
    """ORB-SLAM2's schedule on GTSAM with one optimiser setting; build and optimise times
    (CPU ms) and the final mean chi2 over the inliers."""
    import gtsam

    from semslam.backend import bundle_adjustment as ba
    from semslam.backend.gtsam_utils import mono_calibration, stereo_calibration

    p = ba._normalized(problem)
    Ks = stereo_calibration(p.fx, p.fy, p.cx, p.cy, p.bf)
    Km = mono_calibration(p.fx, p.fy, p.cx, p.cy)
    thr = ba._chi2_threshold(p)
    K = p.poses_cw.shape[0]
    poses, points = p.poses_cw, p.points_w
    build = opt = 0.0
    n_it = 0
    active = np.ones(p.obs_pose.size, bool)
    for stage, n in enumerate(iterations):
        if stage == 1:
            active = ba.reprojection_errors(p, poses, points) <= thr
        act = active & ba._constrained_points(p, active)[p.obs_point]
        t = time.thread_time()
        pose_keys = np.unique(p.obs_pose[act])
        point_idx = np.unique(p.obs_point[act])
        graph = ba._build_graph(p, act, stage == 0, Ks, Km)
        values = ba._values(invert(poses), points, pose_keys, point_idx)
        kind, _, solver = variant.partition(":")
        if kind == "lm":
            params = gtsam.LevenbergMarquardtParams()
        elif kind == "gn":
            params = gtsam.GaussNewtonParams()
        else:
            params = gtsam.DoglegParams()
        params.setMaxIterations(n)
        if "schur" in solver:
            ordering = gtsam.Ordering()
            for key in (point_idx + K).tolist():
                ordering.push_back(key)
            for key in pose_keys.tolist():
                ordering.push_back(key)
            params.setOrdering(ordering)
        params.setLinearSolverType("SEQUENTIAL_CHOLESKY" if "seq" in solver
                                   else "MULTIFRONTAL_CHOLESKY")
        t1 = time.thread_time()
        opt_cls = {"lm": gtsam.LevenbergMarquardtOptimizer, "gn": gtsam.GaussNewtonOptimizer,
                   "dl": gtsam.DoglegOptimizer}[kind]
        optimizer = opt_cls(graph, values, params)
        result = optimizer.optimize()
        t2 = time.thread_time()
        n_it += optimizer.iterations()
        poses = poses.copy()
        points = points.copy()
        free = pose_keys[~p.pose_fixed[pose_keys]]
        wc = ba.poses_from_rows(gtsam.utilities.extractPose3(result))
        poses[free] = invert(wc[~p.pose_fixed[pose_keys]])
        points[point_idx] = gtsam.utilities.extractPoint3(result)
        build += (t1 - t) * 1e3
        opt += (t2 - t1) * 1e3
    chi2 = ba.reprojection_errors(p, poses, points)
    inl = chi2 <= thr
    return {"build": build, "optimize": opt, "iterations": float(n_it),
            "final_error": float(chi2[inl].mean())}


GTSAM_VARIANTS = ["lm:seq-schur", "lm:multi-schur", "lm:multi-colamd", "gn:seq-schur",
                  "dl:seq-schur"]


def windows(args: argparse.Namespace) -> dict[str, Any]:
    cache = Path(args.cache)
    if cache.is_file():
        problems = pickle.loads(cache.read_bytes())
    else:
        problems = record_windows(Path(args.sequence), args.frames, args.preset, args.set)
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_bytes(pickle.dumps(problems))
    sizes = {
        "keyframes": _stats([q.poses_cw.shape[0] for q in problems]),
        "free": _stats([int((~np.asarray(q.pose_fixed)).sum()) for q in problems]),
        "points": _stats([q.points_w.shape[0] for q in problems]),
        "observations": _stats([q.obs_pose.size for q in problems]),
    }
    out: dict[str, Any] = {"windows": len(problems), "sizes": sizes}
    for solver in ("schur", "gtsam"):
        bundle_adjust(problems[0], solver=solver)  # warm-up (numba cache load, gtsam import)
        rows: dict[str, list[float]] = defaultdict(list)
        for q in problems[:: args.stride]:
            c = time.thread_time()
            res = bundle_adjust(q, solver=solver)
            rows["cpu_total"].append((time.thread_time() - c) * 1e3)
            for k, v in res.timings.items():
                rows[k].append(v)
            rows["final_error"].append(res.final_error)
        out[f"bundle_adjust[{solver}]"] = {k: _stats(v) for k, v in rows.items()}
    if not args.skip_variants:
        for variant in GTSAM_VARIANTS:
            rows = defaultdict(list)
            for q in problems[:: args.stride * 2]:
                for k, v in _gtsam_variant(q, variant).items():
                    rows[k].append(v)
            out[f"gtsam[{variant}]"] = {k: _stats(v) for k, v in rows.items()}
    return out


# --------------------------------------------------------------------------- threaded SLAM


class TimedLock:
    """A stand-in for ``Map.lock`` (an RLock) that records, per thread name, how long each
    outermost acquisition waited and how long the lock was then held (seconds), and the
    holds per critical section (thread and the function that entered it)."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self._local = threading.local()
        self.waits: dict[str, list[float]] = defaultdict(list)
        self.holds: dict[str, list[float]] = defaultdict(list)
        self.sections: dict[str, list[float]] = defaultdict(list)

    def acquire(self, blocking: bool = True, timeout: float = -1, site: str = "?") -> bool:
        depth = getattr(self._local, "depth", 0)
        t0 = time.perf_counter()
        ok = self._inner.acquire(blocking, timeout)
        if ok:
            if depth == 0:
                t1 = time.perf_counter()
                self.waits[threading.current_thread().name].append(t1 - t0)
                self._local.t_acquired = t1
                self._local.site = site
            self._local.depth = depth + 1
        return ok

    def release(self) -> None:
        depth = self._local.depth - 1
        self._local.depth = depth
        if depth == 0:
            held = time.perf_counter() - self._local.t_acquired
            name = threading.current_thread().name
            self.holds[name].append(held)
            self.sections[f"{name}:{self._local.site}"].append(held)
        self._inner.release()

    def __enter__(self) -> bool:
        return self.acquire(site=sys._getframe(1).f_code.co_name)

    def __exit__(self, *exc: object) -> None:
        self.release()


def slam_run(seq: Path, preset: str, frames: int | None, out_dir: Path,
             overrides: list[str] | None = None) -> dict[str, Any]:
    """One threaded run with the timed lock; returns the lock, BA and run statistics."""
    from semslam.config import load_config
    from semslam.io.sequence import open_sequence
    from semslam.pipeline import run_slam
    from semslam.slam.orb import local_mapping, map as map_mod

    locks: list[TimedLock] = []
    mappers: list[Any] = []
    map_init = map_mod.Map.__init__
    lm_init = local_mapping.LocalMapping.__init__

    def timed_map_init(self, *a, **kw):
        map_init(self, *a, **kw)
        self.lock = TimedLock(self.lock)
        locks.append(self.lock)

    def collecting_lm_init(self, *a, **kw):
        lm_init(self, *a, **kw)
        mappers.append(self)

    map_mod.Map.__init__ = timed_map_init
    local_mapping.LocalMapping.__init__ = collecting_lm_init
    try:
        cfg = load_config(preset, overrides or [])
        result = run_slam(open_sequence(seq), cfg, out_dir, max_frames=frames, progress=False,
                          report=False)
    finally:
        map_mod.Map.__init__ = map_init
        local_mapping.LocalMapping.__init__ = lm_init
    lock, mapper = locks[-1], mappers[-1]
    ms = 1e3
    out: dict[str, Any] = {
        "ate_rmse_m": (result.ate or {}).get("rmse"),
        "ms_per_frame": result.ms_per_frame,
        "keyframes": result.keyframes,
        "tracking_lock_wait_ms": _stats([w * ms for w in lock.waits.get("MainThread", [])]),
        "lock_hold_ms": {name: _stats([h * ms for h in v]) for name, v in lock.holds.items()},
        "lock_wait_ms": {name: _stats([w * ms for w in v]) for name, v in lock.waits.items()},
        "lock_sections_ms": {site: _stats([h * ms for h in v]) for site, v in lock.sections.items()},
    }
    split: dict[str, list[float]] = defaultdict(list)
    for rec in mapper.stats.get("local_ba_split", []):
        for k, v in rec.items():
            split[k].append(v)
    out["local_ba"] = {k: _stats(v) for k, v in split.items()}
    out["mapping_steps"] = {name: {k: _stats(v) for k, v in rec.items()}
                            for name, rec in mapper.stats.get("steps", {}).items()}
    return out


def slam(args: argparse.Namespace) -> dict[str, Any]:
    runs = []
    for r in range(args.runs):
        runs.append(slam_run(Path(args.sequence), args.preset, args.frames,
                             Path(args.out) / f"run{r}", args.set))
    merged: dict[str, Any] = {"runs": runs}
    merged["ate_rmse_m"] = [r["ate_rmse_m"] for r in runs]
    for key in ("tracking_lock_wait_ms",):
        merged[key] = {s: float(np.median([r[key][s] for r in runs])) for s in ("median", "p95", "max")}
    merged["local_ba_total_ms_median"] = float(np.median([r["local_ba"]["total"]["median"]
                                                         for r in runs if r["local_ba"]]))
    return merged


def _slam_table(out: dict[str, Any]) -> list[tuple[str, Any]]:
    rows: list[tuple[str, Any]] = []
    for i, r in enumerate(out["runs"]):
        rows.append((f"run {i}: ATE rmse (mm)", (r["ate_rmse_m"] or float("nan")) * 1e3))
        rows.append((f"run {i}: ms/frame p95", r["ms_per_frame"].get("p95", float("nan"))))
        w = r["tracking_lock_wait_ms"]
        rows.append((f"run {i}: tracking lock wait median/p95/max",
                     f"{w['median']:.2f}/{w['p95']:.2f}/{w['max']:.1f}"))
        for name, h in r["lock_hold_ms"].items():
            rows.append((f"run {i}: lock held by {name[:18]} med/p95/max",
                         f"{h['median']:.1f}/{h['p95']:.1f}/{h['max']:.0f}"))
        for site, h in r["lock_sections_ms"].items():
            if not site.startswith("MainThread"):
                rows.append((f"run {i}: {site[:28]} n/med/p95/max",
                             f"{h['n']}/{h['median']:.1f}/{h['p95']:.1f}/{h['max']:.0f}"))
        for k, v in r["local_ba"].items():
            rows.append((f"run {i}: local BA {k} (median)", v["median"]))
        for name, rec in r["mapping_steps"].items():
            rows.append((f"run {i}: mapping {name} wall/cpu ms",
                         f"{rec['wall_ms']['median']:.1f}/{rec['cpu_ms']['median']:.1f}"))
    return rows


def main() -> None:
    from semslam.runtime import limit_threads

    limit_threads()
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="mode")
    s = sub.add_parser("synthetic")
    s.add_argument("--repeat", type=int, default=20)
    w = sub.add_parser("windows")
    w.add_argument("sequence")
    w.add_argument("--frames", type=int, default=200)
    w.add_argument("--preset", default="orb")
    w.add_argument("--cache", default="out/backend_timing/windows.pkl")
    w.add_argument("--stride", type=int, default=1, help="time every n-th window")
    w.add_argument("--skip-variants", action="store_true", help="no GTSAM optimiser variants")
    w.add_argument("--set", action="append", default=[], help="config override for the recording run")
    r = sub.add_parser("slam")
    r.add_argument("sequence")
    r.add_argument("--preset", default="orb")
    r.add_argument("--runs", type=int, default=1)
    r.add_argument("--frames", type=int, default=None)
    r.add_argument("--out", default="out/backend_timing/slam")
    r.add_argument("--set", action="append", default=[], help="config override section.key=value")
    args = ap.parse_args()
    if args.mode in (None, "synthetic"):
        args.repeat = getattr(args, "repeat", 20)
        out = synthetic(args)
        print(json.dumps(out, indent=1))
        _table([(k[:-3], v) for k, v in out.items() if k.endswith("_ms")])
    elif args.mode == "windows":
        out = windows(args)
        print(json.dumps(out, indent=1))
        rows = [(f"window {k} (median)", v["median"]) for k, v in out["sizes"].items()]
        for name, rec in out.items():
            if isinstance(rec, dict) and "optimize" in rec:
                for k in ("cpu_total", "build", "optimize", "check", "iterations", "final_error"):
                    if k in rec:
                        rows.append((f"{name} {k} (median)", rec[k]["median"]))
        _table(rows)
    else:
        out = slam(args)
        print(json.dumps(out, indent=1, default=float))
        _table(_slam_table(out))


if __name__ == "__main__":
    main()
