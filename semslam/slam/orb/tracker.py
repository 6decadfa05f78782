"""The ORB-SLAM2-class RGB-D tracker's assembler: the one place that wires tracking, local
mapping and loop closing over one map (as ORB-SLAM3's System constructor does), behind the
``core.protocols.Tracker`` contract. It feeds no map builders: the keyframes it announces
in its results and their final poses are what the System feeds them from.

Tracking runs in the caller's thread; local mapping and loop closing run in their own
threads (or inline with ``slam.sequential``); one bundle-adjustment runner (a worker process
when threaded: GTSAM holds the GIL) is owned here and shared by both. Everything that can
fail to build is built before any thread or process starts, and ``shutdown`` stops and
closes everything on every path.

Trajectory output follows ORB-SLAM's SaveTrajectoryTUM: every tracked frame is stored
relative to its reference keyframe and composed with that keyframe's final pose (walking up
the spanning tree when the keyframe was culled); lost frames have no pose and are left out.
With the atlas (``slam/orb/atlas.py``) every frame is in its final map's frame: the first map's
once the maps merged, its own map's first keyframe otherwise (``stats.json`` counts them).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from semslam.backend.worker import BundleAdjustmentRunner
from semslam.config import SystemConfig
from semslam.core.protocols import FramePacket, TrackerInputs
from semslam.core.types import Frame, KeyframeEvent, TrackResult
from semslam.errors import ConfigError, WorkerFailed
from semslam.features import create_extractor, feature_spec
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.io.depth import SensorDepth
from semslam.core.trajectory import Trajectory
from semslam.place.database import KeyframeDatabase
from semslam.place.flat import vocabulary_for
from semslam.place.vocabulary import Vocabulary
from semslam.slam.orb.atlas import Atlas
from semslam.slam.orb.depth_prior import DepthPrior
from semslam.slam.orb.frame_builders import frame_builder, is_monocular
from semslam.slam.orb.fusion import PointFusion
from semslam.slam.orb.keyframe_worker import KeyframeInbox
from semslam.slam.orb.local_mapping import LocalMapping
from semslam.slam.orb.loop_closing import LoopClosing
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.map_merging import MapMerger
from semslam.slam.orb.tracking import Tracking

log = logging.getLogger(__name__)


def _pose_cw_through_tree(T_c_ref: np.ndarray, ref: KeyFrame) -> np.ndarray:
    """``T_cw`` of a camera known relative to ``ref``, walking up the spanning tree while the
    keyframe was culled (ORB-SLAM's SaveTrajectoryTUM)."""
    T, k = T_c_ref, ref
    while k.bad and k.parent is not None and k.T_cp is not None:
        T = T @ k.T_cp
        k = k.parent
    return T @ k.T_cw


class PlaceIndexer:
    """The keyframe sink when local mapping (or loop closing) is off: keyframes still go into
    the place-recognition database, so relocalisation works."""

    def __init__(self, vocabulary: Vocabulary, database: KeyframeDatabase) -> None:
        self.vocabulary = vocabulary
        self.database = database

    def insert(self, kf: KeyFrame) -> None:
        if kf.bow is None:
            kf.set_words(*self.vocabulary.transform(kf.keypoints.descriptors))
        self.database.add(kf.id, kf.bow)

    def idle(self) -> bool:
        return True

    def queue_size(self) -> int:
        return 0


def _image_size(camera: PinholeCamera) -> tuple[int, int] | None:
    return (camera.width, camera.height) if camera.width > 0 and camera.height > 0 else None


def create_tracker(config: SystemConfig, camera: PinholeCamera, inputs: TrackerInputs | None = None,
                   map_path: Path | None = None) -> "OrbTracker":
    """The registry's factory: loads a saved map."""
    # sensor: mono with depth.source: sensor runs without depth (two-view initialisation,
    # slam/orb/mono_init.py); with a depth network's depth it is pseudo-RGB-D.
    slam_map = None
    if map_path is not None:
        from semslam.slam.orb.map_io import load_map

        slam_map = load_map(map_path, feature_spec(config.features, _image_size(camera)))
    return OrbTracker(config, camera, inputs or TrackerInputs(SensorDepth()), slam_map)


class OrbTracker:
    """Tracking + local mapping + loop closing over one map (``core.protocols.Tracker``)."""

    has_map = True

    def __init__(self, config: SystemConfig, camera: PinholeCamera, inputs: TrackerInputs,
                 slam_map: Map | None = None) -> None:
        self.config = config
        self.camera = camera
        self._announced: list[KeyFrame] = []  # culled ones too: their points stay in the maps
        self.threaded = not config.slam.sequential
        # One BA runner shared by local mapping and loop closing; owned (and closed) here.
        self.ba_runner = BundleAdjustmentRunner()
        self._stopped = False
        # Built first: everything that can fail on a bad config, before any thread or process.
        extractor = create_extractor(config.features, _image_size(camera))
        self.map = slam_map or Map(extractor.spec)
        self.vocabulary = vocabulary_for(self.map.spec, config.slam.vocabulary)
        self.database = KeyframeDatabase()
        use_mapping = config.slam.local_mapping and not config.slam.localization_only
        use_loops = config.slam.loop_closing and not config.slam.localization_only
        if use_loops and not self.vocabulary.recognises_places:
            raise ConfigError("slam.loop_closing: no bag-of-words vocabulary for "
                              f"{self.map.spec.kind.value} descriptors "
                              f"(features.extractor: {config.features.extractor}); "
                              "set slam.loop_closing=false")
        indexer = PlaceIndexer(self.vocabulary, self.database)
        fusion = PointFusion(self.map, camera, config.slam.bf)
        mapping_inbox, loop_inbox = KeyframeInbox(), KeyframeInbox()
        # Multi-map atlas (ORB-SLAM3): off with localisation only (no mapping) or a delay <= 0.
        new_map_after = config.slam.new_map_after_s if (use_mapping and self.vocabulary.recognises_places) else 0.0
        self.atlas = Atlas(self.map, new_map_after)
        merger = MapMerger(self.map, self.atlas, fusion, camera, config.slam.bf) if self.atlas.enabled else None
        self.closer = LoopClosing(config, camera, self.map, self.database, self.ba_runner, fusion, loop_inbox,
                                  mapping_inbox, merger)
        # A depth network's depth as a checked prior of a monocular map (depth.use: prior).
        self.depth_prior = (DepthPrior(config.depth)
                            if is_monocular(config) and config.depth.source != "sensor" else None)
        self.mapper = LocalMapping(config, camera, self.map, self.vocabulary, self.ba_runner, fusion, mapping_inbox,
                                   next_stage=self.closer if use_loops else indexer, depth_prior=self.depth_prior)
        # A stereo pair's right image gets an extractor of its own (extracted beside the left).
        right_extractor = (create_extractor(config.features, _image_size(camera))
                           if config.sensor == "stereo" else None)
        builder = frame_builder(config, camera, extractor.spec, right_extractor, extractor)
        self.tracking = Tracking(config, camera, self.map, self.vocabulary, self.database, extractor,
                                 keyframes=self.mapper if use_mapping else indexer, depth=inputs.depth,
                                 dynamics=inputs.dynamics, atlas=self.atlas if self.atlas.enabled else None,
                                 builder=builder, depth_prior=self.depth_prior, imu=inputs.imu)
        self.closer.frame_records = self.tracking.trajectory_refs  # a monocular loop rescales them
        if self.threaded and use_mapping:
            self.tracking.pause_mapping = mapping_inbox.paused  # while a monocular map is made metric
        if slam_map is not None:
            for kf in self.map.all_keyframes():
                indexer.insert(kf)
            if self.map.keyframes:
                self.tracking.start_lost_in(self.map.all_keyframes()[-1])
        # Last: the BA worker process and the threads (nothing below can fail on the config).
        self.ba_runner.start(use_process=self.threaded)
        if self.threaded:
            if use_mapping:
                self.mapper.start()
            if use_loops:
                self.closer.start()

    # ------------------------------------------------------------------ Tracker contract
    def prepare(self, frame: Frame) -> None:
        """A stereo pair's right image is extracted here, ahead of tracking."""
        self.tracking.builder.prepare(frame)

    def track(self, packet: FramePacket) -> TrackResult:
        self._raise_worker_error()
        result = self.tracking.track(packet)
        if not result.is_keyframe:
            return result
        kf = self.tracking.ref_kf  # the keyframe just made
        assert kf is not None
        self._announced.append(kf)
        return replace(result, keyframe=KeyframeEvent(kf.id, kf.timestamp, kf.T_wc))

    def final_keyframe_poses(self) -> dict[int, np.ndarray]:
        """``T_wc`` of every keyframe announced, after the final optimisation (culled ones
        through the spanning tree, as the trajectory does)."""
        with self.map.lock:
            return {kf.id: invert(_pose_cw_through_tree(np.eye(4), kf)) for kf in self._announced}

    @property
    def n_keyframes(self) -> int:
        return len(self.map.keyframes)

    def _raise_worker_error(self) -> None:
        for worker in (self.mapper, self.closer):
            if worker.error is not None:
                raise WorkerFailed(f"{worker.thread_name} thread failed: "
                                   f"{type(worker.error).__name__}: {worker.error}") from worker.error

    def shutdown(self) -> None:
        """Let local mapping and loop closing finish their queues (ORB-SLAM's Shutdown waits for
        them too), stop the BA process; raise WorkerFailed afterwards if a thread failed."""
        if self._stopped:
            return
        self._stopped = True
        try:
            for worker in (self.mapper, self.closer):
                worker.stop()
        finally:
            self.tracking.builder.close()
            self.ba_runner.close()
        self._raise_worker_error()

    def trajectory(self) -> Trajectory:
        with self.map.lock:
            stamped = [(t, invert(_pose_cw_through_tree(T_cr, ref))) for t, ref, T_cr in self.tracking.trajectory_refs]
        return Trajectory.from_poses(stamped)

    def keyframe_trajectory(self) -> Trajectory:
        return Trajectory.from_poses([(k.timestamp, k.T_wc) for k in self.map.all_keyframes()])

    def map_points(self) -> np.ndarray:
        """World positions of the map's points now (a copy, taken under the map lock)."""
        with self.map.lock:
            rows = np.fromiter((p.row for p in self.map.points.values()), np.intp, len(self.map.points))
            return self.map.store.pos[rows].copy()

    def stats(self) -> dict[str, Any]:
        mapper, closer = self.mapper, self.closer
        lba = mapper.stats["local_ba_ms"]
        return {
            "map_points": len(self.map.points),
            "loops": closer.stats["loops"],
            "loop_pairs": closer.loops,
            "relocalisations": self.tracking.n_relocalisations,
            **self.tracking.prior_counters(),
            "local_ba": mapper.stats["local_ba"],
            "local_ba_failed": mapper.stats["local_ba_failed"],
            "local_ba_links": mapper.stats["local_ba_links"],
            "local_ba_ms_median": float(np.median(lba)) if lba else 0.0,
            "local_mapping_cpu_ms": mapper.cpu_ms(),
            "global_ba": closer.stats["global_ba"],
            "global_ba_failed": closer.stats["global_ba_failed"],
            "pose_graph_failed": closer.stats["pose_graph_failed"],
            "loops_dropped": closer.stats["loops_dropped"],
            "ba_worker_restarts": self.ba_runner.restarts,
            "culled_keyframes": mapper.stats["culled_keyframes"],
            "triangulated_points": mapper.stats["triangulated"],
            "culled_dynamic_points": self.tracking.n_culled_dynamic_points,
            "threaded": self.threaded,
            **self._atlas_stats(),
            **self._mono_stats(),
            **(self.depth_prior.stats() if self.depth_prior is not None else {}),
        }

    def _mono_stats(self) -> dict[str, Any]:
        """Monocular only: two-view reconstructions tried and why they were refused."""
        init = self.tracking.mono_init
        if init is None:
            return {}
        return {"mono_init_attempts": init.attempts, "mono_init_refused": dict(init.reasons)}

    def _atlas_stats(self) -> dict[str, Any]:
        """``maps``, ``merges`` and the trajectory's frames per final map (slam/orb/atlas.py)."""
        with self.map.lock:
            return self.atlas.stats(ref.map_id for _, ref, _ in self.tracking.trajectory_refs)

    def save_map(self, path: Path) -> None:
        from semslam.slam.orb.map_io import save_map

        save_map(self.map, path)
