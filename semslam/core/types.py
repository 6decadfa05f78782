"""Values that cross component boundaries: frames, keypoints and what describes them,
labels, tracking results. Plain data with no behaviour beyond small derived properties.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from enum import Enum
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.imu import ImuSamples
from semslam.core.results import (BLOCKS, AtlasCounters, DynamicsCounters, InputHealthCounters, LoopClosingCounters,
                                  MapBuildingCounters, MappingCounters, TrackingCounters, join_counters,
                                  split_counters)


# ---------------------------------------------------------------------------- frames
@dataclass
class Frame:
    """One time step: colour image (RGB, uint8), depth in metres (0 = none) and timestamp.

    A stereo frame also carries the right image (``right``, in ``rgb``'s form, rectified
    with the left so that a point lies on the same row in both); None for other sensors.
    With an IMU, ``imu`` holds the readings since the frame before."""

    index: int
    timestamp: float
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None = None
    rgb_path: Path | None = None
    depth_path: Path | None = None
    right: NDArray[np.uint8] | None = field(default=None, repr=False)
    right_path: Path | None = None
    #: IMU readings after the frame before, up to this frame (the first frame: the last reading
    #: at or before it); None without an IMU.
    imu: ImuSamples | None = field(default=None, repr=False)
    _gray: NDArray[np.uint8] | None = field(default=None, repr=False)
    _right_gray: NDArray[np.uint8] | None = field(default=None, repr=False)

    @property
    def gray(self) -> NDArray[np.uint8]:
        if self._gray is None:
            self._gray = cv2.cvtColor(self.rgb, cv2.COLOR_RGB2GRAY)
        return self._gray

    @property
    def right_gray(self) -> NDArray[np.uint8] | None:
        """The right image in grey (None without one), converted once."""
        if self._right_gray is None and self.right is not None:
            self._right_gray = cv2.cvtColor(self.right, cv2.COLOR_RGB2GRAY)
        return self._right_gray

    @property
    def shape(self) -> tuple[int, int]:
        return self.rgb.shape[0], self.rgb.shape[1]


# ---------------------------------------------------------------------------- features
class DescriptorKind(str, Enum):
    """Binary descriptors are compared by Hamming distance, float ones by L2."""

    BINARY = "binary"
    FLOAT = "float"


@dataclass(frozen=True)
class ScalePyramid:
    """Per-level scale factors and observation weights of an extractor's pyramid
    (ORB-SLAM's mvScaleFactor, mvInvLevelSigma2), and the level a point is predicted at."""

    scale_factor: float
    n_levels: int

    @cached_property
    def scales(self) -> NDArray[np.float64]:
        return self.scale_factor ** np.arange(self.n_levels)

    @cached_property
    def inv_sigma2(self) -> NDArray[np.float64]:
        return 1.0 / self.scales**2

    @cached_property
    def log_scale(self) -> float:
        return float(np.log(self.scale_factor))

    def predict_level(self, max_dist: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.intp]:
        """Pyramid level at which a point observed up to ``max_dist`` appears from ``dist``
        (ORB-SLAM MapPoint::PredictScale), for many points at once."""
        ratio = np.asarray(max_dist) / np.maximum(dist, 1e-9)
        level = np.ceil(np.log(np.maximum(ratio, 1e-9)) / self.log_scale)
        return np.clip(level, 0, self.n_levels - 1).astype(np.intp)


@dataclass(frozen=True)
class FeatureSpec:
    """What an extractor produces: the descriptor kind and size, the distance that compares
    them, the matching thresholds in that distance, and the pyramid it actually used.

    ``th_low`` / ``th_high`` are ORB-SLAM's TH_LOW / TH_HIGH (50 / 100 Hamming bits for ORB):
    the strict threshold for guided searches (fusion, triangulation, bag-of-words) and the
    loose one for searches by projection.
    """

    kind: DescriptorKind
    dim: int  # bytes for binary descriptors, elements for float ones
    scale_factor: float
    n_levels: int
    th_low: float
    th_high: float

    @property
    def dtype(self) -> type:
        return np.uint8 if self.kind is DescriptorKind.BINARY else np.float32

    @property
    def distance(self) -> str:
        return "hamming" if self.kind is DescriptorKind.BINARY else "l2"

    @cached_property
    def pyramid(self) -> ScalePyramid:
        return ScalePyramid(self.scale_factor, self.n_levels)


#: ORB's 256-bit descriptors with ORB-SLAM's thresholds, for an extractor's spec.
def orb_spec(scale_factor: float, n_levels: int) -> FeatureSpec:
    return FeatureSpec(DescriptorKind.BINARY, 32, scale_factor, n_levels, th_low=50, th_high=100)


@dataclass
class Keypoints:
    """Keypoints of one image: pixel positions (as detected, distorted), pyramid level,
    detector response, orientation in degrees and one descriptor row per keypoint
    (uint8 bytes for binary descriptors, float32 for float ones)."""

    xy: NDArray[np.float32]
    octave: NDArray[np.int32]
    response: NDArray[np.float32]
    angle: NDArray[np.float32]
    descriptors: NDArray[np.uint8] | NDArray[np.float32]

    def __len__(self) -> int:
        return len(self.xy)

    def subset(self, keep: NDArray[np.bool_] | NDArray[np.intp]) -> "Keypoints":
        return Keypoints(self.xy[keep], self.octave[keep], self.response[keep], self.angle[keep], self.descriptors[keep])

    @staticmethod
    def empty(descriptor_size: int = 32, dtype: type = np.uint8) -> "Keypoints":
        return Keypoints(
            np.zeros((0, 2), np.float32), np.zeros(0, np.int32), np.zeros(0, np.float32),
            np.zeros(0, np.float32), np.zeros((0, descriptor_size), dtype),
        )


# ---------------------------------------------------------------------------- semantics
@dataclass
class LabelMap:
    """Per-pixel class ids of one image in the label set of the backend that made it.

    ``names`` maps every id the backend can output to its class name, so class names in
    the config (not backend-specific ids) decide what is dynamic. ``confidence`` is the
    backend's score of the chosen label where it has one (for display and thresholds).
    """

    labels: NDArray[np.uint8]
    names: dict[int, str]
    confidence: NDArray[np.float32] | None = None

    def __post_init__(self) -> None:
        if self.labels.dtype != np.uint8 or self.labels.ndim != 2:
            raise ValueError(f"LabelMap.labels must be uint8 HxW, got {self.labels.dtype} {self.labels.shape}")
        if self.confidence is not None and self.confidence.shape != self.labels.shape:
            raise ValueError(f"LabelMap.confidence shape {self.confidence.shape} != labels {self.labels.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.labels.shape[0], self.labels.shape[1]


# ---------------------------------------------------------------------------- tracking
class TrackingState(str, Enum):
    NOT_INITIALIZED = "not_initialized"
    OK = "ok"
    LOST = "lost"


@dataclass(frozen=True)
class KeyframeEvent:
    """A keyframe a tracker made at this frame, as the map builders take it (the System
    feeds them; later pose changes come as ``TrackResult.corrected_poses`` and at the end
    from ``Tracker.final_keyframe_poses``)."""

    id: int
    timestamp: float
    T_wc: NDArray[np.float64] = field(repr=False)
    #: The depth the tracker placed the keyframe's points with where it is not the depth
    #: source's (SDF-SLAM's prediction aligned to the map); None: the depth source's.
    depth: NDArray[np.float32] | None = field(default=None, repr=False)


@dataclass
class TrackResult:
    """What a tracker returns for one frame. ``pose_wc`` is None when the frame has no pose
    (before initialisation, or lost): such frames are left out of the trajectory."""

    timestamp: float
    pose_wc: NDArray[np.float64] | None
    state: TrackingState
    n_matches: int = 0
    n_inliers: int = 0
    n_keypoints: int = 0
    is_keyframe: bool = False
    dynamic_ratio: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    #: The frame's final dynamic mask (semantic classes + moving regions; None without
    #: dynamics handling), for the map builders.
    dynamic: NDArray[np.bool_] | None = field(default=None, repr=False)
    #: For viewers (``viz.rerun_log``): the keypoints extracted (pixels as detected) and, per
    #: keypoint, False where it was removed as dynamic (moving regions).
    keypoints_xy: NDArray[np.float32] | None = field(default=None, repr=False)
    keypoint_static: NDArray[np.bool_] | None = field(default=None, repr=False)
    #: The keyframe made at this frame (None: the frame is no keyframe).
    keyframe: KeyframeEvent | None = field(default=None, repr=False)
    #: Keyframes' new ``T_wc`` where this frame moved them (a pose-graph correction).
    corrected_poses: dict[int, NDArray[np.float64]] | None = field(default=None, repr=False)
    #: What posed the frame when its features did not (a pose prior's name: ``inertial`` for
    #: the IMU alone, ``depth_odometry``, ``blur_coast``); empty when the features did.
    posed_by: str = ""


# ---------------------------------------------------------------------------- runs
@dataclass
class RunResult:
    """What one SLAM run produced, as a value (evo's ``Result`` is the model): written by the
    pipeline as ``stats.json``, read back by ``semslam bench`` and the CLI.

    The components' counters are one typed block each (``tracking``, ``mapping``,
    ``loop_closing``, ``atlas``, ``dynamics``, ``map_building``, ``input_health``;
    ``core.results``), at the top level of ``stats.json``; ``set_counters`` takes them as the
    one flat dict the components report. ``ate`` / ``rpe_*`` hold evo-style statistics
    (rmse, mean, median, std, min, max) in metres / degrees when the sequence has ground truth.
    """

    sequence: str
    preset: str
    out_dir: Path
    frames: int = 0
    tracked_frames: int = 0
    lost_frames: int = 0
    uninitialized_frames: int = 0
    keyframes: int = 0
    skipped_frames: int = 0
    skipped: list[str] = field(default_factory=list)
    # The frames the run was given (the sequence's listed frames, or --max-frames); they add
    # up: frames_total = tracked + lost + uninitialized + skipped + not_reached (frames a
    # run stopped early, by Ctrl-C or an error, never read). ``frames`` = the first three.
    frames_total: int = 0
    frames_not_reached: int = 0
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    stages_ms_median: dict[str, float] = field(default_factory=dict)
    stages_ms_p95: dict[str, float] = field(default_factory=dict)
    stages_ms_max: dict[str, float] = field(default_factory=dict)
    # Where each frame's tracking time went, per-frame medians (ms; ``semslam.thread_clock``):
    # "cpu" the tracking thread's own CPU time, "runqueue" waiting for a core, "asleep" the
    # rest (the GIL, a lock, a mask). Linux only for the last two.
    tracking_thread_ms: dict[str, float] = field(default_factory=dict)
    # Camera-rate runs (slam.realtime): time from a frame's arrival to its pose, and the
    # frames that arrived while the previous one was still being tracked.
    realtime: bool = False
    latency_ms: dict[str, float] = field(default_factory=dict)
    late_frames: int = 0
    dynamic_ratio_mean: float = 0.0
    wall_s: float = 0.0
    fps: float = 0.0
    tracking_fps: float = 0.0
    camera: dict[str, object] = field(default_factory=dict)
    ate: dict[str, float] | None = None
    ate_alignment: str | None = None
    # Monocular runs: ``ate`` is Sim(3)-aligned (as monocular tables report); this is the same
    # trajectory SE(3)-aligned only (metric scale counts), and the Sim(3) scale found.
    ate_se3: dict[str, float] | None = None
    ate_sim3_scale: float | None = None
    rpe_trans_1s: dict[str, float] | None = None
    rpe_rot_deg_1s: dict[str, float] | None = None
    eval_error: str | None = None
    error: str | None = None
    # Stopped before the last frame by Ctrl-C / SIGTERM (runtime.request_stop): the outputs
    # hold the frames tracked so far.
    interrupted: bool = False
    paths: dict[str, str] = field(default_factory=dict)
    tracking: TrackingCounters = field(default_factory=TrackingCounters)
    mapping: MappingCounters = field(default_factory=MappingCounters)
    loop_closing: LoopClosingCounters = field(default_factory=LoopClosingCounters)
    atlas: AtlasCounters = field(default_factory=AtlasCounters)
    dynamics: DynamicsCounters = field(default_factory=DynamicsCounters)
    map_building: MapBuildingCounters = field(default_factory=MapBuildingCounters)
    input_health: InputHealthCounters = field(default_factory=InputHealthCounters)
    #: Counters no block knows (a component's new counter): kept and written as reported.
    other_counters: dict[str, object] = field(default_factory=dict)

    @property
    def ate_rmse(self) -> float | None:
        return None if self.ate is None else float(self.ate["rmse"])

    @property
    def rpe_trans_rmse(self) -> float | None:
        return None if self.rpe_trans_1s is None else float(self.rpe_trans_1s["rmse"])

    def set_counters(self, counters: Mapping[str, object]) -> None:
        """Every block from the components' counters (one flat dict, ``stats.json`` names)."""
        blocks, self.other_counters = split_counters(counters)
        for name, block in blocks.items():
            setattr(self, name, block)

    def counters(self) -> dict[str, object]:
        """The blocks' counters as one flat dict, in the ``stats.json`` layout."""
        return join_counters([getattr(self, name) for name in BLOCKS], self.other_counters)

    def to_dict(self) -> dict[str, object]:
        """The ``stats.json`` layout: every field, the counters at the top level."""
        d = asdict(self)
        for name in (*BLOCKS, "other_counters"):
            del d[name]
        d["out_dir"] = str(self.out_dir)
        d.update({k: v for k, v in self.counters().items() if k not in d})
        return {k: v for k, v in d.items() if v is not None}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> "RunResult":
        """A ``stats.json`` read back: its fields, and its counters into the blocks."""
        names = {f.name for f in fields(cls)} - {*BLOCKS, "other_counters"}
        known = {k: v for k, v in d.items() if k in names}
        known["out_dir"] = Path(str(known.get("out_dir", ".")))
        result = cls(**known)  # type: ignore[arg-type]
        result.set_counters({k: v for k, v in d.items() if k not in names})
        return result
