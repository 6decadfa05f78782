"""Run the System over a sequence and write what other tools read.

Outputs in ``out_dir``: ``trajectory.txt`` (TUM; evo reads it), ``stats.json`` (counts,
per-frame and per-stage timings, ATE/RPE when ground truth exists), ``report.html``.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from semslam.config import SystemConfig, config_to_dict
from semslam.errors import EvalError
from semslam.io.sequence import Frame, Sequence
from semslam.io.trajectory import read_trajectory, write_tum
from semslam.slam.system import System

log = logging.getLogger(__name__)


@dataclass
class RunSummary:
    out_dir: Path
    stats: dict[str, Any]

    @property
    def ate_rmse(self) -> float | None:
        ate = self.stats.get("ate")
        return None if ate is None else float(ate["rmse"])


def prefetch(frames: Iterator[Frame], depth: int = 2) -> Iterator[Frame]:
    """Decode the next frames in a background thread (OpenCV releases the GIL)."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        sentinel = object()
        it = iter(frames)
        queue = [pool.submit(next, it, sentinel) for _ in range(depth)]
        while True:
            item = queue.pop(0).result()
            if item is sentinel:
                return
            queue.append(pool.submit(next, it, sentinel))
            yield item  # type: ignore[misc]


def _timing_stats(values: list[float]) -> dict[str, float]:
    if not values:
        return {"median": 0.0, "mean": 0.0, "p95": 0.0, "max": 0.0}
    a = np.asarray(values)
    return {"median": float(np.median(a)), "mean": float(a.mean()), "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def run_slam(
    sequence: Sequence,
    config: SystemConfig,
    out_dir: str | Path,
    max_frames: int | None = None,
    progress: bool = True,
    report: bool = True,
    save_map: str | Path | None = None,
    load_map: str | Path | None = None,
) -> RunSummary:
    """Track every frame of ``sequence``, write outputs, evaluate against ground truth."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    system = System(config, sequence.camera, Path(load_map) if load_map else None)
    n_total = len(sequence) if max_frames is None else min(max_frames, len(sequence))
    frame_ms: list[float] = []
    dynamic_ratio: list[float] = []
    stage_ms: dict[str, list[float]] = {}
    t_start = time.perf_counter()
    # The reader thread hands each decoded frame to the system at once (segmentation starts).
    frames = prefetch(system.prepare(f) for f in sequence.frames(0, n_total))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_total, unit="frame", desc=f"semslam {config.preset}", dynamic_ncols=True, leave=True)
    try:
        for frame in frames:
            t0 = time.perf_counter()
            result = system.track(frame)
            frame_ms.append((time.perf_counter() - t0) * 1e3)
            dynamic_ratio.append(result.dynamic_ratio)
            for stage, ms in result.timings.items():
                stage_ms.setdefault(stage, []).append(ms)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(state=result.state.value, inl=result.n_inliers, kf=system.n_keyframes, refresh=False)
    finally:
        if bar is not None:
            bar.close()
        system.shutdown()
    wall_s = time.perf_counter() - t_start
    if save_map:
        system.save_map(Path(save_map))

    traj = system.trajectory()
    write_tum(out / "trajectory.txt", traj)
    kf_traj = system.keyframe_trajectory()
    if kf_traj is not None:
        write_tum(out / "keyframes.txt", kf_traj)
    stats: dict[str, Any] = {
        "sequence": str(sequence.root),
        "preset": config.preset,
        **system.counts(),
        **system.extra_stats(),
        "skipped_frames": len(sequence.skipped),
        "ms_per_frame": _timing_stats(frame_ms),
        "stages_ms_median": {k: float(np.median(v)) for k, v in stage_ms.items()},
        "dynamic_ratio_mean": float(np.mean(dynamic_ratio)) if dynamic_ratio else 0.0,
        "wall_s": wall_s,
        "fps": len(frame_ms) / wall_s if wall_s > 0 else 0.0,
        "tracking_fps": 1000.0 / float(np.mean(frame_ms)) if frame_ms else 0.0,
        "camera": {"fx": sequence.camera.fx, "fy": sequence.camera.fy, "cx": sequence.camera.cx,
                   "cy": sequence.camera.cy, "dist": list(sequence.camera.dist), "source": sequence.camera.source},
    }
    if sequence.skipped:
        stats["skipped"] = [msg for _, msg in sequence.skipped]
    if sequence.groundtruth_path is not None and len(traj) >= 3:
        stats.update(_evaluate(sequence.groundtruth_path, traj, config, out, stats, report))
    (out / "stats.json").write_text(json.dumps(stats, indent=2))
    (out / "config.json").write_text(json.dumps(config_to_dict(config), indent=2))
    return RunSummary(out, stats)


def _evaluate(gt_path: Path, traj: Any, config: SystemConfig, out: Path, stats: dict[str, Any], report: bool) -> dict[str, Any]:
    from semslam.eval.metrics import ate, rpe

    gt = read_trajectory(gt_path)
    align = "se3" if config.sensor == "rgbd" else "sim3"
    try:
        ate_res = ate(gt, traj, align=align)
        rpe_res = rpe(gt, traj, delta=1.0, delta_unit="seconds", align="none")
    except EvalError as exc:
        log.warning("evaluation skipped: %s", exc)
        return {"eval_error": str(exc)}
    result = {"ate": ate_res.stats, "ate_alignment": align,
              "rpe_trans_1s": rpe_res.trans_stats, "rpe_rot_deg_1s": rpe_res.rot_stats}
    if report:
        from semslam.eval.report import write_report

        extra = {"preset": config.preset, "frames": stats["frames"], "tracked": stats["tracked_frames"],
                 "keyframes": stats["keyframes"], "median ms/frame": round(stats["ms_per_frame"]["median"], 2),
                 "fps (wall)": round(stats["fps"], 1)}
        write_report(out / "report.html", gt, traj, ate_res, rpe_res, title=f"semslam {config.preset}: {Path(stats['sequence']).name}", extra=extra)
    return result
