#!/usr/bin/env python
"""Benchmark: issue 10's real-time targets, measured as ``semslam run`` is used (threaded).

    python benchmarks/realtime_targets.py [--frames 300] [--long-frames 900] [--repeats 3] [--json out.json]
                                          [--modes fast,camera] [--skip-long] [--skip-one-core]

1. ``orb``, ``default``, ``stdc``, ``ddl`` on the static and walking renders, each run a
   ``semslam run`` process of its own: per-frame
   median / p95, the per-stage medians, the tracking thread's wait for the map lock
   (median / p95 / max), local BA median, ATE. Targets: ``orb`` <= 15 ms median and <= 30
   ms p95, ``default`` <= 17 / <= 35 (the median over the two renders is the mean of the
   two runs' medians; the p95 likewise). Two modes:
   - ``fast``: frames as fast as they decode (``semslam run``'s default), so the reader,
     the semantic thread and local mapping always have work beside tracking;
   - ``camera``: frames at their timestamps' rate (``semslam run --realtime``), as a live
     camera delivers them and as ORB-SLAM3's TUM examples feed them (they sleep until the
     next frame is due), which is how its per-frame times are measured. Latency (arrival
     to pose) and frames that arrived while the previous one was still tracked are reported.
2. ``default`` on a ``--long-frames`` render of walking_xyz: wall-clock fps including PNG
   decoding (target >= 30).
3. ``default`` pinned to one core (``taskset -c 0``, a 2x slower machine), at camera rate:
   every frame processed and none lost.

Prints a JSON document, then markdown tables with each target and whether it is met.
Numbers come from this run on this machine; the load average is reported with them, and the
machine's speed before and after the runs (``experiments/speed_probe.py``: a Python loop and
ORB extraction on a fixed image), since these machines' speed changes from day to day.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from semslam.core.types import RunResult
from semslam.experiments.bench import emit_json, machine, targets_table
from semslam.experiments.speed_probe import speed_probe
from semslam.synth import SEQUENCES, ensure_rendered

sys.path.insert(0, str(Path(__file__).parent))
from results_page import write_results_page  # noqa: E402  (benchmarks/, run as a script)

PRESETS = ["orb", "default", "stdc", "ddl"]
RENDERS = ["static_xyz", "walking_xyz"]
TARGETS = {"orb": (15.0, 30.0), "default": (17.0, 35.0)}
#: mode -> (variant label suffix, config overrides)
MODES: dict[str, tuple[str, tuple[str, ...]]] = {"fast": ("", ()), "camera": ("@camera", ("slam.realtime=true",))}


def _row(r: Any) -> dict[str, Any]:
    return {
        "frames": r.frames, "tracked": r.tracked_frames, "lost": r.lost_frames, "keyframes": r.keyframes,
        "ate_cm": None if r.ate_rmse is None else 100 * r.ate_rmse,
        "ms_median": r.ms_per_frame["median"], "ms_p95": r.ms_per_frame["p95"], "ms_max": r.ms_per_frame["max"],
        "fps_wall": r.fps, "stages_ms_median": r.stages_ms_median,
        # The tracking thread's per-frame CPU, run-queue wait and sleep (GIL, locks, a mask).
        "tracking_thread_ms": r.tracking_thread_ms or None,
        "lock_wait_ms": {"median": r.stages_ms_median.get("lock_wait"), "p95": r.stages_ms_p95.get("lock_wait"),
                         "max": r.stages_ms_max.get("lock_wait")},
        "local_ba_ms_median": r.mapping.local_ba_ms_median, "jit_warmup_s": r.tracking.jit_warmup_s,
        # Local mapping's CPU (its Python holds the GIL tracking needs): total and per keyframe.
        "local_mapping_cpu_ms": r.mapping.local_mapping_cpu_ms,
        "latency_ms": r.latency_ms or None, "late_frames": r.late_frames if r.realtime else None,
    }


def _split(split: dict[str, float] | None) -> str:
    """"CPU / run queue / asleep" ms of the tracking thread ("-" where not measured)."""
    if not split:
        return "-"
    return " / ".join("-" if split.get(k) is None else f"{split[k]:.1f}" for k in ("cpu", "runqueue", "asleep"))


def _median_run(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The run whose per-frame median is the median of the repeats, with every repeat's median and p95 beside it.

    One run of a threaded SLAM system on a 2-core machine varies by 1-3 ms in its median (scheduling,
    which frames become keyframes while the semantic thread holds the other core); the median run
    of several is a stable figure, and the spread is shown rather than hidden.
    """
    order = sorted(range(len(rows)), key=lambda i: rows[i]["ms_median"])
    mid = dict(rows[order[(len(rows) - 1) // 2]])
    mid["repeats"] = [{"ms_median": r["ms_median"], "ms_p95": r["ms_p95"]} for r in rows]
    return mid


def _runs_table(doc: dict[str, Any]) -> str:
    """Every run's row (the median run of each cell) as a markdown table."""
    lines = ["| preset | sequence | ms/frame median / p95 | tracking thread: CPU / run queue / asleep | extract | track "
             "| local map | lock wait median / p95 / max | local BA ms | local mapping CPU ms / keyframe | ATE cm | latency median / p95 | late frames "
             "| every repeat's median |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for preset, runs in doc["runs"].items():
        for name, r in runs.items():
            s, w = r["stages_ms_median"], r["lock_wait_ms"]
            lines.append(f"| {preset} | {name} | {r['ms_median']:.1f} / {r['ms_p95']:.1f} | {_split(r['tracking_thread_ms'])} | "
                         f"{s.get('extract', 0):.1f} | "
                         f"{s.get('track', 0):.1f} | {s.get('local_map', 0):.1f} | {w['median'] or 0:.2f} / {w['p95'] or 0:.1f}"
                         f" / {w['max'] or 0:.1f} | {r['local_ba_ms_median'] or 0:.0f} | "
                         f"{(r['local_mapping_cpu_ms'] or {}).get('per_keyframe', 0):.0f} | "
                         f"{'n/a' if r['ate_cm'] is None else format(r['ate_cm'], '.2f')} | "
                         + (f"{r['latency_ms']['median']:.1f} / {r['latency_ms']['p95']:.1f} | {r['late_frames']} |"
                            if r["latency_ms"] else "- | - |")
                         + " " + ", ".join(f"{x['ms_median']:.1f}" for x in r["repeats"]) + " |")
    return "\n".join(lines)


def _cli_run(seq: Path, out: Path, preset: str, prefix: list[str], flags: tuple[str, ...] = ()) -> dict[str, Any]:
    semslam = shutil.which("semslam") or str(Path(sys.executable).with_name("semslam"))
    cmd = [*prefix, semslam, "run", str(seq), "--out", str(out), "--preset", preset, "--quiet", "--no-report", *flags]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "stats.json").read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--long-frames", type=int, default=900)
    ap.add_argument("--data", type=Path, default=Path("out/bench/data"))
    ap.add_argument("--out", type=Path, default=Path("out/bench/realtime"))
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--modes", default="fast,camera", help="fast (as frames decode), camera (--realtime)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="runs per (preset, render, mode); the cell reports the median run (by median ms)")
    ap.add_argument("--skip-long", action="store_true")
    ap.add_argument("--skip-one-core", action="store_true")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--write-docs", type=Path, metavar="PATH",
                    help="also write the tables as a dated results page (e.g. docs/results/speed.md)")
    args = ap.parse_args(argv)

    doc: dict[str, Any] = {"machine": {**machine(), "loadavg_before": os.getloadavg(), "speed_before": speed_probe()},
                           "runs": {}, "targets": []}
    modes = [m for m in args.modes.split(",") if m]
    for mode in modes:
        if mode not in MODES:
            raise SystemExit(f"--modes: unknown {mode!r} (known: {', '.join(MODES)})")
        for name in RENDERS:  # each run in a process of its own, as `semslam run` runs
            seq = args.data / name
            ensure_rendered(replace(SEQUENCES[name], frames=args.frames), seq)
            for p in args.presets.split(","):
                label = f"{p}{MODES[mode][0]}"
                flags = [f for o in MODES[mode][1] for f in ("--set", o)]
                rows = [_row(RunResult.from_dict(_cli_run(seq, args.out / "runs" / label / name / f"run{i}", p, [],
                                                          tuple(flags)))) for i in range(args.repeats)]
                doc["runs"].setdefault(label, {})[name] = _median_run(rows)
        for preset, (t_med, t_p95) in TARGETS.items():
            runs = doc["runs"].get(f"{preset}{MODES[mode][0]}")
            if not runs:
                continue
            med = float(np.mean([r["ms_median"] for r in runs.values()]))
            p95 = float(np.mean([r["ms_p95"] for r in runs.values()]))
            doc["targets"].append({"target": f"{preset} median <= {t_med} ms ({mode})", "value": med,
                                   "met": med <= t_med})
            doc["targets"].append({"target": f"{preset} p95 <= {t_p95} ms ({mode})", "value": p95,
                                   "met": p95 <= t_p95})
    waits = [r["lock_wait_ms"]["p95"] for runs in doc["runs"].values() for r in runs.values()
             if r["lock_wait_ms"]["p95"] is not None]
    if waits:
        doc["targets"].append({"target": "tracking's lock wait p95 <= 2 ms (worst run)", "value": max(waits),
                               "met": max(waits) <= 2.0})
    ba = [r["local_ba_ms_median"] for runs in doc["runs"].values() for r in runs.values() if r["local_ba_ms_median"]]
    if ba:
        doc["targets"].append({"target": "local BA median <= 150 ms (worst run)", "value": max(ba),
                               "met": max(ba) <= 150.0})

    if not args.skip_long:
        cfg = replace(SEQUENCES["walking_xyz"], frames=args.long_frames)
        seq = args.data / f"walking_xyz_{args.long_frames}"
        ensure_rendered(cfg, seq)
        stats = _cli_run(seq, args.out / "long", "default", [])
        doc["long"] = {"sequence": seq.name, **{k: stats.get(k) for k in ("frames", "tracked_frames", "fps", "wall_s")},
                       "ms_per_frame": stats["ms_per_frame"]}
        doc["targets"].append({"target": f"default >= 30 fps wall on {args.long_frames} frames",
                               "value": stats["fps"], "met": stats["fps"] >= 30.0})
    if not args.skip_one_core and shutil.which("taskset"):
        seq = args.data / "walking_xyz"
        stats = _cli_run(seq, args.out / "one_core", "default", ["taskset", "-c", "0"], ["--realtime"])
        doc["one_core"] = {k: stats.get(k) for k in ("frames", "tracked_frames", "lost_frames", "fps", "late_frames",
                                                     "latency_ms")}
        doc["one_core"]["ate_cm"] = 100 * stats["ate"]["rmse"] if stats.get("ate") else None
        doc["one_core"]["ms_per_frame"] = stats["ms_per_frame"]
        ok = stats["frames"] == stats["tracked_frames"] and stats["lost_frames"] == 0
        doc["targets"].append({"target": "default on one core: every frame tracked", "value":
                               f"{stats['tracked_frames']}/{stats['frames']}", "met": ok})
    doc["machine"]["loadavg_after"] = os.getloadavg()
    doc["machine"]["speed_after"] = speed_probe()

    emit_json(doc, args.json)
    tables = _runs_table(doc) + "\n\n" + targets_table(doc["targets"], digits=1)
    print("\n" + tables)
    print(f"\nload average before / after: {doc['machine']['loadavg_before']} / {doc['machine']['loadavg_after']}")
    sb, sa = doc["machine"]["speed_before"], doc["machine"]["speed_after"]
    print(f"machine speed before / after (experiments/speed_probe.py): Python loop of 10^7 additions "
          f"{sb['python_loop_1e7_s']:.2f} / {sa['python_loop_1e7_s']:.2f} s, ORB-SLAM2 extraction on the probe "
          f"image {sb['orb_extract_ms']:.1f} / {sa['orb_extract_ms']:.1f} ms")
    if args.write_docs:
        write_results_page(args.write_docs, "Real time on two cores", tables, speed=sb,
                           notes="ms/frame: the time `track()` takes; camera mode feeds frames at their "
                                 "timestamps' rate (`--realtime`). The speed probe was taken before the runs.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
