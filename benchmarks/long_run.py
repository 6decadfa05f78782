#!/usr/bin/env python
"""Benchmark: issue 13's long runs. Does a run that keeps revisiting one room stay flat?

    python benchmarks/long_run.py [--frames 36000] [--preset orb] [--set KEY=VALUE ...]
                                  [--cache ~/.cache/semslam/bench] [--json out.json] [--render-only]

The sequence is ``long_revisit`` (``semslam synth``'s name): the camera turns round the
middle of the room once every 30 s, so after the first turn every view is one seen before.
It is rendered once into ``--cache`` (outside the repository; ~0.06 s and ~0.7 MB a frame
at 640x480); a render at least ``--frames`` long is reused, its first frames only, and an
interrupted or shorter one is resumed from its first missing frame.

The run is threaded, as ``semslam run`` runs it (reader thread, local mapping, loop closing,
the BA worker process). Every 100 frames the resident memory (RSS) of this process and,
separately, of its worker processes is sampled; per 1000 frames the script reports the
median ms per frame (``track`` call, as ``stats.json``'s per-frame time), the tracking
thread's CPU ms in it (less disturbed by other processes on a shared machine; reported, not
checked), the largest RSS seen, and the keyframes and map points at the end of the window.
Once the room is mapped, tracking finds enough of the map to insert (almost) no keyframes;
ORB-SLAM's culling removes those that are redundant.

Prints a JSON document and a markdown table, then checks that RSS (process and workers) and
the median ms/frame grew by at most 10 % from the second thousand frames to the last; if
not, it names what grew and exits 1. Timings depend on the machine's load: the load
average is printed with them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from semslam.api import System
from semslam.config import load_config
from semslam.experiments.bench import emit_json
from semslam.io.sequence import open_sequence
from semslam.pipeline import prefetch
from semslam.runtime import limit_threads
from semslam.synth import SEQUENCES, render_sequence

SEQUENCE = "long_revisit"
WINDOW = 1000
SAMPLE_EVERY = 100
MAX_GROWTH = 0.10
MB = 1024.0 * 1024.0


def cached_render(cache: Path, frames: int) -> tuple[Path, int]:
    """A render of ``long_revisit`` holding at least ``frames`` frames (rendered now if the
    cache has none), and how many it holds. Rendered into a ``.partial`` folder first, so an
    interrupted render is never taken for a finished one; the next call resumes it, and a
    shorter finished render is extended, not rendered again (frames depend on their index
    only)."""
    seq_dir = cache / SEQUENCE
    meta = seq_dir / "sequence.json"
    if meta.is_file():
        have = int(json.loads(meta.read_text()).get("config", {}).get("frames", 0))
        if have >= frames:
            return seq_dir, have
    partial = cache / f"{SEQUENCE}.partial"
    cache.mkdir(parents=True, exist_ok=True)
    if seq_dir.is_dir() and not partial.exists():
        seq_dir.rename(partial)  # a shorter render: extend it
    print(f"rendering {frames} frames of {SEQUENCE} into {seq_dir} (once; resumes where it stopped)",
          file=sys.stderr)
    render_sequence(SEQUENCES[SEQUENCE].replace(frames=frames), partial, progress=True, resume=True)
    shutil.rmtree(seq_dir, ignore_errors=True)
    partial.rename(seq_dir)
    return seq_dir, frames


def rss_mb(proc: psutil.Process) -> tuple[float, float]:
    """RSS of the process and, summed, of its descendants (the BA and maps workers), in MB."""
    own = proc.memory_info().rss / MB
    workers = 0.0
    for child in proc.children(recursive=True):
        try:
            workers += child.memory_info().rss / MB
        except psutil.Error:  # a worker that ended between listing and reading
            pass
    return own, workers


def run(seq_dir: Path, frames: int, preset: str, overrides: list[str]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Track the first ``frames`` frames threaded; one row per window of WINDOW frames."""
    config = load_config(preset, overrides)
    sequence = open_sequence(seq_dir)
    proc = psutil.Process()
    rows: list[dict[str, Any]] = []
    ms: list[float] = []
    cpu_ms: list[float] = []
    samples: list[tuple[float, float]] = []
    start = time.perf_counter()
    with System(config, sequence.camera, name=str(seq_dir)) as system:
        packets = prefetch(system.prepare(f) for f in sequence.frames(0, frames))
        try:
            for i, packet in enumerate(packets):
                t0, c0 = time.perf_counter(), time.thread_time()
                system.track_frame(packet)
                ms.append(1000.0 * (time.perf_counter() - t0))
                cpu_ms.append(1000.0 * (time.thread_time() - c0))
                if (i + 1) % SAMPLE_EVERY == 0:
                    samples.append(rss_mb(proc))
                if (i + 1) % WINDOW == 0 or i + 1 == frames:
                    rows.append(_window(len(rows), ms, cpu_ms, samples, system))
                    ms, cpu_ms, samples = [], [], []
                    print(_row_line(rows[-1]), file=sys.stderr, flush=True)
        finally:
            packets.close()
        wall = time.perf_counter() - start
        stats = system.stats()
        summary = {"frames": system.n_frames, "keyframes": system.n_keyframes, "wall_s": wall,
                   "tracked": stats.get("tracked_frames"), "lost": stats.get("lost_frames"),
                   "loops": stats.get("loops"), "culled_keyframes": stats.get("culled_keyframes"),
                   "map_points": stats.get("map_points")}
    return rows, summary


def _window(k: int, ms: list[float], cpu_ms: list[float], samples: list[tuple[float, float]], system: System) -> dict[str, Any]:
    stats = system.stats()
    own = [s[0] for s in samples] or [float("nan")]
    workers = [s[1] for s in samples] or [float("nan")]
    return {"frames": f"{k * WINDOW}-{k * WINDOW + len(ms) - 1}", "n": len(ms), "ms_median": float(np.median(ms)),
            "ms_p95": float(np.percentile(ms, 95)), "cpu_ms_median": float(np.median(cpu_ms)), "rss_mb": max(own), "workers_rss_mb": max(workers),
            "keyframes": system.n_keyframes, "map_points": stats.get("map_points"),
            "culled_keyframes": stats.get("culled_keyframes"), "loops": stats.get("loops"),
            "lost": stats.get("lost_frames")}


def _row_line(r: dict[str, Any]) -> str:
    return (f"frames {r['frames']}: {r['ms_median']:.1f} ms median, RSS {r['rss_mb']:.0f} MB + workers "
            f"{r['workers_rss_mb']:.0f} MB, {r['keyframes']} keyframes, {r['map_points']} points")


def growth(rows: list[dict[str, Any]]) -> list[str]:
    """What grew by more than MAX_GROWTH from the second window to the last full one."""
    full = [r for r in rows if r["n"] == WINDOW]
    if len(full) < 3:
        return []
    second, last = full[1], full[-1]
    grew = []
    for key, what in (("rss_mb", "RSS"), ("workers_rss_mb", "workers' RSS"), ("ms_median", "median ms/frame")):
        if last[key] > (1.0 + MAX_GROWTH) * second[key]:
            grew.append(f"{what} grew {100 * (last[key] / second[key] - 1):.0f} % "
                        f"({second[key]:.1f} -> {last[key]:.1f}, frames {second['frames']} -> {last['frames']})")
    return grew


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| frames | ms/frame median | p95 | tracking CPU ms median | RSS MB | workers RSS MB | keyframes | culled "
             "| map points | loops |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['frames']} | {r['ms_median']:.1f} | {r['ms_p95']:.1f} | {r['cpu_ms_median']:.1f} | "
                     f"{r['rss_mb']:.0f} | "
                     f"{r['workers_rss_mb']:.0f} | {r['keyframes']} | {r['culled_keyframes']} | {r['map_points']} | "
                     f"{r['loops']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--frames", type=int, default=SEQUENCES[SEQUENCE].frames)
    ap.add_argument("--preset", default="orb")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "semslam" / "bench")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--render-only", action="store_true")
    args = ap.parse_args(argv)
    limit_threads()
    seq_dir, have = cached_render(args.cache.expanduser(), args.frames)
    if args.render_only:
        print(f"{seq_dir}: {have} frames")
        return 0
    overrides = list(args.overrides)
    rows, summary = run(seq_dir, args.frames, args.preset, overrides)
    grew = growth(rows)
    doc = {"sequence": SEQUENCE, "render": str(seq_dir), "preset": args.preset, "overrides": overrides,
           "load_average": os.getloadavg(), "windows": rows, "summary": summary, "grew": grew}
    emit_json(doc, args.json)
    print(table(rows))
    if grew:
        print("long run: " + "; ".join(grew), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
