"""The ORB-SLAM2-class core: tracking in the caller's thread, local mapping and loop
closing in their own threads (or inline with ``slam.sequential``), one shared map.

Trajectory output follows ORB-SLAM's SaveTrajectoryTUM: every frame is stored relative to
its reference keyframe and composed with that keyframe's final pose (walking up the
spanning tree when the keyframe was culled).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from semslam.config import SystemConfig
from semslam.errors import ConfigError, SemslamError
from semslam.features import feature_spec
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.io.sequence import Frame
from semslam.io.trajectory import Trajectory
from semslam.slam.local_mapping import LocalMapping
from semslam.slam.loop_closing import LoopClosing
from semslam.slam.map import KeyFrame, Map
from semslam.slam.tracking import Tracking
from semslam.slam.types import TrackResult

log = logging.getLogger(__name__)


class OrbSlam:
    """Tracking + local mapping + loop closing over one map."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map | None = None) -> None:
        from semslam.place.database import KeyframeDatabase
        from semslam.place.flat import vocabulary_for

        self.config = config
        self.camera = camera
        self.map = slam_map or Map(feature_spec(config.features))
        self.vocabulary = vocabulary_for(self.map.spec, config.slam.vocabulary)
        self.database = KeyframeDatabase()
        self.tracking = Tracking(config, camera, self.map, self.vocabulary, self.database)
        self.mapper = LocalMapping(config, camera, self.map, self.vocabulary)
        self.closer = LoopClosing(config, camera, self.map, self.database, self.mapper)
        use_mapping = config.slam.local_mapping and not config.slam.localization_only
        use_loops = config.slam.loop_closing and not config.slam.localization_only
        if use_loops and not self.vocabulary.recognises_places:
            raise ConfigError("slam.loop_closing: no bag-of-words vocabulary for "
                              f"{self.map.spec.kind.value} descriptors "
                              f"(features.extractor: {config.features.extractor}); "
                              "set slam.loop_closing=false")
        if use_mapping:
            self.tracking.insert_keyframe = self.mapper.insert
            self.tracking.mapping_idle = self.mapper.idle
            self.tracking.mapping_queue_size = self.mapper.queue_size
        else:
            self.tracking.insert_keyframe = self._add_to_database_only
        if use_loops:
            self.mapper.on_keyframe_done = self.closer.insert
        else:
            self.mapper.on_keyframe_done = self._add_to_database_only
        self.threaded = not config.slam.sequential
        if self.threaded:
            from semslam.backend.worker import BundleAdjustmentRunner

            self.mapper.ba = BundleAdjustmentRunner(use_process=True)
            if use_mapping:
                self.mapper.start()
            if use_loops:
                self.closer.start()
        self.semantic = None
        if config.dynamics.semantic:
            from semslam.dynamics.semantic_worker import SemanticWorker

            self.semantic = SemanticWorker(config.semantics, threaded=self.threaded)
            self.tracking.semantic_mask = self.semantic.mask
        if slam_map is not None:
            self._index_loaded_map()

    def _add_to_database_only(self, kf: KeyFrame) -> None:
        if kf.bow is None:
            kf.bow, kf.featvec = self.vocabulary.transform(kf.keypoints.descriptors)
        self.database.add(kf.id, kf.bow)

    def _index_loaded_map(self) -> None:
        """A loaded map: index its keyframes for relocalisation and start lost (we do not
        know where the camera is until it relocalises)."""
        from semslam.slam.types import TrackingState

        for kf in self.map.all_keyframes():
            self._add_to_database_only(kf)
        if self.map.keyframes:
            self.tracking.state = TrackingState.LOST
            self.tracking.ref_kf = self.map.all_keyframes()[-1]

    # ------------------------------------------------------------------ System interface
    def prepare(self, frame: Frame) -> Frame:
        """Called by the reader as soon as a frame is decoded: start its segmentation."""
        return self.semantic.prepare(frame) if self.semantic is not None else frame

    def track(self, frame: Frame) -> TrackResult:
        for worker in (self.mapper, self.closer):
            if worker.error is not None:
                raise SemslamError(f"{type(worker).__name__} thread failed: {worker.error}") from worker.error
        return self.tracking.track(frame)

    @property
    def n_keyframes(self) -> int:
        return len(self.map.keyframes)

    def shutdown(self) -> None:
        """Let the threads finish their queues (ORB-SLAM's Shutdown waits for them too)."""
        if self.threaded:
            self.mapper.stop()
            self.closer.stop()
        self.mapper.ba.close()
        if self.semantic is not None:
            self.semantic.close()

    def trajectory(self) -> Trajectory:
        stamps, poses = [], []
        with self.map.lock:
            for t, ref, T_cr, _lost in self.tracking.trajectory_refs:
                T = T_cr
                k = ref
                while k.bad and k.parent is not None and k.T_cp is not None:
                    T = T @ k.T_cp
                    k = k.parent
                stamps.append(t)
                poses.append(invert(T @ k.T_cw))
        if not stamps:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        return Trajectory(np.asarray(stamps), np.stack(poses))

    def keyframe_trajectory(self) -> Trajectory:
        kfs = self.map.all_keyframes()
        if not kfs:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        return Trajectory(np.array([k.timestamp for k in kfs]), np.stack([k.T_wc for k in kfs]))

    def extra_stats(self) -> dict[str, object]:
        lba = self.mapper.stats["local_ba_ms"]
        return {
            "map_points": len(self.map.points),
            "loops": self.closer.stats["loops"],
            "loop_pairs": self.closer.loops,
            "relocalisations": self.tracking.n_relocalisations,
            "local_ba": self.mapper.stats["local_ba"],
            "local_ba_ms_median": float(np.median(lba)) if lba else 0.0,
            "global_ba": self.closer.stats["global_ba"],
            "culled_keyframes": self.mapper.stats["culled_keyframes"],
            "triangulated_points": self.mapper.stats["triangulated"],
            "threaded": self.threaded,
            **(self.semantic.stats() if self.semantic is not None else {}),
        }

    def save_map(self, path: Path) -> None:
        from semslam.slam.map_io import save_map

        save_map(self.map, path)
