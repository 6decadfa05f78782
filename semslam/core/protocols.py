"""The contracts of the SLAM core. Read this first.

Every backend implements one of these protocols and is found by name through
``semslam.core.registry``; the System and the pipeline call only what is written here.

    SequenceSource ─► Frame ─► System.prepare: DynamicStage.prepare(frame) (reader thread)
                                   │ FramePacket (frozen: the frame and what was measured ahead)
                                   ▼
    Tracker.track(packet)   uses  Extractor (+ its FeatureSpec) ─► Matcher (chosen by the spec)
                                  DepthSource (sensor depth, or SDFCNN's for monocular runs)
                                  DynamicStage.before_extraction / after_pose
                                   │ TrackResult (pose, dynamic mask, keyframe event, corrections)
                                   ▼
    System ─► MapStage.add_keyframe(snapshot) / add_frame ... correct_poses(...) ... finish(out_dir)

Data flows one way: nothing downstream writes into a packet; what a stage finds comes
back as its return value.

Which thread owns what is in ``docs/architecture.md``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ImuCalibration
from semslam.core.trajectory import Trajectory
from semslam.core.types import FeatureSpec, Frame, Keypoints, LabelMap, TrackResult
from semslam.geometry.camera import PinholeCamera

BoolImage = NDArray[np.bool_]


# ---------------------------------------------------------------------------- per-frame packet
@dataclass(frozen=True)
class FramePacket:
    """One frame on its way to the tracker, with what ``System.prepare`` measured ahead of
    tracking in the reader thread. Read-only downstream: the dynamic stage keeps what it
    started for the frame (keyed by its index), the tracker returns what it found.
    """

    frame: Frame
    #: The frame's sharpness (``frontend.sharpness.sharpness``), measured ahead when the
    #: tracker compares frames' sharpness (blur coasting, depth odometry); None: the
    #: tracker measures it if it needs it.
    sharpness: float | None = None


@dataclass
class MotionPrior:
    """What tracking knows of the camera before it extracts a frame: the last frame (index,
    tracked pose) and the constant-velocity model, T_cw(k) = velocity @ T_cw(k-1) (None when
    tracking is lost). The dynamic stage warps skipped frames' masks with it."""

    last_index: int
    T_cw_last: NDArray[np.float64]
    velocity: NDArray[np.float64] | None

    def predicted(self) -> NDArray[np.float64] | None:
        return None if self.velocity is None else self.velocity @ self.T_cw_last


@dataclass
class KeyframeSnapshot:
    """What a map builder gets for a new keyframe: a copy that stays valid after the SLAM
    core moves on (poses change later through ``MapBuilder.correct_poses``)."""

    keyframe_id: int
    timestamp: float
    T_wc: NDArray[np.float64]
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None
    dynamic: BoolImage | None
    labels: LabelMap | None
    camera: PinholeCamera
    #: Set by background inpainting (``reconstruction.inpainting``): dynamic pixels whose
    #: static background was filled from earlier keyframes, and those filled by image
    #: inpainting (synthesised, not observed). ``dynamic`` then marks what stays unknown.
    filled: BoolImage | None = None
    synthesized: BoolImage | None = None


@dataclass
class MovingRegions:
    """Found after the pose (DDL-SLAM multi-view geometry): ``moving`` pixels, and the wider
    ``drop`` band inside which keypoints are removed."""

    moving: BoolImage
    drop: BoolImage


@dataclass
class TrackerInputs:
    """What the System builds and hands every tracker: where depth comes from, the
    dynamic stage (None when dynamics handling is off) and the IMU's calibration (None
    without an IMU, or with ``imu.use: false``)."""

    depth: "DepthSource"
    dynamics: "DynamicStage | None" = None
    imu: ImuCalibration | None = None


# ---------------------------------------------------------------------------- contracts
@runtime_checkable
class SequenceSource(Protocol):
    """Frames of one sequence with its camera and, where known, its ground truth."""

    name: str
    root: Path
    camera: PinholeCamera
    groundtruth_path: Path | None
    has_depth: bool
    skipped: list[tuple[int, str]]

    def __len__(self) -> int: ...

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]: ...


@runtime_checkable
class Extractor(Protocol):
    """Keypoints and descriptors of a grey image; ``spec`` says what the descriptors are and
    which pyramid the extractor really used (the core sizes its tables from it)."""

    spec: FeatureSpec

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints: ...


@runtime_checkable
class Matcher(Protocol):
    """Descriptor distances and candidate matching for one descriptor kind (Hamming or L2)."""

    def distances(self, a: NDArray[Any], b: NDArray[Any]) -> NDArray[np.float64]:
        """Distance between row k of ``a`` and row k of ``b``."""
        ...

    def match_candidates(self, desc_query: NDArray[Any], desc_train: NDArray[Any], cand_q: NDArray[np.intp],
                         cand_t: NDArray[np.intp], max_distance: float, ratio: float
                         ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]: ...

    def match_brute_force(self, desc_query: NDArray[Any], desc_train: NDArray[Any], max_distance: float, ratio: float
                          ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]: ...


@runtime_checkable
class Segmenter(Protocol):
    """RGB image -> LabelMap. ``names`` is the label set where known before the first image
    (None for backends whose labels come with the data, like ``ground_truth``)."""

    name: str
    names: dict[int, str] | None

    def segment(self, rgb: NDArray[np.uint8], frame: Frame | None = None) -> LabelMap: ...

    def close(self) -> None:
        """Free what the backend holds (a MediaPipe graph, a thread pool)."""
        ...


@runtime_checkable
class DepthSource(Protocol):
    """Depth in metres for a frame: the sensor's, or a depth network's (SDFCNN) for monocular runs."""

    def depth(self, frame: Frame) -> NDArray[np.float32] | None: ...


@runtime_checkable
class DynamicStage(Protocol):
    """Dynamic-scene handling around tracking (STDC-SLAM, DDL-SLAM).

    ``prepare`` runs in the reader thread as soon as a frame is decoded (segmentation starts;
    the stage keeps what it started, keyed by the frame's index); ``before_extraction`` gives
    the mask of pixels where no keypoint may be extracted (dynamic classes, refined by SRM,
    grown by the border band) and the ms waited for it; ``prior`` carries the motion model,
    for frames whose mask is warped from an earlier one; ``labels`` gives the class labels
    behind that mask; ``after_pose`` finds moving regions with the pose just tracked
    (multi-view geometry).
    """

    def prepare(self, frame: Frame) -> None: ...

    def before_extraction(self, packet: FramePacket, prior: MotionPrior | None = None
                          ) -> tuple[BoolImage | None, NDArray[np.uint8] | None, float]:
        """(dynamic mask, extractor mask, ms waited)."""
        ...

    def labels(self, index: int) -> LabelMap | None:
        """The class labels of frame ``index`` once ``before_extraction`` gave its mask: its
        own segmentation's (None when its mask was warped from another frame's)."""
        ...

    def after_pose(self, T_cw: NDArray[np.float64], depth: NDArray[np.float32],
                   references: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]]
                   ) -> MovingRegions | None: ...

    def after_pose_mono(self, current: Any, references: list[Any], spec: FeatureSpec) -> MovingRegions | None:
        """``after_pose`` without depth: ``current`` and ``references`` are
        ``dynamics.multiview_mono.MonoView`` (a layer above this one)."""
        ...

    def stats(self) -> dict[str, float]: ...

    def close(self) -> None: ...


@runtime_checkable
class MapBuilder(Protocol):
    """Builds a map from keyframe snapshots (inpainting, octree, semantic cloud, TSDF);
    told when loop closing or BA moves keyframes, asked to write its files at the end."""

    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None: ...

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None: ...

    def finish(self, out_dir: Path) -> dict[str, Path]: ...

    def close(self) -> None: ...


@runtime_checkable
class MapStage(MapBuilder, Protocol):
    """What the System feeds: the map builders behind one worker (``maps.builders``).

    Besides the keyframes it takes every other tracked frame when ``wants_frames`` (the
    inpainted frames of ``--save-inpainted``), and ``stats`` says what the maps cost (empty
    until ``finish``).
    """

    wants_frames: bool

    def add_frame(self, snapshot: KeyframeSnapshot) -> None: ...

    def stats(self) -> dict[str, float]: ...


@runtime_checkable
class Tracker(Protocol):
    """A SLAM front end + back end behind one call per frame."""

    has_map: bool

    def prepare(self, frame: Frame) -> None:
        """Work on a decoded frame that can run ahead of tracking (``System.prepare``, in the
        reader thread): a stereo pair's right image features. Nothing for most trackers."""
        ...

    def track(self, packet: FramePacket) -> TrackResult: ...

    @property
    def n_keyframes(self) -> int: ...

    def trajectory(self) -> Trajectory:
        """Every frame that has a pose (lost frames are left out), after final optimisation."""
        ...

    def keyframe_trajectory(self) -> Trajectory: ...

    def map_points(self) -> NDArray[np.float64]:
        """World positions (N, 3) of the map's points now ((0, 3) for a tracker without a map)."""
        ...

    def stats(self) -> dict[str, Any]: ...

    def save_map(self, path: Path) -> None: ...

    def shutdown(self) -> None:
        """Stop every thread and process the tracker owns (its final optimisation runs
        first); safe to call twice."""
        ...

    def final_keyframe_poses(self) -> dict[int, NDArray[np.float64]]:
        """``T_wc`` of every keyframe announced in a ``TrackResult``, after ``shutdown``'s
        final optimisation (for the map builders)."""
        ...
