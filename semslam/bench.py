"""Benchmarks on the project's synthetic sequences (``semslam bench``, ``make bench``):
render them, run presets on each, print a JSON document and a markdown table of ATE RMSE
and ms/frame per (variant, sequence).

    semslam bench [--presets f2kf,orb] [--sequences static_xyz,room_loop]
                  [--variant "orb-noloop:orb:slam.loop_closing=false"] [--ablation]

``--ablation`` runs the structure of STDC-SLAM's Table 1 (base, +S, +S+SRM, +S+SRM+Q, +Q)
plus DDL-SLAM, on the walking and static sequences.

A variant is ``label:preset:key=value[,key=value...]`` (a preset with overrides).
Rendered sequences are cached under ``--data`` (re-rendered when their config changes).
Numbers come from this run on this machine; nothing is hard-coded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import semslam.runtime  # (thread limits, before numpy loads)
from semslam.cli.run_cmd import _needs_render
from semslam.config import load_config
from semslam.io.sequence import open_sequence
from semslam.pipeline import run_slam
from semslam.synth import SEQUENCES, render_sequence

#: STDC-SLAM Table 1 columns: OS3 (base), +S, +S+SRM, +S+SRM+Q (= stdc), +Q; and DDL-SLAM.
ABLATION_VARIANTS = [
    "base:orb:",
    "+S:orb:dynamics.semantic=true",
    "+S+SRM:orb:dynamics.semantic=true,semantics.srm=true",
    "+S+SRM+Q:stdc:",
    "+Q:orb:features.extractor=qtree_orb,features.n_levels=6",
    "ddl:ddl:",
]
ABLATION_SEQUENCES = ["walking_xyz", "walking_rpy", "walking_halfsphere", "walking_static", "static_xyz"]

DEFAULT_SEQUENCES = ["static_xyz", "loop", "room_loop", "walking_static", "walking_xyz", "walking_rpy", "walking_halfsphere"]


def _variants(args: argparse.Namespace) -> list[tuple[str, str, list[str]]]:
    out = [(p, p, []) for p in args.presets.split(",") if p]
    for v in args.variant + (ABLATION_VARIANTS if args.ablation else []):
        label, preset, *rest = v.split(":")
        out.append((label, preset, rest[0].split(",") if rest and rest[0] else []))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="semslam bench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", default=None, help="comma-separated preset names (default f2kf,orb; none with --ablation)")
    ap.add_argument("--ablation", action="store_true", help="STDC-SLAM Table 1 variants + ddl on walking/static sequences")
    ap.add_argument("--variant", action="append", default=[], help="label:preset:key=value,... (repeatable)")
    ap.add_argument("--sequences", default=None, help="comma-separated synthetic sequence names")
    ap.add_argument("--frames", type=int, default=None, help="frames per sequence (default: each sequence's own)")
    ap.add_argument("--data", type=Path, default=Path("out/bench/data"), help="where rendered sequences are cached")
    ap.add_argument("--out", type=Path, default=Path("out/bench/runs"), help="where run outputs go")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    semslam.runtime.limit_opencv_threads()
    if args.presets is None:
        args.presets = "" if args.ablation else "f2kf,orb"
    if args.sequences is None:
        args.sequences = ",".join(ABLATION_SEQUENCES if args.ablation else DEFAULT_SEQUENCES)

    names = [s.strip() for s in args.sequences.split(",") if s.strip()]
    unknown = [n for n in names if n not in SEQUENCES]
    if unknown:
        ap.error(f"unknown sequences {unknown} (known: {', '.join(SEQUENCES)})")
    rows = []
    for name in names:
        synth_cfg = SEQUENCES[name] if args.frames is None else replace(SEQUENCES[name], frames=args.frames)
        seq_dir = args.data / name
        if _needs_render(seq_dir, synth_cfg):
            t0 = time.perf_counter()
            render_sequence(synth_cfg, seq_dir, progress=False)
            print(f"rendered {name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        for label, preset, overrides in _variants(args):
            cfg = load_config(preset, overrides)
            summary = run_slam(open_sequence(seq_dir), cfg, args.out / label / name, progress=False, report=False)
            s = summary.stats
            rows.append({
                "variant": label, "preset": preset, "overrides": overrides, "sequence": name,
                "people": synth_cfg.people, "motion": synth_cfg.motion,
                "frames": s["frames"], "tracked_frames": s["tracked_frames"], "keyframes": s["keyframes"],
                "loops": s.get("loops"), "relocalisations": s.get("relocalisations"),
                "ate_rmse_m": s["ate"]["rmse"] if "ate" in s else None,
                "rpe_trans_rmse_m_1s": s["rpe_trans_1s"]["rmse"] if "rpe_trans_1s" in s else None,
                "ms_per_frame_median": s["ms_per_frame"]["median"],
                "ms_per_frame_p95": s["ms_per_frame"]["p95"],
                "stages_ms_median": s["stages_ms_median"],
                "dynamic_ratio_mean": s.get("dynamic_ratio_mean"),
            })
            r = rows[-1]
            print(f"{label} on {name}: ATE {r['ate_rmse_m']}, {r['ms_per_frame_median']:.1f} ms/frame, loops {r['loops']}",
                  file=sys.stderr)
    doc = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                       "cores": os.cpu_count()},
           "results": rows, "synth_configs": {n: asdict(SEQUENCES[n]) for n in names}}
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text)
    print()
    print("| sequence | people | variant | frames (tracked) | KFs | loops | ATE RMSE (cm) | RPE 1 s (cm) | ms/frame median | p95 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ate = "n/a" if r["ate_rmse_m"] is None else f"{r['ate_rmse_m'] * 100:.2f}"
        rpe = "n/a" if r["rpe_trans_rmse_m_1s"] is None else f"{r['rpe_trans_rmse_m_1s'] * 100:.2f}"
        loops = "-" if r["loops"] is None else str(r["loops"])
        print(f"| {r['sequence']} | {r['people']} | {r['variant']} | {r['frames']} ({r['tracked_frames']}) | {r['keyframes']} | "
              f"{loops} | {ate} | {rpe} | {r['ms_per_frame_median']:.1f} | {r['ms_per_frame_p95']:.1f} |")
    return 0


