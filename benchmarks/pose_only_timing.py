#!/usr/bin/env python
"""Benchmark: one motion-only pose optimisation, numpy reference vs the compiled kernel.

    python benchmarks/pose_only_timing.py [--sizes 200,400,800] [--cases 5] [--repeat 40]

Per size, ``--cases`` synthetic frames (TUM-like camera, bf = 40, 20 % of observations without
depth, 0.5 px noise at level 0 scaled by octave, 10 % gross outliers, a start ~1 deg / 3 cm
off: ``benchmarks/backend_timing.py``'s frames) are each solved ``--repeat`` times by
``optimize_pose_numpy`` and by ``optimize_pose`` (the numba kernel; warmed up first, so no
JIT time is counted).  Reports the median CPU time (this thread) of one call over all cases
and repeats, and checks that both return the same inliers and pose.  Prints one JSON object,
then a markdown table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from semslam.backend.pose_only import optimize_pose, optimize_pose_numpy
from semslam.backend.pose_only import warm_up

sys.path.insert(0, str(Path(__file__).parent))
from backend_timing import BF, CX, CY, FX, FY, pose_only_case  # noqa: E402  (the same synthetic frames)


def case(n: int, rng: np.random.Generator):
    """(T_init, pts_w, uv, ur, inv_sigma2) of one frame with ``n`` matched map points."""
    return pose_only_case(n, rng)[1:]


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
