"""Run the System over a sequence and write what other tools read: a loop over the Python
API's ``System`` (``semslam/api.py``), which tracks each frame and writes the outputs.

Outputs in ``out_dir``: ``trajectory.txt`` (TUM; evo reads it), ``keyframes.txt``,
``stats.json`` (the run's ``RunResult``: counts, per-frame and per-stage timings, ATE/RPE
when ground truth exists), ``config.json`` and ``report.html``.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Generator, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar


from semslam.api import System, make_config
from semslam.config import SystemConfig
from semslam.core.protocols import SequenceSource as Sequence
from semslam.core.types import Frame, RunResult, TrackResult
from semslam.errors import ConfigError, DataError, OutputError, RunInterrupted
from semslam.io.stereo_calibration import StereoCalibration
from semslam.runtime import lower_thread_priority, stop_exit_code, stop_requested, tracking_core

if TYPE_CHECKING:
    from semslam.viz.rerun_log import RerunRecorder

T = TypeVar("T")


def prefetch(items: Iterator[T], depth: int = 2) -> Generator[T, None, None]:
    """Decode the next frames in a background thread (OpenCV releases the GIL), at
    ``runtime.BACKGROUND_NICE``: ahead of tracking by ``depth`` frames, it need not take a
    core from the frame being tracked."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="reader", initializer=lower_thread_priority) as pool:
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
    """Track every frame of ``sequence``, write outputs, evaluate against ground truth: a loop
    over ``api.System`` (the Python API), whose ``track_frame`` takes each frame and whose
    ``save`` writes the outputs.

    Whatever happens (a failed worker thread, an exception while tracking), the trajectory
    so far, ``keyframes.txt`` and ``stats.json`` (with ``error``) are written before the
    exception propagates; every thread and process the run started is stopped. A stop asked
    for (``runtime.request_stop``: Ctrl-C or SIGTERM under ``runtime.StopOnSignals``) ends
    tracking after the current frame; the outputs are written as usual (``"interrupted":
    true``, and ``--save-map``'s map) except the maps of ``maps.builders``, whose final
    integration takes seconds (``semslam map OUT`` builds them from the keyframes); then
    ``RunInterrupted`` is raised (its ``exit_code``: 128 + the signal's number).

    Every output path is checked first (``check_output_paths``): one that cannot be written
    is an ``OutputError`` before the first frame, not a lost run at the end.

    ``rerun`` (an ``.rrd`` path) / ``rerun_spawn`` record the run for the Rerun viewer
    (``viz.rerun_log``); the recording is closed, complete, on every path too.
    """
    out = Path(out_dir)
    check_output_paths(out, save_map=save_map, rerun=rerun, save_inpainted=config.maps.save_inpainted or None)
    config = config_for_sequence(config, sequence)
    if config.sensor == "rgbd" and not sequence.has_depth:
        raise DataError(sequence.root, "no depth images: this is a monocular sequence; run it with sensor: mono "
                                       "(--preset sdf)")
    # Entered before the system starts its threads and processes, which then move to the
    # other CPUs (runtime.lower_thread_priority); this thread tracks. Not where tracking
    # waits for every frame's mask (semantics.schedule: every, `ddl` and `stdc`): its CPU
    # would idle while the semantic thread shares the other with local mapping, whose map
    # lock slices then got preempted (`ddl` on walking_xyz: median 49-51 -> 44-49 ms, but
    # lock-wait p95 0.02-3.0 -> 2.2-6.4 ms).
    waits_for_masks = config.dynamics.semantic and config.semantics.schedule == "every"
    with tracking_core(config.slam.pin_tracking and not waits_for_masks):
        camera = stereo_calibration(sequence) if config.sensor == "stereo" else sequence.camera
        imu = sequence.imu.calibration if sequence.imu is not None else None
        system = System(config, camera, load_map=load_map, name=str(sequence.root), imu=imu)
        return _run(system, sequence, config, out, max_frames, progress, report, save_map, rerun, rerun_spawn)


def stereo_calibration(sequence: Sequence) -> StereoCalibration | None:
    """The calibration of a stereo sequence (its frames carry ``right``), else None."""
    calibration = getattr(sequence, "calibration", None)
    return calibration if isinstance(calibration, StereoCalibration) else None


def config_for_sequence(config: SystemConfig, sequence: Sequence) -> SystemConfig:
    """The sensor follows the input: a stereo sequence runs an RGB-D preset as stereo (the
    System takes the pair's ``bf`` from its calibration), a monocular preset on its left
    images; ``sensor: stereo`` on a sequence without right images is a ``DataError``."""
    calibration = stereo_calibration(sequence)
    if config.sensor == "stereo" and calibration is None:
        raise DataError(sequence.root, "sensor: stereo, but this sequence has no right images (expected EuRoC's "
                                       "mav0/cam0 + cam1, KITTI's image_0 + image_1, or rgb_right.txt)")
    if calibration is None or config.sensor == "mono" or (config.sensor == "rgbd" and sequence.has_depth):
        return config
    return make_config(config, ["sensor=stereo"])


def _run(system: System, sequence: Sequence, config: SystemConfig, out: Path, max_frames: int | None,
         progress: bool, report: bool, save_map: str | Path | None, rerun: str | Path | None,
         rerun_spawn: bool) -> RunResult:
    """``run_slam``'s body, once the system is made."""
    if save_map and not system.has_map:  # before any frame, not after the whole run
        system.close()
        raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
    recorder = _open_recorder(rerun, rerun_spawn, system)
    out.mkdir(parents=True, exist_ok=True)  # an unusable output folder fails now, not after the run
    n_total = len(sequence) if max_frames is None else min(max_frames, len(sequence))
    error: BaseException | None = None
    interrupted = False
    try:
        interrupted = _track_all(system, sequence, config, n_total, progress, recorder)
    except BaseException as exc:
        error = exc
    try:
        try:  # raises the run's error once the outputs are written
            result = system.save(out, groundtruth=sequence.groundtruth_path, report=report, save_map=save_map,
                                 error=error, interrupted=interrupted,
                                 skipped=[msg for _, msg in sequence.skipped], total=n_total)
        finally:
            if recorder is not None and system.result is not None:
                _log_run_end(recorder, system, out / "map")
    finally:
        if recorder is not None:
            recorder.close()
    if interrupted:
        maps = " (maps not written: `semslam map OUT` builds them)" if config.maps.builders else ""
        raise RunInterrupted(f"stopped after {system.n_frames} of {n_total} frames; outputs in {out}{maps}",
                             exit_code=stop_exit_code())
    return result


# ---------------------------------------------------------------------------- output paths
#: What a run writes into its output folder (``semslam run -o``), and what ``--overwrite``
#: removes from one: these names, and Rerun recordings (``*.rrd``). Nothing else is touched.
RUN_OUTPUTS = ("trajectory.txt", "keyframes.txt", "stats.json", "config.json", "report.html", "map")
RUN_OUTPUT_PATTERNS = ("*.rrd",)


def check_output_paths(out: Path, save_map: str | Path | None = None, rerun: str | Path | None = None,
                       save_inpainted: str | Path | None = None) -> None:
    """``OutputError`` naming the first output path that cannot be written: a folder (``--out``,
    ``--save-inpainted``) or a file (``--save-map``, ``--rerun``) that exists as the other kind,
    sits under a regular file, or whose nearest existing folder is not writable."""
    _check_path(Path(out), "--out", folder=True)
    if save_inpainted:
        _check_path(Path(save_inpainted), "--save-inpainted", folder=True)
    if save_map:
        _check_path(Path(save_map), "--save-map", folder=False)
    if rerun:
        _check_path(Path(rerun), "--rerun", folder=False)


def _check_path(path: Path, option: str, folder: bool) -> None:
    if path.exists():
        if folder and not path.is_dir():
            raise OutputError(path, f"{option}: exists and is not a folder")
        if not folder and path.is_dir():
            raise OutputError(path, f"{option}: is a folder; give a file name")
        if not os.access(path, os.W_OK):
            raise OutputError(path, f"{option}: not writable (permission denied)")
        return
    parent = path.parent
    while not parent.exists() and parent != parent.parent:  # under a regular file, exists() is False
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(path, f"{option}: cannot be created: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(path, f"{option}: cannot be created: no permission to write in {parent}")


def previous_run_outputs(out: Path) -> list[Path]:
    """The files and folders of an earlier run in ``out`` (``RUN_OUTPUTS``, ``*.rrd``)."""
    if not out.is_dir():
        return []
    found = [out / name for name in RUN_OUTPUTS if (out / name).exists() or (out / name).is_symlink()]
    for pattern in RUN_OUTPUT_PATTERNS:
        found += sorted(p for p in out.glob(pattern) if p not in found)
    return found


def remove_previous_run(out: Path, keep: Iterable[str | Path | None] = ()) -> list[Path]:
    """Remove an earlier run's outputs from ``out`` (``previous_run_outputs``; other files
    stay); ``OutputError`` first if one of them holds a path in ``keep`` (an input of the
    new run, e.g. ``--load-map``). Returns what was removed."""
    found = previous_run_outputs(out)
    for path in (Path(k).absolute() for k in keep if k):
        for old in found:
            if path == old.absolute() or old.absolute() in path.parents:
                raise OutputError(old, f"--overwrite would delete {path}, which this run reads; "
                                       "move it out of the output folder first")
    for old in found:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old)
        else:
            old.unlink()
    return found


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


def _log_frame(recorder: "RerunRecorder", frame: Frame, result: TrackResult, system: System) -> None:
    recorder.log_frame(frame.index, frame.timestamp, frame.rgb, result.dynamic, result.keypoints_xy,
                       result.keypoint_static, result.pose_wc, system.camera)


def _log_run_end(recorder: "RerunRecorder", system: System, map_dir: Path) -> None:
    """The final trajectory, the map points and the semantic cloud (if the maps wrote one)."""
    recorder.log_trajectory(system.trajectory().positions)
    points = system.map_points()
    if len(points):
        recorder.log_map_points(points)
    recorder.log_map_dir(map_dir)


def _track_all(system: System, sequence: Sequence, config: SystemConfig, n_total: int, progress: bool,
               recorder: "RerunRecorder | None" = None) -> bool:
    """Feed the frames to ``system``; returns whether a stop was asked for before the last."""
    # The reader thread hands each decoded frame to the system at once (segmentation starts),
    # at the camera's rate with slam.realtime.
    realtime = config.slam.realtime
    packets = prefetch((system.prepare(f), t) for f, t in at_camera_rate(sequence.frames(0, n_total), realtime))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_total, unit="frame", desc=f"semslam {config.preset}", dynamic_ncols=True, leave=True)
    try:
        for packet, t_arrived in packets:
            if stop_requested():
                return True
            result = system.track_frame(packet, t_arrived if realtime else None)
            if recorder is not None:
                _log_frame(recorder, packet.frame, result, system)
            if bar is not None:  # skipped frames count too: the bar ends at the sequence's total
                bar.update(max(1, packet.frame.index + 1 - bar.n))
                bar.set_postfix(state=result.state.value, inl=result.n_inliers, kf=system.n_keyframes, refresh=False)
        if bar is not None:
            bar.update(max(0, n_total - bar.n))  # the last frames skipped
    finally:
        packets.close()
        if bar is not None:
            bar.close()
    return False
