"""Run the System over a sequence and write what other tools read.

Outputs in ``out_dir``: ``trajectory.txt`` (TUM; evo reads it), ``keyframes.txt``,
``stats.json`` (the run's ``RunResult``: counts, per-frame and per-stage timings, ATE/RPE
when ground truth exists), ``config.json`` and ``report.html``.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Generator, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from semslam.config import SystemConfig, config_to_dict
from semslam.core.protocols import FramePacket, SequenceSource as Sequence
from semslam.core.types import Frame, RunResult, TrackResult
from semslam.errors import ConfigError, DataError, EvalError, RunInterrupted
from semslam.io.trajectory import Trajectory, read_trajectory, write_tum
from semslam.runtime import stop_requested
from semslam.slam.system import System

if TYPE_CHECKING:
    from semslam.viz.rerun_log import RerunRecorder

log = logging.getLogger(__name__)
T = TypeVar("T")


def prefetch(items: Iterator[T], depth: int = 2) -> Generator[T, None, None]:
    """Decode the next frames in a background thread (OpenCV releases the GIL)."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="reader") as pool:
        sentinel = object()
        it = iter(items)
        queue = [pool.submit(next, it, sentinel) for _ in range(depth)]
        while True:
            item = queue.pop(0).result()
            if item is sentinel:
                return
            queue.append(pool.submit(next, it, sentinel))
            yield item  # type: ignore[misc]


def at_camera_rate(frames: Iterator[Frame], realtime: bool) -> Generator[tuple[Frame, float], None, None]:
    """Each frame with the time it arrives: with ``realtime``, not before its timestamp
    (relative to the first frame's) comes due, as a live camera delivers it; otherwise
    as soon as it is decoded."""
    t_first = start = None
    for frame in frames:
        if realtime:
            now = time.perf_counter()
            if t_first is None:
                t_first, start = frame.timestamp, now
            due = start + (frame.timestamp - t_first)
            if due > now:
                time.sleep(due - now)
        yield frame, time.perf_counter()


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
    rerun: str | Path | None = None,
    rerun_spawn: bool = False,
) -> RunResult:
    """Track every frame of ``sequence``, write outputs, evaluate against ground truth.

    Whatever happens (a failed worker thread, an exception while tracking), the trajectory
    so far, ``keyframes.txt`` and ``stats.json`` (with ``error``) are written before the
    exception propagates; every thread and process the run started is stopped. A stop asked
    for (``runtime.request_stop``: Ctrl-C or SIGTERM under ``runtime.StopOnSignals``) ends
    tracking after the current frame; the outputs are written as usual (``"interrupted":
    true``, and ``--save-map``'s map) except the maps of ``maps.builders``, whose final
    integration takes seconds (``semslam map OUT`` builds them from the keyframes); then
    ``RunInterrupted`` is raised.

    ``rerun`` (an ``.rrd`` path) / ``rerun_spawn`` record the run for the Rerun viewer
    (``viz.rerun_log``); the recording is closed, complete, on every path too.
    """
    out = Path(out_dir)
    if config.sensor == "rgbd" and not sequence.has_depth:
        raise DataError(sequence.root, "no depth images: this is a monocular sequence; run it with sensor: mono "
                                       "(--preset sdf)")
    system = System(config, sequence.camera, Path(load_map) if load_map else None)
    if save_map and not system.has_map:  # before any frame, not after the whole run
        system.close()
        raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
    recorder = _open_recorder(rerun, rerun_spawn, system)
    out.mkdir(parents=True, exist_ok=True)
    n_total = len(sequence) if max_frames is None else min(max_frames, len(sequence))
    timing = _RunTiming()
    error: BaseException | None = None
    try:
        _track_all(system, sequence, config, n_total, timing, progress, recorder)
    except BaseException as exc:
        error = exc
    finally:
        try:
            system.shutdown()
        except BaseException as exc:  # a worker that failed on the last keyframes
            error = error or exc
    try:
        if save_map and error is None:
            system.save_map(Path(save_map))
        result, map_error = _write_outputs(system, sequence, config, out, timing, report, error)
        error = error or map_error
        if timing.interrupted and error is None:
            maps = " (maps not written: `semslam map OUT` builds them)" if config.maps.builders else ""
            error = RunInterrupted(f"stopped after {len(timing.frame_ms)} of {n_total} frames; outputs in {out}{maps}")
        if recorder is not None:
            _log_run_end(recorder, system, out / "map")
    finally:
        if recorder is not None:
            recorder.close()
    if error is not None:
        raise error
    return result


class _RunTiming:
    """Per-frame wall times, per-stage times and dynamic ratios of one run."""

    def __init__(self) -> None:
        self.frame_ms: list[float] = []
        self.dynamic_ratio: list[float] = []
        self.stage_ms: dict[str, list[float]] = {}
        self.latency_ms: list[float] = []
        self.late_frames = 0
        self.interrupted = False
        self.t_start = time.perf_counter()
        self.wall_s = 0.0

    def add(self, ms: float, result: TrackResult) -> None:
        self.frame_ms.append(ms)
        self.dynamic_ratio.append(result.dynamic_ratio)
        for stage, v in result.timings.items():
            self.stage_ms.setdefault(stage, []).append(v)


def _open_recorder(path: str | Path | None, spawn: bool, system: System) -> "RerunRecorder | None":
    """The Rerun recorder asked for, if any (the system is closed if it cannot be made)."""
    if path is None and not spawn:
        return None
    from semslam.viz.rerun_log import RerunRecorder

    try:
        return RerunRecorder("semslam", path=path, spawn=spawn)
    except BaseException:
        system.close()
        raise


def _log_frame(recorder: "RerunRecorder", packet: FramePacket, result: TrackResult, sequence: Sequence) -> None:
    frame = packet.frame
    dynamic = packet.dynamic if isinstance(packet.dynamic, np.ndarray) else None
    recorder.log_frame(frame.index, frame.timestamp, frame.rgb, dynamic, packet.keypoints_xy, packet.keypoint_static,
                       result.pose_wc, sequence.camera)


def _log_run_end(recorder: "RerunRecorder", system: System, map_dir: Path) -> None:
    """The final trajectory, the map points and the semantic cloud (if the maps wrote one)."""
    recorder.log_trajectory(system.trajectory().positions)
    points = system.map_points()
    if len(points):
        recorder.log_map_points(points)
    recorder.log_map_dir(map_dir)


def _track_all(system: System, sequence: Sequence, config: SystemConfig, n_total: int, timing: _RunTiming,
               progress: bool, recorder: "RerunRecorder | None" = None) -> None:
    # The reader thread hands each decoded frame to the system at once (segmentation starts),
    # at the camera's rate with slam.realtime.
    realtime = config.slam.realtime
    packets = prefetch((system.prepare(FramePacket(f)), t) for f, t in
                       at_camera_rate(sequence.frames(0, n_total), realtime))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_total, unit="frame", desc=f"semslam {config.preset}", dynamic_ncols=True, leave=True)
    try:
        done = -np.inf
        for packet, t_arrived in packets:
            if stop_requested():
                timing.interrupted = True
                break
            if realtime:  # the previous frame was still being tracked when this one arrived
                timing.late_frames += int(done > t_arrived)
            t0 = time.perf_counter()
            result = system.track(packet)
            done = time.perf_counter()
            timing.add((done - t0) * 1e3, result)
            if realtime:
                timing.latency_ms.append((done - t_arrived) * 1e3)
            if recorder is not None:
                _log_frame(recorder, packet, result, sequence)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(state=result.state.value, inl=result.n_inliers, kf=system.n_keyframes, refresh=False)
    finally:
        packets.close()
        if bar is not None:
            bar.close()
        timing.wall_s = time.perf_counter() - timing.t_start


def _write_outputs(system: System, sequence: Sequence, config: SystemConfig, out: Path, timing: _RunTiming,
                   report: bool, error: BaseException | None) -> tuple[RunResult, BaseException | None]:
    """Write every output; returns the result and the maps' failure, if they failed."""
    traj = system.trajectory()
    write_tum(out / "trajectory.txt", traj)
    paths = {"trajectory": str(out / "trajectory.txt"), "stats": str(out / "stats.json"),
             "config": str(out / "config.json")}
    kf_traj = system.keyframe_trajectory()
    if len(kf_traj):
        write_tum(out / "keyframes.txt", kf_traj)
        paths["keyframes"] = str(out / "keyframes.txt")
    map_error: BaseException | None = None
    if timing.interrupted:  # stop fast: finishing the maps takes seconds; `semslam map OUT` rebuilds them
        system.close()
    else:
        try:  # a failed map still leaves the trajectory and stats.json (with the error) behind
            paths.update({name: str(p) for name, p in system.write_maps(out / "map").items()})
        except Exception as exc:  # noqa: BLE001 - reported in stats.json, then raised by run_slam
            map_error = exc
            error = error or exc
    n = len(timing.frame_ms)
    cam = sequence.camera
    result = RunResult(
        sequence=str(sequence.root), preset=config.preset, out_dir=out, **system.counts(),
        skipped_frames=len(sequence.skipped), skipped=[msg for _, msg in sequence.skipped],
        ms_per_frame=_timing_stats(timing.frame_ms),
        stages_ms_median={k: float(np.median(v)) for k, v in timing.stage_ms.items()},
        stages_ms_p95={k: float(np.percentile(v, 95)) for k, v in timing.stage_ms.items()},
        stages_ms_max={k: float(np.max(v)) for k, v in timing.stage_ms.items()},
        realtime=config.slam.realtime, late_frames=timing.late_frames,
        latency_ms=_timing_stats(timing.latency_ms) if timing.latency_ms else {},
        dynamic_ratio_mean=float(np.mean(timing.dynamic_ratio)) if timing.dynamic_ratio else 0.0,
        wall_s=timing.wall_s, fps=n / timing.wall_s if timing.wall_s > 0 else 0.0,
        tracking_fps=1000.0 / float(np.mean(timing.frame_ms)) if n else 0.0,
        camera={"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height,
                "dist": list(cam.dist), "source": cam.source},
        tracker=system.stats(), paths=paths, interrupted=timing.interrupted or isinstance(error, KeyboardInterrupt),
        error=None if error is None else f"{type(error).__name__}: {error}",
    )
    if sequence.groundtruth_path is not None and len(traj) >= 3:
        # Interrupted: ATE into stats.json, but no report (its plots take a second or more).
        _evaluate(sequence.groundtruth_path, traj, config, out, result, report and not timing.interrupted)
    (out / "stats.json").write_text(json.dumps(result.to_dict(), indent=2))
    (out / "config.json").write_text(json.dumps(config_to_dict(config), indent=2))
    return result, map_error


def _evaluate(gt_path: Path, traj: Trajectory, config: SystemConfig, out: Path, result: RunResult,
              report: bool) -> None:
    """ATE (SE(3) for RGB-D, Sim(3) for monocular) and RPE over 1 s, into ``result``; the HTML report."""
    from semslam.eval.metrics import ate, rpe

    gt = read_trajectory(gt_path)
    align = "se3" if config.sensor == "rgbd" else "sim3"
    try:
        ate_res = ate(gt, traj, align=align)
        ate_se3 = ate(gt, traj, align="se3") if align == "sim3" else None  # mono: the metric scale too
    except EvalError as exc:
        log.warning("evaluation skipped: %s", exc)
        result.eval_error = str(exc)
        return
    result.ate, result.ate_alignment = ate_res.stats, align
    if ate_se3 is not None:
        result.ate_se3, result.ate_sim3_scale = ate_se3.stats, float(ate_res.scale)
    try:  # a run shorter than a second (one stopped early) has an ATE but no 1 s RPE
        rpe_res = rpe(gt, traj, delta=1.0, delta_unit="seconds", align="none")
    except EvalError as exc:
        log.warning("RPE skipped: %s", exc)
        result.eval_error = str(exc)
        return
    result.rpe_trans_1s, result.rpe_rot_deg_1s = rpe_res.trans_stats, rpe_res.rot_stats
    if report:
        from semslam.eval.report import write_report

        extra = {"preset": config.preset, "frames": result.frames, "tracked": result.tracked_frames,
                 "lost": result.lost_frames, "keyframes": result.keyframes,
                 "median ms/frame": round(result.ms_per_frame["median"], 2), "fps (wall)": round(result.fps, 1)}
        write_report(out / "report.html", gt, traj, ate_res, rpe_res,
                     title=f"semslam {config.preset}: {Path(result.sequence).name}", extra=extra,
                     map_dir=out / "map", ate_se3=ate_se3)
        result.paths["report"] = str(out / "report.html")
