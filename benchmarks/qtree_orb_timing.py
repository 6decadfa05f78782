#!/usr/bin/env python
"""Benchmark: STDC-SLAM's improved Qtree-ORB extractor (``semslam.features.qtree_orb``,
preset ``stdc``) compiled against its numpy reference and ORB-SLAM2's extractor, on
640x480 frames, A/B interleaved in one process.

    python benchmarks/qtree_orb_timing.py [--rounds 15] [--variants qtree_orb,qtree_orb_reference,orb_slam2]
                                          [--frames DIR] [--n-frames 10] [--json out.json]

Variants: ``qtree_orb`` = ``QtreeOrbExtractor()`` as installed (compiled Algorithm 2 and
Harris since issue 10; run this script with PYTHONPATH on an older checkout to time the
numpy one it replaced), ``qtree_orb_reference`` = ``QtreeOrbExtractor(reference=True)``
(the numpy Algorithm 2 and Harris kept as the test oracle), ``orb_slam2`` =
``OrbSlamExtractor()``. Each round extracts every frame once with every variant, the
variants one after the other, so a change of the machine's load hits them alike; the
numbers are the median (and quartiles) over rounds x frames of each frame's main-thread
CPU ms and wall ms, and the per-stage CPU medians. BLAS / OpenCV run single-threaded
(``semslam.runtime.limit_threads``), so CPU time is the whole cost. Also checks that the
compiled and reference variants give identical keypoints and descriptors.

Frames: ``--frames DIR`` (a TUM-layout folder's ``rgb/``, e.g. a ``semslam synth``
render), else the real 640x480 frames of ../shared/data and one ``walking_xyz`` render.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from semslam.runtime import limit_threads
from semslam.experiments.bench import emit_json

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
_FIELDS = ("xy", "octave", "response", "angle", "descriptors")


def load_frames(folder: Path | None, n: int) -> dict[str, np.ndarray]:
    if folder is not None:
        paths = sorted((folder / "rgb").glob("*.png"))[:n]
        return {p.stem: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths}
    frames = {f"images_people/{p.stem}": cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted((SHARED_DATA / "images_people").glob("*.png"))}
    from semslam.synth import SEQUENCES, Renderer

    rgb = Renderer(SEQUENCES["walking_xyz"].replace(frames=3)).render(1).rgb
    frames["synthetic/walking_xyz_1"] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return frames


def make_extractors(names: list[str]) -> dict[str, Any]:
    from semslam.features.orb_slam2 import OrbSlamExtractor
    from semslam.features.qtree_orb import QtreeOrbExtractor

    makers = {"qtree_orb": QtreeOrbExtractor, "qtree_orb_reference": lambda: QtreeOrbExtractor(reference=True),
              "orb_slam2": OrbSlamExtractor}
    return {name: makers[name]() for name in names}


def quartiles(values: list[float]) -> dict[str, float]:
    q1, q2, q3 = np.percentile(values, [25, 50, 75])
    return {"median": float(q2), "q1": float(q1), "q3": float(q3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--variants", default="qtree_orb,qtree_orb_reference,orb_slam2")
    ap.add_argument("--frames", type=Path, default=None, help="a TUM-layout folder (its rgb/*.png)")
    ap.add_argument("--n-frames", type=int, default=10, help="with --frames: how many")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    limit_threads()

    t0 = time.perf_counter()
    extractors = make_extractors(args.variants.split(","))
    warm_s = time.perf_counter() - t0  # numba kernels loaded (or compiled) by the constructors
    frames = load_frames(args.frames, args.n_frames)
    load_start = os.getloadavg()[0]
    for ex in extractors.values():  # warm-up: buffers, caches
        for gray in frames.values():
            ex.extract(gray)
    cpu: dict[str, list[float]] = {k: [] for k in extractors}
    wall: dict[str, list[float]] = {k: [] for k in extractors}
    stages: dict[str, dict[str, list[float]]] = {k: {} for k in extractors}
    for _ in range(args.rounds):
        for gray in frames.values():
            for name, ex in extractors.items():
                w0, c0 = time.perf_counter(), time.thread_time()
                ex.extract(gray)
                cpu[name].append(1e3 * (time.thread_time() - c0))
                wall[name].append(1e3 * (time.perf_counter() - w0))
                for stage, ms in ex.last_stage_cpu_ms.items():
                    stages[name].setdefault(stage, []).append(ms)
    identical = None
    if {"qtree_orb", "qtree_orb_reference"} <= set(extractors):
        a, b = extractors["qtree_orb"], extractors["qtree_orb_reference"]
        identical = all(np.array_equal(getattr(ka, f), getattr(kb, f))
                        for gray in frames.values() for ka, kb in [(a.extract(gray), b.extract(gray))]
                        for f in _FIELDS)
    doc = {
        "frames": list(frames), "rounds": args.rounds, "cpus": os.cpu_count(),
        "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]},
        "constructors_s": warm_s, "identical_compiled_and_reference": identical,
        "variants": {name: {"cpu_ms": quartiles(cpu[name]), "wall_ms": quartiles(wall[name]),
                            "stage_cpu_ms_median": {s: float(np.median(v)) for s, v in stages[name].items()}}
                     for name in extractors},
    }
    emit_json(doc, args.json)
    print()
    print(f"ms per frame over {args.rounds} rounds x {len(frames)} frames, variants interleaved; load average "
          f"{load_start:.1f} -> {doc['load_average_1min']['end']:.1f} on {os.cpu_count()} CPUs")
    print()
    print("| variant | CPU ms median (q1-q3) | wall ms median (q1-q3) | per-stage CPU ms (median) |")
    print("|---|---|---|---|")
    for name, v in doc["variants"].items():
        c, w = v["cpu_ms"], v["wall_ms"]
        st = ", ".join(f"{s} {ms:.2f}" for s, ms in v["stage_cpu_ms_median"].items())
        print(f"| {name} | {c['median']:.2f} ({c['q1']:.2f}-{c['q3']:.2f}) | {w['median']:.2f} "
              f"({w['q1']:.2f}-{w['q3']:.2f}) | {st} |")
    if identical is not None:
        print(f"\ncompiled and reference identical (keypoints, responses, angles, descriptors): {identical}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
