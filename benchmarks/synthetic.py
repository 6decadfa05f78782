#!/usr/bin/env python
"""Benchmark: render the project's synthetic sequences, run a preset on each, and print a
JSON document and a markdown table of ATE RMSE and ms/frame per sequence.

    python benchmarks/synthetic.py [--preset default] [--frames 300] [--sequences walking_xyz,static_xyz]

Rendered sequences are cached under ``--data`` (re-rendered when their config changes).
Numbers come from this run on this machine; nothing is hard-coded.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

from semslam.cli.run_cmd import _needs_render
from semslam.config import load_config
from semslam.io.sequence import open_sequence
from semslam.pipeline import run_slam
from semslam.synth import SEQUENCES, render_sequence

DEFAULT_SEQUENCES = ["static_xyz", "walking_static", "walking_xyz", "walking_rpy", "walking_halfsphere", "loop"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="default", help="preset name or YAML file")
    ap.add_argument("--sequences", default=",".join(DEFAULT_SEQUENCES), help="comma-separated synthetic sequence names")
    ap.add_argument("--frames", type=int, default=None, help="frames per sequence (default: each sequence's own)")
    ap.add_argument("--data", type=Path, default=Path("out/bench/data"), help="where rendered sequences are cached")
    ap.add_argument("--out", type=Path, default=Path("out/bench/runs"), help="where run outputs go")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)

    names = [s.strip() for s in args.sequences.split(",") if s.strip()]
    unknown = [n for n in names if n not in SEQUENCES]
    if unknown:
        ap.error(f"unknown sequences {unknown} (known: {', '.join(SEQUENCES)})")
    rows = []
    for name in names:
        synth_cfg = SEQUENCES[name] if args.frames is None else replace(SEQUENCES[name], frames=args.frames)
        seq_dir = args.data / name
        t0 = time.perf_counter()
        if _needs_render(seq_dir, synth_cfg):
            render_sequence(synth_cfg, seq_dir, progress=False)
        render_s = time.perf_counter() - t0
        cfg = load_config(args.preset)
        summary = run_slam(open_sequence(seq_dir), cfg, args.out / args.preset / name, progress=False, report=False)
        s = summary.stats
        rows.append({
            "sequence": name,
            "frames": s["frames"],
            "tracked_frames": s["tracked_frames"],
            "keyframes": s["keyframes"],
            "ate_rmse_m": s["ate"]["rmse"] if "ate" in s else None,
            "rpe_trans_rmse_m_1s": s["rpe_trans_1s"]["rmse"] if "rpe_trans_1s" in s else None,
            "ms_per_frame_median": s["ms_per_frame"]["median"],
            "ms_per_frame_p95": s["ms_per_frame"]["p95"],
            "render_s": render_s,
            "people": synth_cfg.people,
            "motion": synth_cfg.motion,
        })
        print(f"{name}: ATE {rows[-1]['ate_rmse_m']}, {rows[-1]['ms_per_frame_median']:.1f} ms/frame", file=sys.stderr)
    doc = {"preset": args.preset, "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
           "results": rows, "synth_configs": {n: asdict(SEQUENCES[n]) for n in names}}
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text)
    print()
    print(f"| sequence | people | frames (tracked) | ATE RMSE (cm) | RPE 1 s (cm) | ms/frame median | p95 |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ate = "n/a" if r["ate_rmse_m"] is None else f"{r['ate_rmse_m'] * 100:.2f}"
        rpe = "n/a" if r["rpe_trans_rmse_m_1s"] is None else f"{r['rpe_trans_rmse_m_1s'] * 100:.2f}"
        print(f"| {r['sequence']} | {r['people']} | {r['frames']} ({r['tracked_frames']}) | {ate} | {rpe} | "
              f"{r['ms_per_frame_median']:.1f} | {r['ms_per_frame_p95']:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
