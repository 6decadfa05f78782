#!/usr/bin/env python
"""Benchmark of the semantics layer: person segmenter ms/frame and SRM ms at 640x480.

    python benchmarks/semantics_timing.py [--repeats 20] [--json out.json] [--no-brute]

Segmenters (``mediapipe_person``, ``mediapipe_person_fast``, and the default at
``input_width=320``) on the real TUM photographs in ../shared/data/images_people and on
rendered walking_xyz frames: wall ms per frame (p50 / p95 / min over all frames x
repeats) and process CPU ms (all threads, including MediaPipe's). SRM
(``refine_segmentation``, 17x17, tau 0.1 m) on (a) the real Kinect depth of
../shared/data/kinect_rgbd_5frames with random elliptic masks covering 5 / 20 / 40 % of
the image - blobs laid over clutter, a hard case with many pixels between depth layers -
and (b) rendered frames with their true person masks, as is, shrunk (eroded 11x11: an
under-segmenting net, the case SRM is for) and grown (dilated 11x11: a mask bleeding onto
the background). Each SRM result is checked against the brute-force Algorithm 1 once
(unless --no-brute). Prints a JSON document, then markdown tables; numbers come from this
run on this machine (the load average is reported).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from semslam.config import SemanticsConfig
from semslam.dynamics.srm import refine_brute_force, refine_segmentation
from semslam.semantics import create_segmenter
from semslam.experiments.bench import emit_json, time_calls, timing_summary

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def rendered_frames(n: int) -> list[Any]:
    from semslam.synth import SEQUENCES, Renderer

    renderer = Renderer(SEQUENCES["walking_xyz"].replace(frames=200))
    return [renderer.render(i) for i in np.linspace(0, 190, n).astype(int)]


def blob_mask(shape: tuple[int, int], fraction: float, seed: int) -> np.ndarray:
    """Random filled ellipses (up to person-sized) until ``fraction`` of the image is covered."""
    rng = np.random.default_rng(seed)
    h, w = shape
    mask = np.zeros(shape, np.uint8)
    while mask.mean() < fraction:
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        axes = (int(rng.integers(15, 60)), int(rng.integers(30, 120)))
        cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return mask.astype(bool)


def bench_segmenters(repeats: int, synth: list[Any]) -> list[dict[str, Any]]:
    images: list[tuple[str, np.ndarray]] = []
    for p in sorted((SHARED_DATA / "images_people").glob("*.png")):
        images.append((f"real/{p.stem}", cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)))
    images += [(f"synthetic/walking_xyz_{i}", f.rgb) for i, f in enumerate(synth)]
    rows = []
    for backend, width in (("mediapipe_person", 0), ("mediapipe_person_fast", 0), ("mediapipe_person", 320)):
        try:
            seg = create_segmenter(SemanticsConfig(backend=backend, input_width=width))
        except Exception as exc:  # noqa: BLE001 - report and go on (e.g. mediapipe missing)
            rows.append({"backend": backend, "input_width": width, "error": str(exc)})
            continue
        wall: list[float] = []
        cpu: list[float] = []
        for _, rgb in images:
            w, c = time_calls(lambda seg=seg, rgb=rgb: seg.segment(rgb), repeats, cpu_clock=time.process_time)
            wall += w
            cpu += c
        rows.append({"backend": backend, "input_width": width, "frames": len(images), **timing_summary(wall, cpu)})
    return rows


def bench_srm(repeats: int, synth: list[Any], brute: bool) -> list[dict[str, Any]]:
    cases: list[tuple[str, float | None, np.ndarray, np.ndarray]] = []
    depth_dir = SHARED_DATA / "kinect_rgbd_5frames" / "depth"
    kinect = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0 for p in sorted(depth_dir.glob("*.pgm"))]
    for frac in (0.05, 0.2, 0.4):
        for k, depth in enumerate(kinect):
            cases.append(("kinect depth, random blobs", frac, blob_mask(depth.shape, frac, k), depth))
    k11 = np.ones((11, 11), np.uint8)
    for f in synth:
        person = (f.semantic == 15).astype(np.uint8)
        if person.sum() < 2000:
            continue
        depth = f.depth.astype(np.float32) / 5000.0
        cases.append(("rendered, true person mask", None, person.astype(bool), depth))
        cases.append(("rendered, person mask eroded 11x11", None, cv2.erode(person, k11).astype(bool), depth))
        cases.append(("rendered, person mask dilated 11x11", None, cv2.dilate(person, k11).astype(bool), depth))
    groups: dict[tuple[str, float | None], dict[str, Any]] = {}
    for name, frac, mask, depth in cases:
        g = groups.setdefault((name, frac), {"wall": [], "cpu": [], "coverage": [], "grown": [], "brute_ms": [], "equal": True})
        w, c = time_calls(lambda mask=mask, depth=depth: refine_segmentation(mask, depth), repeats,
                          cpu_clock=time.process_time)
        g["wall"] += w
        g["cpu"] += c
        out = refine_segmentation(mask, depth)
        g["coverage"].append(float(mask.mean()))
        g["grown"].append(float(out.mean() - mask.mean()))
        if brute:
            t0 = time.perf_counter()
            ref = refine_brute_force(mask, depth)
            g["brute_ms"].append(1e3 * (time.perf_counter() - t0))
            g["equal"] &= bool(np.array_equal(out, ref))
    rows = []
    for (name, frac), g in groups.items():
        rows.append({"case": name, "target_coverage": frac, "coverage_mean": float(np.mean(g["coverage"])),
                     "added_fraction_mean": float(np.mean(g["grown"])), "masks": len(g["coverage"]),
                     **timing_summary(g["wall"], g["cpu"]),
                     "brute_force_ms_mean": float(np.mean(g["brute_ms"])) if g["brute_ms"] else None,
                     "equal_to_brute_force": g["equal"] if brute else None})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--synthetic-frames", type=int, default=6)
    ap.add_argument("--no-brute", action="store_true", help="skip the brute-force equality check (slow)")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)

    synth = rendered_frames(args.synthetic_frames)
    seg_rows = bench_segmenters(args.repeats, synth)
    srm_rows = bench_srm(args.repeats, synth, not args.no_brute)
    doc = {
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                    "opencv": cv2.__version__, "opencv_threads": cv2.getNumThreads(),
                    "load_average_1min_at_end": os.getloadavg()[0]},
        "repeats": args.repeats,
        "segmenters": seg_rows,
        "srm": srm_rows,
    }
    emit_json(doc, args.json)

    print()
    print(f"load average {doc['machine']['load_average_1min_at_end']:.2f} on {os.cpu_count()} CPUs; 640x480 frames")
    print()
    print("| segmenter | input width | frames x repeats | wall ms p50 | p95 | min | CPU ms p50 (all threads) |")
    print("|---|---|---|---|---|---|---|")
    for r in seg_rows:
        if "error" in r:
            print(f"| {r['backend']} | {r['input_width'] or 'native'} | - | {r['error']} | | | |")
            continue
        print(f"| {r['backend']} | {r['input_width'] or 'native'} | {r['n']} | {r['wall_ms_p50']:.1f} | {r['wall_ms_p95']:.1f} "
              f"| {r['wall_ms_min']:.1f} | {r['cpu_ms_p50']:.1f} |")
    print()
    print("| SRM case | dynamic % (target) | masks | added % | wall ms p50 | p95 | CPU ms p50 | brute force ms | equal |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in srm_rows:
        target = f" ({100 * r['target_coverage']:.0f})" if r["target_coverage"] is not None else ""
        brute = f"{r['brute_force_ms_mean']:.0f}" if r["brute_force_ms_mean"] is not None else "-"
        print(f"| {r['case']} | {100 * r['coverage_mean']:.1f}{target} | {r['masks']} | {100 * r['added_fraction_mean']:.1f} "
              f"| {r['wall_ms_p50']:.2f} | {r['wall_ms_p95']:.2f} | {r['cpu_ms_p50']:.2f} | {brute} "
              f"| {r['equal_to_brute_force'] if r['equal_to_brute_force'] is not None else '-'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
