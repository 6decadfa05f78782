"""Benchmarks on the project's synthetic sequences (``semslam bench``): a batch plan (render
them, run variants on each, ``repeats`` times) run by the batch runner, with one row per run
made from each run's ``RunResult``.

A variant is ``label:preset:key=value[,key=value...]`` (a preset with ``--set`` overrides).
Rendered sequences are cached (re-rendered when their config changes). Numbers come from
the runs on this machine; nothing is hard-coded. Unlike ``semslam batch``, a benchmark runs
every job again (no resuming) and, by default, one job at a time in this process, so the
runs' timings do not compete with each other.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from semslam.core.types import RunResult
from semslam.errors import ConfigError
from semslam.experiments.batch import Executor, run_batch
from semslam.experiments.batch_jobs import JobRecord, read_stats
from semslam.experiments.batch_plan import Plan, SequenceSpec, Variant
from semslam.experiments.batch_summary import machine
from semslam.synth import SEQUENCES

__all__ = ["Variant", "BenchRow", "bench_plan", "run_benchmark", "machine", "targets_table", "document",
           "markdown_table"]

#: STDC-SLAM Table 1 columns: OS3 (base), +S, +S+SRM, +S+SRM+Q (= stdc), +Q; and DDL-SLAM.
ABLATION_VARIANTS = [
    "base:orb:",
    "+S:orb:dynamics.semantic=true",
    "+S+SRM:orb:dynamics.semantic=true,semantics.srm=true",
    "+S+SRM+Q:stdc:",
    "+Q:orb:features.extractor=qtree_orb,features.n_levels=6",
    "ddl:ddl:",
    "default:default:",
]
ABLATION_SEQUENCES = ["walking_xyz", "walking_rpy", "walking_halfsphere", "walking_static", "static_xyz", "walking_box"]
DEFAULT_SEQUENCES = ["static_xyz", "loop", "room_loop", "walking_static", "walking_xyz", "walking_rpy", "walking_halfsphere"]
#: Ray CPUs per benchmark job: tracking and local mapping keep about two cores busy.
BENCH_JOB_CPUS = 2.0


@dataclass
class BenchRow:
    """One (variant, sequence) run, with the sequence's synthetic settings."""

    variant: str
    preset: str
    overrides: list[str]
    sequence: str
    people: int
    motion: str
    result: RunResult
    repeat: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        return {
            "variant": self.variant, "preset": self.preset, "overrides": self.overrides, "sequence": self.sequence,
            "people": self.people, "motion": self.motion, "frames": r.frames, "tracked_frames": r.tracked_frames,
            "lost_frames": r.lost_frames, "keyframes": r.keyframes, "loops": r.loop_closing.loops,
            "relocalisations": r.tracking.relocalisations, "ate_rmse_m": r.ate_rmse,
            "rpe_trans_rmse_m_1s": r.rpe_trans_rmse, "ms_per_frame_median": r.ms_per_frame.get("median"),
            "ms_per_frame_p95": r.ms_per_frame.get("p95"), "stages_ms_median": r.stages_ms_median,
            "tracking_thread_ms": r.tracking_thread_ms, "dynamic_ratio_mean": r.dynamic_ratio_mean,
            "out_dir": str(r.out_dir), "repeat": self.repeat,
        }


def bench_plan(variants: list[Variant], sequences: list[str], data: Path, frames: int | None = None,
               repeats: int = 1) -> Plan:
    """The benchmark as a batch plan: synthetic sequences rendered into ``data`` (``frames``
    long), runs in ``VARIANT/SEQUENCE`` (``VARIANT/SEQUENCE/rK`` with repeats), no reports."""
    unknown = [n for n in sequences if n not in SEQUENCES]
    if unknown:
        raise ConfigError(f"--sequences: unknown {', '.join(unknown)} (known: {', '.join(SEQUENCES)})")
    layout = "{variant}/{sequence}" if repeats == 1 else "{variant}/{sequence}/r{repeat}"
    return Plan([SequenceSpec(n, synth=n) for n in sequences], variants, repeats=repeats, frames=frames,
                num_cpus=BENCH_JOB_CPUS, report=False, data=data, layout=layout, where="semslam bench")


@dataclass
class BenchRun:
    """What ``run_benchmark`` measured: one row per finished run (sequence, variant, repeat
    order), and the batch summary (spread over repeats, failed jobs)."""

    rows: list["BenchRow"]
    summary: dict[str, Any]


def run_benchmark(variants: list[Variant], sequences: list[str], data: Path, out: Path, frames: int | None = None,
                  on_row: Callable[["BenchRow"], None] | None = None, repeats: int = 1,
                  executor: Executor = Executor(ray=False)) -> BenchRun:
    """Render each sequence (cached) and run every variant on it ``repeats`` times; a
    failed run is in ``summary`` (with its one-line error), not a row."""
    plan = bench_plan(variants, sequences, data, frames, repeats)
    rows: dict[str, BenchRow] = {}

    def add(record: JobRecord) -> None:
        if not record.ok:
            return
        synth = SEQUENCES[record.sequence]
        row = BenchRow(record.variant, record.preset, list(record.overrides), record.sequence, synth.people,
                       synth.motion, read_stats(record.out_dir), repeat=record.repeat)
        rows[record.key] = row
        if on_row is not None:
            on_row(row)

    summary = run_batch(plan, out, executor, resume=False, progress=False, on_record=add)
    v_order, s_order = [v.label for v in variants], list(sequences)
    ordered = sorted(rows.values(), key=lambda r: (s_order.index(r.sequence), v_order.index(r.variant), r.repeat))
    return BenchRun(ordered, summary)


def emit_json(doc: dict[str, Any], path: Path | None = None) -> None:
    """Print a benchmark's JSON document and, with ``path``, also write it there: every
    benchmark script ends this way, so their numbers can be read back by other tools."""
    text = json.dumps(doc, indent=2)
    print(text)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def time_calls(fn: Callable[[], Any], repeats: int, warmup: int = 1,
               cpu_clock: Callable[[], float] = time.thread_time) -> tuple[list[float], list[float]]:
    """Wall and CPU milliseconds of ``repeats`` calls of ``fn`` after ``warmup`` untimed ones
    (allocators, caches, JIT): the one timing loop of the benchmark scripts. ``cpu_clock`` is
    the calling thread's CPU by default; ``time.process_time`` counts the threads a library
    starts for the call too."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), cpu_clock()
        fn()
        wall.append(1e3 * (time.perf_counter() - w0))
        cpu.append(1e3 * (cpu_clock() - c0))
    return wall, cpu


def timing_summary(wall_ms: list[float], cpu_ms: list[float]) -> dict[str, float]:
    """Median, p95 and minimum wall time and median CPU time of timed calls, in ms."""
    w = np.asarray(wall_ms, float)
    return {"wall_ms_p50": float(np.median(w)), "wall_ms_p95": float(np.percentile(w, 95)),
            "wall_ms_min": float(w.min()), "cpu_ms_p50": float(np.median(cpu_ms)), "n": int(w.size)}


def targets_table(targets: list[dict[str, Any]], digits: int = 1) -> str:
    """The benchmarks' closing table: each target (``{"target", "value", "met"}``), what was
    measured and whether it is met."""
    lines = ["| target | measured | met |", "|---|---|---|"]
    for t in targets:
        v = t["value"]
        lines.append(f"| {t['target']} | {v:.{digits}f} | {'yes' if t['met'] else 'no'} |" if isinstance(v, float)
                     else f"| {t['target']} | {v} | {'yes' if t['met'] else 'no'} |")
    return "\n".join(lines)


def document(rows: list[BenchRow], sequences: list[str], summary: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON document ``semslam bench`` prints; with the batch ``summary``, also the
    spread over repeats per sequence x variant and the failed runs."""
    doc = {"machine": machine(), "results": [r.to_dict() for r in rows],
           "synth_configs": {n: asdict(SEQUENCES[n]) for n in sequences}}
    if summary is not None:
        doc["groups"] = summary["groups"]
        doc["failed"] = [j for j in summary["jobs"] if j["status"] != "ok"]
    return doc


def markdown_table(rows: list[BenchRow]) -> str:
    """One line per run (``(rK)`` after the variant when there are repeats)."""
    lines = ["| sequence | people | variant | frames (tracked) | KFs | loops | ATE RMSE (cm) | RPE 1 s (cm) | "
             "ms/frame median | p95 |", "|---|---|---|---|---|---|---|---|---|---|"]
    repeated = any(row.repeat for row in rows)
    for row in rows:
        r = row.result
        variant = f"{row.variant} (r{row.repeat})" if repeated else row.variant
        ate = "n/a" if r.ate_rmse is None else f"{r.ate_rmse * 100:.2f}"
        rpe = "n/a" if r.rpe_trans_rmse is None else f"{r.rpe_trans_rmse * 100:.2f}"
        loops = r.loop_closing.loops
        lines.append(f"| {row.sequence} | {row.people} | {variant} | {r.frames} ({r.tracked_frames}) | "
                     f"{r.keyframes} | {'-' if loops is None else loops} | {ate} | {rpe} | "
                     f"{r.ms_per_frame['median']:.1f} | {r.ms_per_frame['p95']:.1f} |")
    return "\n".join(lines)
