#!/usr/bin/env python
"""Benchmark: one motion-only pose optimisation, numpy reference vs the compiled kernel.

    python benchmarks/pose_only_timing.py [--sizes 200,400,800] [--cases 5] [--repeat 40]

Per size, ``--cases`` synthetic frames (TUM-like camera, bf = 40, 20 % of observations without
depth, 0.5 px noise at level 0 scaled by octave, 10 % gross outliers, a start 1 deg / 3 cm
off, as ``benchmarks/backend_timing.py``) are each solved ``--repeat`` times by
``optimize_pose_numpy`` and by ``optimize_pose`` (the numba kernel; warmed up first, so no
JIT time is counted).  Reports the median CPU time (this thread) of one call over all cases
and repeats, and checks that both return the same inliers and pose.  Prints one JSON object,
then a markdown table.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from semslam.backend.pose_only import optimize_pose, optimize_pose_numpy, se3_exp
from semslam.backend.pose_only_kernel import warm_up

FX = FY = 525.0
CX, CY = 319.5, 239.5
BF = 40.0
W, H = 640, 480


def case(n: int, rng: np.random.Generator, noise: float = 0.5, outliers: float = 0.1):
    """(T_init, pts_w, uv, ur, inv_sigma2) of one frame with ``n`` matched map points."""
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
    d = np.r_[rng.normal(size=3), rng.normal(size=3)]
    d[:3] *= np.radians(1.0) / np.linalg.norm(d[:3])
    d[3:] *= 0.03 / np.linalg.norm(d[3:])
    return se3_exp(d) @ T, pw, uv, ur, inv


def _cpu_us(fn, repeat: int) -> list[float]:
    fn()
    out = []
    for _ in range(repeat):
        t = time.thread_time()
        fn()
        out.append((time.thread_time() - t) * 1e6)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="200,400,800")
    ap.add_argument("--cases", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=40)
    args = ap.parse_args()
    t0 = time.perf_counter()
    warm_up()
    out: dict[str, object] = {"warm_up_s": round(time.perf_counter() - t0, 3), "sizes": {}}
    rng = np.random.default_rng(0)
    cam = (FX, FY, CX, CY, BF)
    for n in (int(s) for s in args.sizes.split(",")):
        ref: list[float] = []
        ker: list[float] = []
        max_dT = 0.0
        for _ in range(args.cases):
            a = (*case(n, rng), *cam)
            r, k = optimize_pose_numpy(*a), optimize_pose(*a)
            if not np.array_equal(r.inliers, k.inliers):
                raise SystemExit(f"n={n}: the kernel's inliers differ from the reference's")
            max_dT = max(max_dT, float(np.abs(r.T_cw - k.T_cw).max()))
            ref += _cpu_us(lambda a=a: optimize_pose_numpy(*a), args.repeat)
            ker += _cpu_us(lambda a=a: optimize_pose(*a), args.repeat)
        out["sizes"][str(n)] = {
            "numpy_us": round(float(np.median(ref)), 1),
            "kernel_us": round(float(np.median(ker)), 1),
            "speedup": round(float(np.median(ref) / np.median(ker)), 1),
            "max_abs_pose_diff": max_dT,
        }
    print(json.dumps(out))
    print()
    print("| observations | numpy (us) | kernel (us) | speed-up | max pose diff |")
    print("|---:|---:|---:|---:|---:|")
    for n, r in out["sizes"].items():  # type: ignore[union-attr]
        print(f"| {n} | {r['numpy_us']:.0f} | {r['kernel_us']:.0f} | {r['speedup']:.1f}x "
              f"| {r['max_abs_pose_diff']:.1e} |")


if __name__ == "__main__":
    main()
