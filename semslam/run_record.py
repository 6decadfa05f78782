"""What one run measured (per-frame times, latency, dynamic ratios) and its evaluation
against ground truth: the numbers ``stats.json`` and the report are written from."""

from __future__ import annotations

import logging
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from semslam.config import SystemConfig
from semslam.core.types import RunResult, TrackResult
from semslam.errors import EvalError
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import read_trajectory

if TYPE_CHECKING:
    from semslam.eval.metrics import AteResult, RpeResult

log = logging.getLogger(__name__)


class RunTiming:
    """Per-frame wall times, per-stage times and dynamic ratios of one run, as packed
    float64 arrays (8 bytes a value; a list of floats takes 32): a 20-minute run keeps
    about a million of them (benchmarks/long_run.py)."""

    def __init__(self) -> None:
        self.frame_ms: array[float] = array("d")
        self.dynamic_ratio: array[float] = array("d")
        self.stage_ms: dict[str, array[float]] = {}
        self.latency_ms: array[float] = array("d")
        # The tracking thread's CPU and run-queue ms per frame (thread_clock; run queue Linux only).
        self.cpu_ms: array[float] = array("d")
        self.runqueue_ms: array[float] = array("d")
        self.late_frames = 0
        self.interrupted = False
        self.t_first: float | None = None
        self.last_done = -np.inf
        self.wall_s = 0.0

    def add(self, t0: float, done: float, result: TrackResult, arrived: float | None,
            cpu_ms: float | None = None, runqueue_ms: float | None = None) -> None:
        """One frame tracked from ``t0`` to ``done``, with ``cpu_ms`` of the tracking thread's
        CPU and ``runqueue_ms`` waiting for a core in between; wall time counts from the
        first frame."""
        if self.t_first is None:
            self.t_first = t0 if arrived is None else min(t0, arrived)
        self.frame_ms.append((done - t0) * 1e3)
        if cpu_ms is not None:
            self.cpu_ms.append(cpu_ms)
            if runqueue_ms is not None:
                self.runqueue_ms.append(runqueue_ms)
        self.dynamic_ratio.append(result.dynamic_ratio)
        for stage, v in result.timings.items():
            values = self.stage_ms.get(stage)
            if values is None:
                values = self.stage_ms[stage] = array("d")
            values.append(v)
        if arrived is not None:  # camera rate: the previous frame was still being tracked when it arrived
            self.late_frames += int(self.last_done > arrived)
            self.latency_ms.append((done - arrived) * 1e3)
        self.last_done = done
        self.wall_s = done - self.t_first

    def thread_split(self) -> dict[str, float]:
        """Per-frame medians of the tracking thread's CPU, run-queue and asleep ms (the
        asleep time is wall - CPU - run queue, frame by frame); {} if not measured."""
        n = len(self.cpu_ms)
        if n == 0 or n != len(self.frame_ms):
            return {}
        cpu = np.asarray(self.cpu_ms)
        out = {"cpu": float(np.median(cpu))}
        if len(self.runqueue_ms) == n:
            runq = np.asarray(self.runqueue_ms)
            out["runqueue"] = float(np.median(runq))
            out["asleep"] = float(np.median(np.maximum(np.asarray(self.frame_ms) - cpu - runq, 0.0)))
        return out


def timing_stats(values: Sequence[float]) -> dict[str, float]:
    if not values:
        return {"median": 0.0, "mean": 0.0, "p95": 0.0, "max": 0.0}
    a = np.asarray(values)
    return {"median": float(np.median(a)), "mean": float(a.mean()), "p95": float(np.percentile(a, 95)), "max": float(a.max())}


@dataclass
class Evaluation:
    """What ``evaluate`` measured, kept for the report (written later, after the maps it shows)."""

    gt: Trajectory
    traj: Trajectory
    ate: AteResult
    rpe: RpeResult
    ate_se3: AteResult | None


def evaluate(gt_path: Path, traj: Trajectory, config: SystemConfig, result: RunResult) -> Evaluation | None:
    """ATE (SE(3) for RGB-D and stereo, Sim(3) for monocular) and RPE over 1 s, into ``result``; the
    evaluation for ``write_run_report`` (None when the trajectory cannot be evaluated)."""
    from semslam.eval.metrics import ate, rpe

    gt = read_trajectory(gt_path)
    align = "sim3" if config.sensor == "mono" else "se3"
    try:
        ate_res = ate(gt, traj, align=align)
        ate_se3 = ate(gt, traj, align="se3") if align == "sim3" else None  # mono: the metric scale too
    except EvalError as exc:
        log.warning("evaluation skipped: %s", exc)
        result.eval_error = str(exc)
        return None
    result.ate, result.ate_alignment = ate_res.stats, align
    if ate_se3 is not None:
        result.ate_se3, result.ate_sim3_scale = ate_se3.stats, float(ate_res.scale)
    try:  # a run shorter than a second (one stopped early) has an ATE but no 1 s RPE
        rpe_res = rpe(gt, traj, delta=1.0, delta_unit="seconds", align="none")
    except EvalError as exc:
        log.warning("RPE skipped: %s", exc)
        result.eval_error = str(exc)
        return None
    result.rpe_trans_1s, result.rpe_rot_deg_1s = rpe_res.trans_stats, rpe_res.rot_stats
    return Evaluation(gt, traj, ate_res, rpe_res, ate_se3)


def write_run_report(out: Path, evaluation: Evaluation, config: SystemConfig, result: RunResult) -> None:
    """``report.html`` (plots of the evaluation, views of ``out/map``), into ``result.paths``."""
    from semslam.eval.report import write_report

    extra = {"preset": config.preset, "frames": result.frames, "tracked": result.tracked_frames,
             "lost": result.lost_frames, "keyframes": result.keyframes,
             "median ms/frame": round(result.ms_per_frame["median"], 2), "fps (wall)": round(result.fps, 1)}
    write_report(out / "report.html", evaluation.gt, evaluation.traj, evaluation.ate, evaluation.rpe,
                 title=f"semslam {config.preset}: {Path(result.sequence).name}", extra=extra,
                 map_dir=out / "map", ate_se3=evaluation.ate_se3)
    result.paths["report"] = str(out / "report.html")
