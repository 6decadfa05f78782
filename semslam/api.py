"""``semslam.System``: SLAM fed frame by frame from user code, the way ``semslam run`` feeds it.

A live camera (OpenCV, a vendor SDK) gives numpy images one at a time; ``track`` takes
them, ``trajectory()`` / ``keyframes()`` / ``map_points()`` / ``stats()`` answer at any
time, and ``save`` writes what ``semslam run`` writes (``trajectory.txt``,
``keyframes.txt``, ``stats.json``, ``config.json``, the maps, ``report.html`` with ground
truth). ``pipeline.run_slam`` is a loop over this class: one code path for both.

It is the one System of a run: it builds the parts (``semslam.assembly``: depth source,
dynamic stage, maps' worker, tracker), runs each frame through them in order and alone
feeds the map builders, from the keyframes and pose corrections the tracker's results
announce and the final keyframe poses at the end.

    import cv2
    from semslam import System

    with System("default", camera=(535.4, 539.2, 320.1, 247.6), bgr=True, out="run1") as slam:
        for bgr, depth_u16, t in frames:          # depth: uint16, 5000 units per metre (TUM)
            result = slam.track(bgr, depth_u16, t)
            if result.pose_wc is not None:        # 4x4 camera-to-world, None while lost
                ...
    # leaving the block stops every thread and process and writes run1/

A script needs no ``if __name__ == "__main__":`` guard: the worker processes are spawned
without re-running it (``semslam/worker_processes.py``).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Union

import numpy as np
from numpy.typing import NDArray

from semslam.assembly import RunParts, assemble
from semslam.config import SystemConfig, config_from_dict, config_to_dict, load_config
from semslam.core.imu import ImuCalibration
from semslam.core.protocols import DynamicStage, FramePacket, KeyframeSnapshot, MapStage, Tracker
from semslam.core.trajectory import Trajectory
from semslam.core.types import Frame, RunResult, TrackingState, TrackResult
from semslam.errors import ConfigError, DataError, SemslamError
from semslam.frame_input import as_imu_samples, as_metres, as_rgb, check_timestamp
from semslam.frontend.sharpness import sharpness
from semslam.frontend.stereo_depth import fill_frame_depth
from semslam.geometry.camera import PinholeCamera
from semslam.io.calibration import camera_from_values, read_calib_file, resolve_camera
from semslam.io.input_health import InputHealth
from semslam.io.stereo_calibration import StereoCalibration, read_orbslam3_settings, stereo_from_values
from semslam.io.trajectory import write_tum
from semslam.run_record import Evaluation, RunTiming, evaluate, timing_stats, write_run_report
from semslam.thread_clock import thread_times

log = logging.getLogger(__name__)

#: A camera as the API takes it: intrinsics (fx, fy, cx, cy[, k1, k2, p1, p2, k3]), a
#: ``PinholeCamera``, a ``calib.txt`` file or a sequence folder (its calib.txt / dataset name).
CameraLike = Union[PinholeCamera, Sequence[float], str, Path]


class System:
    """One SLAM run fed frame by frame; owns the threads and processes it starts.

    ``preset``: a preset name (``semslam run --preset``), a YAML file or a ``SystemConfig``.
    ``overrides``: ``--set`` overrides as a mapping (``{"slam.loop_closing": False}``) or as
    ``"section.key=value"`` strings. ``sensor``: ``"rgbd"`` or ``"mono"``; None keeps the
    preset's (``default``, ``orb``: rgbd; ``sdf``: mono). ``depth_scale``: uint16 depth units
    per metre (TUM 5000, millimetres 1000); None keeps the preset's (5000).
    ``bgr``: colour images come in OpenCV's BGR order (``cv2.imread``, ``VideoCapture``);
    the default is RGB. ``image_size``: (width, height); without it (and without a
    ``PinholeCamera`` that has one) the SLAM system is built at the first frame, from its
    size. ``out``: where ``close()`` (and leaving a ``with`` block) writes the outputs; None
    writes nothing unless ``save`` is called. ``load_map``: start from a map saved with
    ``save(save_map=...)`` (relocalise in it). ``name``: what ``stats.json`` calls the sequence.
    """

    def __init__(self, preset: str | Path | SystemConfig = "default", camera: CameraLike | None = None, *,
                 sensor: str | None = None, overrides: Mapping[str, Any] | Sequence[str] | None = None,
                 depth_scale: float | None = None, bgr: bool = False, image_size: tuple[int, int] | None = None,
                 out: str | Path | None = None, load_map: str | Path | None = None, name: str = "live",
                 baseline: float | None = None, imu: ImuCalibration | None = None) -> None:
        if isinstance(camera, StereoCalibration) and sensor is None:
            sensor = "stereo"
        self.config = make_config(preset, overrides, sensor, depth_scale)
        # A stereo pair: its rectification (None when the images come rectified) and bf.
        self._stereo: StereoCalibration | None = None
        if self.config.sensor == "stereo":
            self._stereo = make_stereo_calibration(camera, baseline)
            self.config = make_config(self.config, [f"slam.bf={self._stereo.bf!r}"])
            camera = self._stereo.camera
        elif baseline is not None:
            raise ConfigError(f"baseline is for sensor='stereo'; this system's sensor is {self.config.sensor!r}")
        cam = make_camera(camera)
        self.camera = cam.with_image_size(*image_size) if image_size is not None else cam
        self.bgr = bool(bgr)
        self.out = Path(out) if out is not None else None
        self.name = name
        self._load_map = Path(load_map) if load_map is not None else None
        self.imu = imu
        self._parts: RunParts | None = None
        self._start_lock = threading.Lock()
        # Frames per tracking state, not the TrackResults: a 20-minute run would keep 36 000 of
        # them (~1.5 kB each with pose and timings) only to count them at the end.
        self._states: Counter[TrackingState] = Counter()
        self._input_health = InputHealth()  # why frames could not be tracked (blank, no depth, all dynamic)
        self._stopped = False  # the tracker shut down, the maps told the final poses
        self._timing = RunTiming()
        self._last_t = -np.inf
        self._last_imu_t = -np.inf
        self._n_given = 0
        self._closed = False
        self._warned_mono_depth = False
        #: What ``save`` wrote (None before); ``stats.json`` as a value.
        self.result: RunResult | None = None
        if self.camera.width > 0:  # the size is known: build now (a bad config fails here, not at frame 1)
            self._start()

    # ------------------------------------------------------------------ lifetime
    def _start(self) -> RunParts:
        """The run's parts, built on first use (``pipeline.run_slam``'s reader thread may be first)."""
        with self._start_lock:
            if self._parts is None:
                self._parts = assemble(self.config, self.camera, self._load_map, self.imu)
            return self._parts

    @property
    def tracker(self) -> Tracker:
        """The tracker of ``tracking.method`` (for tools and tests that look inside)."""
        return self._start().tracker

    @property
    def dynamics(self) -> DynamicStage | None:
        """The dynamic stage (None with dynamics handling off)."""
        return self._start().dynamics

    def __enter__(self) -> System:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """Outputs to ``out`` (with the exception that ended the block in ``stats.json``;
        after Ctrl-C without the maps, which take seconds), then everything stopped."""
        if self.out is None or self.result is not None or self._closed:
            self.close()
            return
        stopped = isinstance(exc, KeyboardInterrupt)
        try:
            self.save(self.out, error=None if stopped else exc, interrupted=stopped)
        except BaseException as failure:  # the block's own exception propagates as it is
            if failure is not exc:
                raise

    def close(self) -> None:
        """Stop every thread and process of the run (local mapping, loop closing, the BA worker,
        the semantic thread, the maps' worker); with ``out``, write the outputs there first.
        Safe to call twice; ``trajectory()`` and the others still answer afterwards."""
        if self._closed or self.result is not None:
            self._closed = True
            return
        if self.out is not None:
            self.save(self.out)
            return
        self._closed = True
        if self._parts is not None:
            self._close_run(self._parts)

    @property
    def closed(self) -> bool:
        return self._closed or self.result is not None

    # ------------------------------------------------------------------ frames
    def track(self, rgb: NDArray[np.uint8], depth: NDArray[Any] | None, timestamp: float, *,
              bgr: bool | None = None, imu: Sequence[tuple[float, Any, Any]] | None = None) -> TrackResult:
        """Track one frame: ``rgb`` HxWx3 uint8 (RGB, or BGR with ``bgr``; HxW grey is
        accepted), ``depth`` HxW uint16 (``depth_scale`` units per metre) or float (metres,
        0 / NaN = no measurement) or None for monocular presets, ``timestamp`` in seconds,
        increasing. A stereo system takes ``track(left, right, timestamp)``: the right image
        in the left's form, in place of the depth (rectified here when the calibration says
        the pair is not). ``imu``: with ``System(..., imu=ImuCalibration)``, the readings since
        the frame before as ``(t, gyro xyz rad/s, acc xyz m/s^2)`` in the IMU frame, times
        increasing and not past ``timestamp``. Returns the ``TrackResult``: ``pose_wc`` (4x4
        camera-to-world, None while not initialised or lost), ``state``, inlier counts,
        per-stage timings."""
        where = f"System.track (frame {self._n_given}, t={timestamp})"
        if self.closed:
            raise SemslamError(f"{where}: the system is closed (save() or close() ended the run)")
        t = check_timestamp(timestamp, self._last_t, where)
        as_bgr = self.bgr if bgr is None else bgr
        image = as_rgb(rgb, as_bgr, where)
        metres, right = None, None
        if self._stereo is not None:
            if depth is None:
                raise DataError(where, "no right image: a stereo system takes track(left, right, timestamp)")
            right = as_rgb(depth, as_bgr, where.replace("System.track", "System.track, right image"))
            if right.shape != image.shape:
                raise DataError(where, f"right image is {right.shape[1]}x{right.shape[0]} but the left one is "
                                       f"{image.shape[1]}x{image.shape[0]}")
            image, right = self._stereo.rectify(image, right)
        else:
            metres = self._as_depth(depth, image.shape[:2], where)
        if self.camera.width > 0 and (self.camera.width, self.camera.height) != (image.shape[1], image.shape[0]):
            raise DataError(where, f"image is {image.shape[1]}x{image.shape[0]} but the camera is "
                                   f"{self.camera.width}x{self.camera.height}")
        if self._parts is None:
            self.camera = self.camera.with_image_size(image.shape[1], image.shape[0])
        readings = None
        if imu is not None:
            if self.imu is None:
                raise ConfigError(f"{where}: IMU readings given, but the System has no IMU calibration "
                                  "(System(..., imu=ImuCalibration(noise, T_bc)))")
            readings = as_imu_samples(imu, self._last_imu_t, t, where)
            if len(readings):
                self._last_imu_t = float(readings.t[-1])
        self._last_t = t
        frame = Frame(self._n_given, t, image, metres, right=right, imu=readings)
        self._n_given += 1
        return self.track_frame(self.prepare(frame))

    def _as_depth(self, depth: NDArray[Any] | None, shape: tuple[int, ...], where: str) -> NDArray[np.float32] | None:
        if self.config.sensor == "mono":  # as `semslam run` reads a TUM folder for a mono preset
            if depth is not None and not self._warned_mono_depth:
                log.warning("sensor mono (preset %s): the depth images given are not used", self.config.preset)
                self._warned_mono_depth = True
            return None
        if depth is None:
            raise DataError(where, f"no depth: preset {self.config.preset!r} is RGB-D (sensor rgbd); give depth, "
                                   "or use a monocular preset (sensor='mono', preset 'sdf')")
        return as_metres(depth, self.config.depth_scale, shape, where)

    def prepare(self, frame: Frame) -> FramePacket:
        """Start the work that can run ahead of tracking (segmentation) on a decoded frame;
        ``pipeline.run_slam`` calls it from its reader thread."""
        parts = self._start()
        if parts.stereo_depth is not None:  # a stereo pair's depth image, before segmentation (SRM reads it)
            fill_frame_depth(frame, parts.stereo_depth)
        if parts.dynamics is not None:
            parts.dynamics.prepare(frame)
        parts.tracker.prepare(frame)  # a stereo pair's right image features
        # Work that depends on the image alone runs here too, off the tracking thread: the grey
        # conversion (cached on the frame) and, where tracking compares frames' sharpness, that.
        gray = frame.gray
        slam = self.config.slam
        wanted = slam.blur_coast_sharp_ratio > 0 or slam.depth_odometry_sharp_ratio > 0
        return FramePacket(frame, sharpness(gray) if wanted else None)

    def track_frame(self, packet: FramePacket, arrived: float | None = None) -> TrackResult:
        """Track a prepared frame and record its timings (``track`` after its checks, and
        ``pipeline.run_slam`` for each frame it reads). ``arrived``: when the frame came in
        (``time.perf_counter``), for the latency of camera-rate runs."""
        if self.closed:
            raise SemslamError("System.track_frame: the system is closed (save() or close() ended the run)")
        parts = self._start()
        cpu0, runq0 = thread_times()  # where the frame's time goes: CPU / run queue / asleep
        t0 = time.perf_counter()
        result = self._track(parts, packet)
        done = time.perf_counter()
        cpu1, runq1 = thread_times()
        self._timing.add(t0, done, result, arrived, cpu1 - cpu0,
                         None if runq0 is None or runq1 is None else runq1 - runq0)
        return result

    def _track(self, parts: RunParts, packet: FramePacket) -> TrackResult:
        """The tracker's result for the packet, fed to the maps and counted."""
        result = parts.tracker.track(packet)
        if parts.maps is not None:
            self._feed_maps(parts, parts.maps, packet.frame, result)
        self._states[result.state] += 1
        self._input_health.observe(packet.frame, result)
        return result

    def _feed_maps(self, parts: RunParts, maps: MapStage, frame: Frame, result: TrackResult) -> None:
        """The keyframe the result announces (or, when the maps want every frame, the tracked
        frame), then the keyframe poses it corrected."""
        event = result.keyframe
        if event is not None:
            maps.add_keyframe(self._snapshot(parts, frame, result, event.id, event.timestamp, event.T_wc, event.depth))
        elif maps.wants_frames and result.pose_wc is not None:
            maps.add_frame(self._snapshot(parts, frame, result, -1, result.timestamp, result.pose_wc, None))
        if result.corrected_poses:
            maps.correct_poses(result.corrected_poses)

    def _snapshot(self, parts: RunParts, frame: Frame, result: TrackResult, kf_id: int, timestamp: float,
                  T_wc: NDArray[np.float64], depth: NDArray[np.float32] | None) -> KeyframeSnapshot:
        """A frame, its pose, its depth (the tracker's, else the depth source's), its final
        dynamic mask and its class labels, as the map builders take them."""
        labels = parts.dynamics.labels(frame.index) if parts.dynamics is not None else None
        return KeyframeSnapshot(kf_id, timestamp, T_wc, frame.rgb, depth if depth is not None else parts.depth.depth(frame),
                                result.dynamic, labels, self.camera)

    # ------------------------------------------------------------------ at any time
    @property
    def has_map(self) -> bool:
        """Whether the tracker keeps a map that ``save(save_map=...)`` can write (``orb_slam``)."""
        return self._start().tracker.has_map

    @property
    def n_frames(self) -> int:
        """Frames tracked so far."""
        return len(self._timing.frame_ms)

    @property
    def n_keyframes(self) -> int:
        return self._parts.tracker.n_keyframes if self._parts is not None else 0

    def trajectory(self) -> Trajectory:
        """Camera-to-world poses of every frame tracked so far that has one (lost frames are
        left out); after ``save``, the poses after the final optimisation."""
        return self._parts.tracker.trajectory() if self._parts is not None else Trajectory.from_poses([])

    def save_trajectory(self, path: str | Path) -> None:
        """``trajectory()`` as a TUM file (``timestamp tx ty tz qx qy qz qw``; evo reads it)."""
        write_tum(path, self.trajectory())

    def keyframes(self) -> Trajectory:
        """Camera-to-world poses of the keyframes."""
        return self._parts.tracker.keyframe_trajectory() if self._parts is not None else Trajectory.from_poses([])

    def map_points(self) -> NDArray[np.float64]:
        """World positions (N, 3) of the sparse map's points now ((0, 3) for a tracker without a
        map). They carry no colour or class; the coloured, labelled maps (``maps.builders``:
        semantic cloud, octree, mesh) are built from the keyframes and written by ``save``."""
        return self._parts.tracker.map_points() if self._parts is not None else np.zeros((0, 3))

    def stats(self) -> dict[str, Any]:
        """What ``stats.json`` holds so far (counts, ms/frame, per-stage times, the tracker's
        counters); ATE/RPE and paths come with ``save`` (they need the end of the run)."""
        if self.result is not None:
            return self.result.to_dict()
        out = self.out if self.out is not None else Path(".")
        return self._run_result(out, {}, (), None).to_dict()

    # ------------------------------------------------------------------ the end
    def save(self, out_dir: str | Path | None = None, *, groundtruth: str | Path | None = None, report: bool = True,
             save_map: str | Path | None = None, error: BaseException | None = None, interrupted: bool = False,
             skipped: Sequence[str] = (), total: int | None = None) -> RunResult:
        """End the run and write what ``semslam run`` writes to ``out_dir`` (default ``out``):
        ``trajectory.txt`` (poses after the final optimisation), ``keyframes.txt``,
        ``stats.json``, ``config.json``, the maps of ``maps.builders`` under ``map/``; with
        ``groundtruth`` (a TUM file) ATE/RPE in ``stats.json`` and ``report.html``;
        ``save_map`` writes the sparse map (.npz) for ``load_map``. Every thread and process
        is stopped first. Returns the ``RunResult`` (``stats.json`` as a value).

        The trajectory, keyframes and ``stats.json`` are written first: a failure in what
        follows (the map file, the maps, the report) is recorded in ``stats.json`` and raised
        (an ``OSError`` as a ``DataError`` naming the path), the run's record stays on disk.

        For drivers such as ``pipeline.run_slam``: ``error`` (what ended the feeding) goes into
        ``stats.json`` and is raised once the outputs are written; ``interrupted`` (Ctrl-C)
        marks the run so and skips the maps (``semslam map OUT`` builds them later);
        ``skipped`` lists frames the reader could not use; ``total``: the frames the run was
        given (``frames_total`` in ``stats.json``; default: those tracked and skipped)."""
        target = out_dir if out_dir is not None else self.out
        if target is None:
            raise ConfigError("System.save: no output folder (give out_dir, or out= to System)")
        if self.closed:
            raise SemslamError(f"System.save: the run has ended already ({self._ended_how()})")
        out = Path(target)
        out.mkdir(parents=True, exist_ok=True)
        parts = self._start()
        try:
            self._shutdown(parts)  # the final optimisation; worker threads and the BA process stop
        except BaseException as exc:  # a worker that failed on the last keyframes
            error = error or exc
        failure = self._write_outputs(parts, out, groundtruth, report, save_map, error, interrupted, skipped, total)
        error = error or failure
        if error is not None:
            raise error
        assert self.result is not None
        return self.result

    def _ended_how(self) -> str:
        return f"saved to {self.result.out_dir}" if self.result is not None else "closed"

    def _shutdown(self, parts: RunParts) -> None:
        """Stop the tracker's threads and processes (its final optimisation first), tell the
        maps the final keyframe poses, stop the dynamic stage; once."""
        if self._stopped:
            return
        self._stopped = True
        try:
            try:
                parts.tracker.shutdown()
            finally:  # a worker that failed does not keep the maps from the final poses
                if parts.maps is not None:
                    parts.maps.correct_poses(parts.tracker.final_keyframe_poses())
        finally:
            if parts.dynamics is not None:
                parts.dynamics.close()

    def _close_run(self, parts: RunParts) -> None:
        """Stop and free everything without writing maps."""
        try:
            self._shutdown(parts)
        finally:
            self._close_parts(parts)

    @staticmethod
    def _close_parts(parts: RunParts) -> None:
        if parts.maps is not None:
            parts.maps.close()
        if parts.dynamics is not None:  # the stage's stats stay readable once closed
            parts.dynamics.close()

    @staticmethod
    def _write_maps(parts: RunParts, out_dir: Path) -> dict[str, Path]:
        """The maps' files under ``out_dir``; then every part is closed."""
        try:
            return parts.maps.finish(out_dir) if parts.maps is not None else {}
        finally:
            System._close_parts(parts)

    @staticmethod
    def _save_map(parts: RunParts, path: Path) -> None:
        if not parts.tracker.has_map:
            raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
        parts.tracker.save_map(path)

    def _write_outputs(self, parts: RunParts, out: Path, groundtruth: str | Path | None, report: bool,
                       save_map: str | Path | None, error: BaseException | None, interrupted: bool,
                       skipped: Sequence[str], total: int | None) -> BaseException | None:
        """The run's record first (trajectory, keyframes, ``stats.json``, ``config.json``), then
        what may fail or take long (the map file, the maps, the report), then ``stats.json``
        again with their paths and counters; returns the first failure of those."""
        traj = parts.tracker.trajectory()
        write_tum(out / "trajectory.txt", traj)
        paths = {"trajectory": str(out / "trajectory.txt"), "stats": str(out / "stats.json"),
                 "config": str(out / "config.json")}
        kf_traj = parts.tracker.keyframe_trajectory()
        if len(kf_traj):
            write_tum(out / "keyframes.txt", kf_traj)
            paths["keyframes"] = str(out / "keyframes.txt")
        self._timing.interrupted = interrupted
        result = self._run_result(out, paths, skipped, error, total)
        evaluation = evaluate(Path(groundtruth), traj, self.config, result) if groundtruth is not None and \
            len(traj) >= 3 else None
        (out / "config.json").write_text(json.dumps(config_to_dict(self.config), indent=2))
        (out / "stats.json").write_text(json.dumps(result.to_dict(), indent=2))
        self.result = result
        # Interrupted: no report (its plots take a second or more) and no maps (`semslam map OUT`).
        failure = self._write_extras(parts, out, result, save_map if error is None else None,
                                     evaluation if report and not interrupted else None, interrupted)
        result.set_counters(self._tracker_stats(parts))  # now with the maps' counters
        if failure is not None:
            result.error = result.error or f"{type(failure).__name__}: {failure}"
        (out / "stats.json").write_text(json.dumps(result.to_dict(), indent=2))
        return failure

    def _write_extras(self, parts: RunParts, out: Path, result: RunResult, save_map: str | Path | None,
                      evaluation: Evaluation | None, interrupted: bool) -> BaseException | None:
        """The map file, the maps of ``maps.builders``, the report: each tried even when one
        before failed; the first failure is returned, not raised."""
        failures: list[BaseException] = []
        closed = False
        try:
            if save_map:
                _attempt(failures, Path(save_map), lambda: self._save_map(parts, Path(save_map)))
            if interrupted:  # stop fast: finishing the maps takes seconds
                self._close_run(parts)
            else:  # _write_maps closes the parts, also when a builder fails
                _attempt(failures, out / "map", lambda: result.paths.update(
                    {n: str(p) for n, p in self._write_maps(parts, out / "map").items()}))
            closed = True
            if evaluation is not None:
                _attempt(failures, out / "report.html",
                         lambda: write_run_report(out, evaluation, self.config, result))
        finally:
            if not closed:  # a KeyboardInterrupt while the map file was written
                self._close_run(parts)
        return failures[0] if failures else None

    def _counts(self) -> dict[str, int]:
        return {
            "frames": sum(self._states.values()),
            "tracked_frames": self._states[TrackingState.OK],
            "lost_frames": self._states[TrackingState.LOST],
            "uninitialized_frames": self._states[TrackingState.NOT_INITIALIZED],
            "keyframes": self.n_keyframes,
        }

    def _tracker_stats(self, parts: RunParts) -> dict[str, Any]:
        """The tracker's, the dynamic stage's and (once written) the maps' counters."""
        return {**parts.tracker.stats(), **(parts.dynamics.stats() if parts.dynamics is not None else {}),
                **(parts.maps.stats() if parts.maps is not None else {}), **self._input_health.stats(),
                "jit_warmup_s": parts.jit_warmup_s}

    def _run_result(self, out: Path, paths: dict[str, str], skipped: Sequence[str],
                    error: BaseException | None, total: int | None = None) -> RunResult:
        timing, cam = self._timing, self.camera
        n = len(timing.frame_ms)
        counts = self._counts() if self._parts is not None else {}
        given = counts.get("frames", 0) + len(skipped)
        result = RunResult(
            sequence=self.name, preset=self.config.preset, out_dir=out, **counts,
            skipped_frames=len(skipped), skipped=list(skipped),
            frames_total=max(given, total or 0), frames_not_reached=max(0, (total or 0) - given),
            ms_per_frame=timing_stats(timing.frame_ms),
            stages_ms_median={k: float(np.median(v)) for k, v in timing.stage_ms.items()},
            stages_ms_p95={k: float(np.percentile(v, 95)) for k, v in timing.stage_ms.items()},
            stages_ms_max={k: float(np.max(v)) for k, v in timing.stage_ms.items()},
            tracking_thread_ms=timing.thread_split(),
            realtime=self.config.slam.realtime, late_frames=timing.late_frames,
            latency_ms=timing_stats(timing.latency_ms) if timing.latency_ms else {},
            dynamic_ratio_mean=float(np.mean(timing.dynamic_ratio)) if timing.dynamic_ratio else 0.0,
            wall_s=timing.wall_s, fps=n / timing.wall_s if timing.wall_s > 0 else 0.0,
            tracking_fps=1000.0 / float(np.mean(timing.frame_ms)) if n else 0.0,
            camera={"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width,
                    "height": cam.height, "dist": list(cam.dist), "source": cam.source},
            paths=paths, interrupted=timing.interrupted or isinstance(error, KeyboardInterrupt),
            error=None if error is None else f"{type(error).__name__}: {error}",
        )
        if self._parts is not None:
            result.set_counters(self._tracker_stats(self._parts))
        return result


def _attempt(failures: list[BaseException], path: Path, write: Callable[[], object]) -> None:
    """``write()``; an exception goes into ``failures`` (an ``OSError`` as a ``DataError``
    naming ``path``: a full disk or a missing permission is the user's to fix)."""
    try:
        write()
    except OSError as exc:
        failures.append(DataError(exc.filename or path, f"cannot write ({exc.strerror or exc}); trajectory.txt "
                                                        "and stats.json were written"))
    except Exception as exc:  # noqa: BLE001 - recorded in stats.json, then raised by save
        failures.append(exc)


# ---------------------------------------------------------------------------- building it
def make_config(preset: str | Path | SystemConfig, overrides: Mapping[str, Any] | Sequence[str] | None = None,
                sensor: str | None = None, depth_scale: float | None = None) -> SystemConfig:
    """The config of a preset (name, YAML file or ``SystemConfig``) with overrides applied; a
    mapping's values go in as YAML (JSON is YAML), so ``{"maps.builders": []}`` works."""
    texts: list[str]
    if overrides is None:
        texts = []
    elif isinstance(overrides, Mapping):
        texts = [f"{key}={json.dumps(value, default=str)}" for key, value in overrides.items()]
    elif isinstance(overrides, str):
        raise ConfigError(f"overrides: give a mapping or a list of 'section.key=value' strings, not {overrides!r}")
    else:
        texts = [str(text) for text in overrides]
    if sensor is not None:
        texts.append(f"sensor={json.dumps(sensor)}")
    if depth_scale is not None:
        texts.append(f"depth_scale={float(depth_scale)}")
    if isinstance(preset, SystemConfig):  # a copy, checked as a preset is (a user may have set any field)
        return config_from_dict(config_to_dict(preset), "config", texts)
    return load_config(preset, texts)


def make_stereo_calibration(camera: CameraLike | StereoCalibration | None, baseline: float | None) -> StereoCalibration:
    """A stereo system's calibration: a ``StereoCalibration`` (``io.stereo_calibration``: EuRoC's
    sensor.yaml, KITTI's calib.txt, an ORB-SLAM3 settings file), an ORB-SLAM3 settings YAML
    path, or the left camera of a rectified pair plus ``baseline`` in metres."""
    if isinstance(camera, StereoCalibration):
        if baseline is not None:
            raise ConfigError("baseline: the StereoCalibration given as camera has its own")
        return camera
    if isinstance(camera, (str, Path)) and Path(camera).suffix.lower() in (".yaml", ".yml"):
        if baseline is not None:
            raise ConfigError(f"baseline: the settings file {camera} has its own")
        return read_orbslam3_settings(camera)
    if baseline is None:
        raise ConfigError("sensor='stereo' needs the pair's calibration: baseline=METRES with the left camera, "
                          "a StereoCalibration, or an ORB-SLAM3 settings YAML as camera")
    left = make_camera(camera)
    return stereo_from_values(left, baseline)


def make_camera(camera: CameraLike | None) -> PinholeCamera:
    """The intrinsics of ``camera``: a ``PinholeCamera``; 4 or 9 numbers (fx fy cx cy [k1 k2 p1
    p2 k3]); a ``calib.txt``; a sequence folder (its calib.txt or the dataset its name says)."""
    if camera is None:
        raise ConfigError("System: camera is required: (fx, fy, cx, cy), a PinholeCamera or a calib.txt path")
    if isinstance(camera, PinholeCamera):
        return camera
    if isinstance(camera, (str, Path)):
        path = Path(camera)
        if path.is_dir():
            return resolve_camera(path)
        if not path.is_file():
            raise DataError(path, "camera calibration file not found")
        return read_calib_file(path)
    try:
        values = [float(v) for v in camera]
    except (TypeError, ValueError):
        raise ConfigError(f"camera: expected (fx, fy, cx, cy[, k1, k2, p1, p2, k3]), got {camera!r}") from None
    return camera_from_values(values, "camera")
