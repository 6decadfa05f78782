"""The System: one object that takes frame packets and keeps the results.

It builds the dynamic stage and the tracker named by ``tracking.method`` through the
registry, and calls only what ``core.protocols`` promises. Which tracker runs behind it is
configuration; adding one is a module with a ``create_tracker`` factory plus a registry line.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.frontend.sharpness import sharpness
from semslam.config import SystemConfig
from semslam.core import registry
from semslam.core.protocols import DepthSource, FramePacket, MapBuilder, Tracker, TrackerInputs
from semslam.core.types import Frame, TrackingState, TrackResult
from semslam.dynamics.stage import create_dynamic_stage
from semslam.errors import ConfigError
from semslam.features.jit import warm_up as warm_up_kernels
from semslam.geometry.camera import PinholeCamera
from semslam.io.input_health import InputHealth
from semslam.core.trajectory import Trajectory


class System:
    """Runs one tracker over frames and records every result; owns what it builds."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera, map_path: Path | None = None) -> None:
        create_tracker = registry.load("tracker", config.tracking.method)
        # Compiled kernels are built (or loaded from disk) now, not inside the first frames.
        self.jit_warmup_s = warm_up_kernels(("semslam.dynamics.multiview_kernels", "semslam.slam.row_kernels"))
        self.config = config
        self.camera = camera
        depth: DepthSource = registry.create("depth_source", config.depth.source, config.depth.resolved(config.semantics))
        builders: list[MapBuilder] = []
        if config.maps.builders:  # inpainting + every builder in the maps' own worker
            from semslam.reconstruction.mapping_worker import MappingWorker

            # The worker segments keyframes tracking did not (a backend that reads its labels
            # from the sequence, ground_truth, needs the frame's files: not from a snapshot).
            segment = (config.maps.segment_keyframes and config.dynamics.semantic
                       and config.semantics.backend != "ground_truth")
            builders.append(MappingWorker(config.maps.builders, config.maps, threaded=not config.slam.sequential,
                                          inpainted_dir=Path(config.maps.save_inpainted)
                                          if config.maps.save_inpainted else None,
                                          semantics=config.semantics if segment else None))
        self.dynamics = create_dynamic_stage(config.dynamics, config.semantics, camera,
                                             threaded=not config.slam.sequential)
        self.inputs = TrackerInputs(depth, self.dynamics, builders)
        try:
            self.tracker: Tracker = create_tracker(config, camera, self.inputs, map_path)
        except BaseException:
            self._close_parts()
            raise
        # Frames per tracking state, not the TrackResults: a 20-minute run would keep 36 000 of
        # them (~1.5 kB each with pose and timings) only to count them at the end.
        self.states: Counter[TrackingState] = Counter()
        self.input_health = InputHealth()  # why frames could not be tracked (blank, no depth, all dynamic)

    @property
    def has_map(self) -> bool:
        return self.tracker.has_map

    def prepare(self, frame: FramePacket | Frame) -> FramePacket:
        """Start per-frame work that can run ahead of tracking (segmentation), from the reader
        (a bare ``Frame`` is wrapped in a packet, which ``track`` then takes)."""
        packet = frame if isinstance(frame, FramePacket) else FramePacket(frame)
        if self.dynamics is not None:
            self.dynamics.prepare(packet)
        # Work that depends on the image alone runs here too, off the tracking thread: the grey
        # conversion (cached on the frame) and, where tracking compares frames' sharpness, that.
        gray = packet.frame.gray
        slam = self.config.slam
        if packet.sharpness is None and (slam.blur_coast_sharp_ratio > 0 or slam.depth_odometry_sharp_ratio > 0):
            packet.sharpness = sharpness(gray)
        return packet

    def track(self, frame: FramePacket | Frame) -> TrackResult:
        """Track one frame (a bare ``Frame`` from user code is wrapped in a packet)."""
        packet = frame if isinstance(frame, FramePacket) else FramePacket(frame)
        result = self.tracker.track(packet)
        self.states[result.state] += 1
        self.input_health.observe(packet, result)
        return result

    @property
    def n_keyframes(self) -> int:
        return self.tracker.n_keyframes

    def trajectory(self) -> Trajectory:
        """Poses of every frame that has one (lost frames are left out), after the final optimisation."""
        return self.tracker.trajectory()

    def keyframe_trajectory(self) -> Trajectory:
        return self.tracker.keyframe_trajectory()

    def map_points(self) -> NDArray[np.float64]:
        """World positions (N, 3) of the tracker's map points ((0, 3) without a map)."""
        return self.tracker.map_points()

    @property
    def n_frames(self) -> int:
        """Frames tracked so far (whatever their state)."""
        return sum(self.states.values())

    def counts(self) -> dict[str, int]:
        return {
            "frames": self.n_frames,
            "tracked_frames": self.states[TrackingState.OK],
            "lost_frames": self.states[TrackingState.LOST],
            "uninitialized_frames": self.states[TrackingState.NOT_INITIALIZED],
            "keyframes": self.n_keyframes,
        }

    def stats(self) -> dict[str, Any]:
        """The tracker's, the dynamic stage's and (once written) the maps' counters."""
        maps: dict[str, Any] = {}
        for builder in self.inputs.map_builders:
            maps.update(getattr(builder, "stats", dict)())
        return {**self.tracker.stats(), **(self.dynamics.stats() if self.dynamics is not None else {}), **maps,
                **self.input_health.stats(), "jit_warmup_s": self.jit_warmup_s}

    def save_map(self, path: Path) -> None:
        if not self.has_map:
            raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
        self.tracker.save_map(path)

    def shutdown(self) -> None:
        """Stop the tracker's threads and processes (map builders get the final keyframe
        poses), then the dynamic stage; safe to call twice."""
        try:
            self.tracker.shutdown()
        finally:
            if self.dynamics is not None:
                self.dynamics.close()

    def write_maps(self, out_dir: Path) -> dict[str, Path]:
        """Each map builder writes its files under ``out_dir``, then is closed."""
        paths: dict[str, Path] = {}
        try:
            for builder in self.inputs.map_builders:
                paths.update(builder.finish(out_dir))
        finally:
            self._close_parts()
        return paths

    def close(self) -> None:
        """Stop and free everything without writing maps (a run that never started)."""
        try:
            self.shutdown()
        finally:
            self._close_parts()

    def _close_parts(self) -> None:
        for builder in self.inputs.map_builders:
            builder.close()
        if self.dynamics is not None:
            self.dynamics.close()
