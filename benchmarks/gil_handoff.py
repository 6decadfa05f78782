#!/usr/bin/env python
"""Benchmark: what a busy Python thread beside tracking costs ORB extraction, by switch interval.

    python benchmarks/gil_handoff.py [--frames 60] [--intervals 0.005,0.001,0.0002]

Tracking's compiled kernels and OpenCV calls release the GIL; when one returns, tracking
must get the GIL back from whichever thread took it, which CPython hands over only every
switch interval. Local mapping is such a thread (mostly Python). This measures one
extraction per frame of the static render alone, then with a pure-Python thread spinning
beside it, at each interval (each in a fresh process: the interval is process-wide).
Prints JSON, then a table. ``semslam.runtime.SWITCH_INTERVAL_S`` is chosen from it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import glob, json, sys, threading, time
import cv2, numpy as np
interval, frames, hog, data = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4]
sys.setswitchinterval(interval)
cv2.setNumThreads(1)
from semslam.config import load_config
from semslam.features import create_extractor
ext = create_extractor(load_config("orb").features)
imgs = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in sorted(glob.glob(data + "/rgb/*.png"))[:frames]]
for im in imgs[:5]:
    ext.extract(im)
stop = False
def spin():
    x = 0
    while not stop:
        x += 1
th = threading.Thread(target=spin)
if hog:
    th.start()
ts = []
for _ in range(2):
    for im in imgs:
        t = time.perf_counter(); ext.extract(im); ts.append((time.perf_counter() - t) * 1e3)
stop = True
if hog:
    th.join()
print(json.dumps({"median_ms": float(np.median(ts)), "p95_ms": float(np.percentile(ts, 95))}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--intervals", default="0.005,0.001,0.0002")
    ap.add_argument("--data", type=Path, default=Path("out/bench/data/static_xyz"))
    args = ap.parse_args()
    from semslam.synth import SEQUENCES, ensure_rendered

    ensure_rendered(SEQUENCES["static_xyz"], args.data)
    rows = []
    for interval in [float(x) for x in args.intervals.split(",")]:
        for hog in (False, True):
            out = subprocess.run([sys.executable, "-c", CHILD, str(interval), str(args.frames), str(int(hog)),
                                  str(args.data)], check=True, capture_output=True, text=True).stdout
            rows.append({"switch_interval_s": interval, "python_thread_beside": hog,
                         **json.loads(out.strip().splitlines()[-1])})
    print(json.dumps(rows, indent=2))
    print("\n| switch interval | Python thread beside | extract median ms | p95 |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['switch_interval_s'] * 1e3:g} ms | {'yes' if r['python_thread_beside'] else 'no'} "
              f"| {r['median_ms']:.1f} | {r['p95_ms']:.1f} |")


if __name__ == "__main__":
    main()
