"""Benchmarks on the project's synthetic sequences (``semslam bench``): render them, run
variants on each, return one row per (variant, sequence) made from each run's ``RunResult``.

A variant is ``label:preset:key=value[,key=value...]`` (a preset with ``--set`` overrides).
Rendered sequences are cached (re-rendered when their config changes). Numbers come from
the runs on this machine; nothing is hard-coded.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from semslam.config import load_config
from semslam.core.types import RunResult
from semslam.errors import ConfigError
from semslam.io.sequence import kind_for_sensor, open_sequence
from semslam.pipeline import run_slam
from semslam.synth import SEQUENCES, ensure_rendered

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


@dataclass(frozen=True)
class Variant:
    label: str
    preset: str
    overrides: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str) -> "Variant":
        """``label:preset:key=value,...``; a bare preset name is its own label."""
        parts = text.split(":")
        if len(parts) == 1:
            return cls(parts[0], parts[0])
        if len(parts) > 3 or not parts[0] or not parts[1]:
            raise ConfigError(f"--variant {text!r}: expected label:preset[:key=value,...]")
        rest = parts[2] if len(parts) == 3 else ""
        return cls(parts[0], parts[1], tuple(o for o in rest.split(",") if o))


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
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        return {
            "variant": self.variant, "preset": self.preset, "overrides": self.overrides, "sequence": self.sequence,
            "people": self.people, "motion": self.motion, "frames": r.frames, "tracked_frames": r.tracked_frames,
            "lost_frames": r.lost_frames, "keyframes": r.keyframes, "loops": r.get("loops"),
            "relocalisations": r.get("relocalisations"), "ate_rmse_m": r.ate_rmse,
            "rpe_trans_rmse_m_1s": r.rpe_trans_rmse, "ms_per_frame_median": r.ms_per_frame.get("median"),
            "ms_per_frame_p95": r.ms_per_frame.get("p95"), "stages_ms_median": r.stages_ms_median,
            "dynamic_ratio_mean": r.dynamic_ratio_mean, "out_dir": str(r.out_dir),
        }


def run_benchmark(variants: list[Variant], sequences: list[str], data: Path, out: Path, frames: int | None = None,
                  on_row: Callable[[BenchRow], None] | None = None) -> list[BenchRow]:
    """Render each sequence (cached) and run every variant on it."""
    unknown = [n for n in sequences if n not in SEQUENCES]
    if unknown:
        raise ConfigError(f"--sequences: unknown {', '.join(unknown)} (known: {', '.join(SEQUENCES)})")
    configs = {v.label: load_config(v.preset, list(v.overrides)) for v in variants}  # fail before rendering
    rows = []
    for name in sequences:
        synth_cfg = SEQUENCES[name] if frames is None else replace(SEQUENCES[name], frames=frames)
        t0 = time.perf_counter()
        if ensure_rendered(synth_cfg, data / name):
            print(f"rendered {name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        for v in variants:
            result = run_slam(open_sequence(data / name, kind=kind_for_sensor(configs[v.label].sensor)), configs[v.label], out / v.label / name,
                              progress=False, report=False)
            row = BenchRow(v.label, v.preset, list(v.overrides), name, synth_cfg.people, synth_cfg.motion, result)
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows


def machine() -> dict[str, Any]:
    return {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count()}


def targets_table(targets: list[dict[str, Any]], digits: int = 1) -> str:
    """The benchmarks' closing table: each target (``{"target", "value", "met"}``), what was
    measured and whether it is met."""
    lines = ["| target | measured | met |", "|---|---|---|"]
    for t in targets:
        v = t["value"]
        lines.append(f"| {t['target']} | {v:.{digits}f} | {'yes' if t['met'] else 'no'} |" if isinstance(v, float)
                     else f"| {t['target']} | {v} | {'yes' if t['met'] else 'no'} |")
    return "\n".join(lines)


def document(rows: list[BenchRow], sequences: list[str]) -> dict[str, Any]:
    """The JSON document ``semslam bench`` prints."""
    return {"machine": machine(), "results": [r.to_dict() for r in rows],
            "synth_configs": {n: asdict(SEQUENCES[n]) for n in sequences}}


def markdown_table(rows: list[BenchRow]) -> str:
    lines = ["| sequence | people | variant | frames (tracked) | KFs | loops | ATE RMSE (cm) | RPE 1 s (cm) | "
             "ms/frame median | p95 |", "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        r = row.result
        ate = "n/a" if r.ate_rmse is None else f"{r.ate_rmse * 100:.2f}"
        rpe = "n/a" if r.rpe_trans_rmse is None else f"{r.rpe_trans_rmse * 100:.2f}"
        loops = r.get("loops")
        lines.append(f"| {row.sequence} | {row.people} | {row.variant} | {r.frames} ({r.tracked_frames}) | "
                     f"{r.keyframes} | {'-' if loops is None else loops} | {ate} | {rpe} | "
                     f"{r.ms_per_frame['median']:.1f} | {r.ms_per_frame['p95']:.1f} |")
    return "\n".join(lines)
