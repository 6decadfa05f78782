#!/usr/bin/env python
"""Benchmark: ORB-SLAM's extractor (``semslam.features.orb_slam2``) against
``cv2.ORB_create(n)`` on 640x480 frames: ms per frame (wall and CPU), per-stage
breakdown (wall and CPU), keypoints per level against ORB-SLAM's formula, spatial
uniformity (fraction of occupied cells of an 8x6 grid, coefficient of variation of the
counts per cell), agreement with the literal per-cell FAST of ORB-SLAM
(``reference_detection=True``) and the numba JIT cost.

    python benchmarks/extractor_timing.py [--repeats 30] [--features 1000] [--cv-threads N]
                                          [--cold-jit] [--json out.json]

Frames: the real ones in ../shared/data (if present) and one rendered synthetic frame.
Prints a JSON document, then markdown tables. Timings are the median and the minimum
over ``--repeats`` runs after a warm-up. "CPU" is the main thread's CPU time, which other
processes on the machine barely affect (unlike wall time; the load average is reported);
with ``--cv-threads 1`` and ``OPENBLAS_NUM_THREADS=1`` all the work is on the main thread,
so that CPU time is the whole cost. Numbers come from this run on this machine.

JIT: ``jit.warm_up_s`` is what ``semslam.features.orb.warm_up()`` took in this process
(loading the kernels from numba's disk cache, or compiling them if the cache is cold);
it is paid once, before the first frame, and is not in any per-frame time. With
``--cold-jit``, ``jit.cold_compile_s`` is the same in a fresh process with an empty cache
(``NUMBA_CACHE_DIR`` set to a temporary directory): the one-time compile cost.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from semslam.features.orb import features_per_level, warm_up
from semslam.features.orb_slam2 import OrbSlamExtractor
from semslam.experiments.bench import emit_json, time_calls, timing_summary

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
GRID = (8, 6)


def load_frames() -> dict[str, np.ndarray]:
    frames: dict[str, np.ndarray] = {}
    for sub in ("kinect_rgbd_5frames/color", "images_people"):
        for p in sorted((SHARED_DATA / sub).glob("*.png")):
            frames[f"{sub.split('/')[0]}/{p.stem}"] = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    from semslam.synth import SEQUENCES, Renderer

    rgb = Renderer(SEQUENCES["static_xyz"].replace(frames=5)).render(0).rgb
    frames["synthetic/static_xyz_0"] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return frames


def cold_compile_seconds() -> float:
    """``warm_up()`` in a fresh process whose numba cache directory is empty."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache,
               "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])}
        out = subprocess.run([sys.executable, "-c", "from semslam.features.orb import warm_up; print(warm_up())"],
                             env=env, check=True, capture_output=True, text=True)
        return float(out.stdout.strip().splitlines()[-1])


def uniformity(xy: np.ndarray, shape: tuple[int, int]) -> dict[str, float]:
    """Fraction of occupied cells of an 8x6 grid and the coefficient of variation of the
    counts per cell (0 = perfectly even)."""
    nx, ny = GRID
    h, w = shape
    cx = np.clip((xy[:, 0] / w * nx).astype(int), 0, nx - 1)
    cy = np.clip((xy[:, 1] / h * ny).astype(int), 0, ny - 1)
    counts = np.bincount(cy * nx + cx, minlength=nx * ny)
    return {"occupied": float(np.mean(counts > 0)), "cv": float(counts.std() / max(counts.mean(), 1e-9))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--features", type=int, default=1000)
    ap.add_argument("--cv-threads", type=int, default=None, help="cv2.setNumThreads (default: OpenCV's)")
    ap.add_argument("--cold-jit", action="store_true", help="also time a compile with an empty numba cache")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    if args.cv_threads is not None:
        cv2.setNumThreads(args.cv_threads)

    jit = {"warm_up_s": warm_up()}  # before any extractor: its constructor would do it
    if args.cold_jit:
        jit["cold_compile_s"] = cold_compile_seconds()
    frames = load_frames()
    ours = OrbSlamExtractor(n_features=args.features)
    reference = OrbSlamExtractor(n_features=args.features, reference_detection=True)
    orb = cv2.ORB_create(args.features)  # OpenCV's own defaults otherwise (8 levels, 1.2)
    wanted = features_per_level(args.features, ours.n_levels, ours.scale_factor)
    rows = []
    for name, gray in frames.items():
        kp = ours.extract(gray)
        stages: list[dict[str, float]] = []
        stages_cpu: list[dict[str, float]] = []

        def run_ours(gray: np.ndarray = gray, stages: list[dict[str, float]] = stages,
                     stages_cpu: list[dict[str, float]] = stages_cpu) -> None:
            ours.extract(gray)
            stages.append(dict(ours.last_stage_ms))
            stages_cpu.append(dict(ours.last_stage_cpu_ms))

        t_ours = timing_summary(*time_calls(run_ours, args.repeats))
        t_cv = timing_summary(*time_calls(lambda gray=gray: orb.detectAndCompute(gray, None), args.repeats))
        cv_kps, _ = orb.detectAndCompute(gray, None)
        cv_xy = np.array([k.pt for k in cv_kps], np.float32).reshape(-1, 2)
        ref = reference.extract(gray)
        a = set(map(tuple, np.c_[kp.xy, kp.octave].tolist()))
        b = set(map(tuple, np.c_[ref.xy, ref.octave].tolist()))
        identical = all(np.array_equal(getattr(kp, f), getattr(ref, f))
                        for f in ("xy", "octave", "response", "angle", "descriptors"))
        rows.append({
            "frame": name,
            "ours": {**t_ours, "n": len(kp), "per_level": np.bincount(kp.octave, minlength=len(wanted)).tolist(),
                     "stage_ms_median": {k: float(np.median([s[k] for s in stages])) for k in stages[0]},
                     "stage_cpu_ms_median": {k: float(np.median([s[k] for s in stages_cpu])) for k in stages_cpu[0]},
                     **uniformity(kp.xy, gray.shape)},
            "cv2_orb": {**t_cv, "n": len(cv_kps),
                        "per_level": np.bincount([k.octave for k in cv_kps], minlength=8).tolist(),
                        **uniformity(cv_xy, gray.shape)},
            "same_as_per_cell_reference": len(a & b) / max(len(b), 1),
            "identical_to_per_cell_reference": identical,
        })

    doc = {
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                    "opencv": cv2.__version__, "opencv_threads": cv2.getNumThreads(),
                    "openblas_num_threads_env": os.environ.get("OPENBLAS_NUM_THREADS"),
                    "load_average_1min_at_end": os.getloadavg()[0]},
        "jit": jit,
        "features": args.features, "repeats": args.repeats,
        "formula_per_level": wanted.tolist(),
        "frames": rows,
    }
    emit_json(doc, args.json)

    print()
    print(f"ms per frame, median of {args.repeats} (min); load average {doc['machine']['load_average_1min_at_end']:.2f}"
          f" on {os.cpu_count()} CPUs")
    print()
    print("| frame | ours wall ms | ours main-thread CPU ms | cv2.ORB wall ms | cv2.ORB main-thread CPU ms | ours n | cv2 n "
          "| occupied 8x6 ours / cv2 | CV per cell ours / cv2 | same as per-cell FAST | identical |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        o, c = r["ours"], r["cv2_orb"]
        print(f"| {r['frame']} | {o['wall_ms_p50']:.1f} ({o['wall_ms_min']:.1f}) | {o['cpu_ms_p50']:.1f} "
              f"| {c['wall_ms_p50']:.1f} ({c['wall_ms_min']:.1f}) | {c['cpu_ms_p50']:.1f} | {o['n']} | {c['n']} "
              f"| {o['occupied']:.2f} / {c['occupied']:.2f} | {o['cv']:.2f} / {c['cv']:.2f} "
              f"| {100 * r['same_as_per_cell_reference']:.1f} % | {'yes' if r['identical_to_per_cell_reference'] else 'NO'} |")
    print()
    print("| frame | " + " | ".join(f"L{i}" for i in range(len(wanted))) + " | total |")
    print("|---|" + "---|" * (len(wanted) + 1))
    print("| formula | " + " | ".join(map(str, wanted.tolist())) + f" | {int(wanted.sum())} |")
    for r in rows:
        per = r["ours"]["per_level"]
        print(f"| {r['frame']} | " + " | ".join(map(str, per)) + f" | {sum(per)} |")
    print()
    for key, title in (("stage_cpu_ms_median", "main-thread CPU"), ("stage_ms_median", "wall")):
        names = list(rows[0]["ours"][key])
        print(f"per-stage {title} ms, median of {args.repeats}")
        print()
        print("| frame | " + " | ".join(names) + " | sum |")
        print("|---|" + "---|" * (len(names) + 1))
        for r in rows:
            st = r["ours"][key]
            print(f"| {r['frame']} | " + " | ".join(f"{st[k]:.2f}" for k in names) + f" | {sum(st.values()):.2f} |")
        print()
    print("JIT (once per process, before the first frame): "
          + ", ".join(f"{k} = {v:.2f}" for k, v in jit.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
