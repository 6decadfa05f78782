"""The counters a run's components report, as one typed block per component of
``RunResult``: tracking, local mapping, loop closing, the atlas, the dynamic stage, the map
builders and the input checks.

A counter's field name is its name in ``stats.json``; a field left None was not reported
(a tracker without loop closing has no ``loops``) and is left out of the file.
``STATS_LAYOUT`` is the order of the counters in ``stats.json``, one order for every tracker.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, Self


@dataclass(frozen=True)
class Counters:
    """A block of counters; subclasses declare them as fields."""

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_counters(cls, counters: Mapping[str, Any]) -> Self:
        """The block's own counters out of a run's counters (other keys are left to the other
        blocks: ``split_counters`` keeps the ones no block knows)."""
        return cls(**{k: counters[k] for k in cls.keys() if k in counters})

    def to_dict(self) -> dict[str, Any]:
        """The counters reported, by their ``stats.json`` names."""
        return {f.name: v for f in fields(self) if (v := getattr(self, f.name)) is not None}


@dataclass(frozen=True)
class TrackingCounters(Counters):
    """The tracking thread: how frames got their pose (ORB core: relocalisation, blur
    coasting, depth odometry; SDF-SLAM: re-anchoring, depth alignment)."""

    relocalisations: int | None = None
    depth_odometry_frames: int | None = None
    coasted_frames: int | None = None
    coast_keyframes: int | None = None
    coasted_on_shift_only: int | None = None
    depth_odometry_runs: int | None = None
    #: Map points removed because they landed on moving regions.
    culled_dynamic_points: int | None = None
    #: Monocular ORB: two-view reconstructions tried before the map started, and why refused.
    mono_init_attempts: int | None = None
    mono_init_refused: Mapping[str, int] | None = None
    #: Monocular with a depth network as a prior (slam/orb/depth_prior.py): whether the map
    #: started metric, the running scale (map depth / predicted depth), keyframes given a
    #: prior and why others were not.
    depth_prior_metric_init: bool | None = None
    depth_prior_scale: float | None = None
    depth_prior_keyframes: int | None = None
    depth_prior_refused: Mapping[str, int] | None = None
    #: With an IMU (slam/orb/motion_priors/inertial.py): the inertial initialisations (a new
    #: map starts another), the frame of the first and the seconds tracked before it, the
    #: refinements, frames posed by the IMU alone, frames lost once blind too long, and the
    #: biases at the end.
    imu_initialisations: int | None = None
    imu_init_frame: int | None = None
    imu_init_after_s: float | None = None
    imu_refinements: int | None = None
    imu_only_frames: int | None = None
    #: Frames whose local map was searched from the IMU's pose (``imu.local_map_recovery``).
    imu_local_map_searches: int | None = None
    imu_only_spans: Sequence[Sequence[float]] | None = None
    imu_bridged_frames: int | None = None
    imu_weak_frames: int | None = None
    imu_refused_solutions: int | None = None
    imu_blind_lost: int | None = None
    #: The map turned to gravity at the initialisation and each refinement, [time, degrees];
    #: a monocular map's scale factors applied, [time, factor, relative spread].
    imu_gravity_alignments: Sequence[Sequence[float]] | None = None
    imu_scale_unsure: int | None = None
    imu_scales: Sequence[Sequence[float]] | None = None
    #: Gravity (m/s^2) in the map's frame: (0, 0, -g) once the map is turned to it
    #: (``imu.gravity_aligned``), else in the first camera's (x right, y down, z forward).
    imu_gravity: Sequence[float] | None = None
    imu_gyro_bias: Sequence[float] | None = None
    imu_acc_bias: Sequence[float] | None = None
    #: Keyframes linked to the one before by the IMU's motion (``imu.keyframe_links``).
    imu_keyframe_links: int | None = None
    tracking_edges: int | None = None
    reanchors: int | None = None
    fallback_reference: int | None = None
    alignment_kept: int | None = None
    depth_alignment_fits: int | None = None
    #: 5th, 50th and 95th percentiles of the depth alignment's fitted power and map / predicted ratio.
    depth_alignment_power_p5_p50_p95: Sequence[float] | None = None
    depth_alignment_ratio_p5_p50_p95: Sequence[float] | None = None
    #: Seconds compiling the numba kernels before the first frame.
    jit_warmup_s: float | None = None


@dataclass(frozen=True)
class MappingCounters(Counters):
    """The sparse map and local mapping (local bundle adjustment, keyframe culling)."""

    map_points: int | None = None
    local_ba: int | None = None
    local_ba_failed: int | None = None
    #: The IMU's keyframe links in all local BAs together (each BA counts the links it held).
    local_ba_links: int | None = None
    local_ba_ms_median: float | None = None
    #: The local mapping thread's CPU ms: ``total``, ``per_keyframe`` and one entry per step.
    local_mapping_cpu_ms: Mapping[str, float] | None = None
    ba_worker_restarts: int | None = None
    culled_keyframes: int | None = None
    triangulated_points: int | None = None
    #: Whether local mapping and loop closing ran in threads of their own.
    threaded: bool | None = None


@dataclass(frozen=True)
class LoopClosingCounters(Counters):
    """Loop closing and global optimisation (ORB core: loops, global BA; SDF-SLAM: the
    global correction rounds)."""

    loops: int | None = None
    #: (keyframe id, loop candidate id) of each loop closed.
    loop_pairs: Sequence[Sequence[int]] | None = None
    global_ba: int | None = None
    global_ba_failed: int | None = None
    global_rounds: int | None = None
    global_pairs_tried: int | None = None
    global_constraints: int | None = None
    pose_graph_failed: int | None = None
    loops_dropped: int | None = None


@dataclass(frozen=True)
class AtlasCounters(Counters):
    """The set of maps: maps started, merges, and which map each trajectory row is in."""

    maps: int | None = None
    merges: int | None = None
    maps_unmerged: int | None = None
    trajectory_frames_by_map: Mapping[str, int] | None = None
    frames_outside_first_map: int | None = None
    #: [first row, rows, map id] of each run of trajectory.txt rows in one map's frame.
    trajectory_map_runs: Sequence[Sequence[int]] | None = None
    merges_rejected: Mapping[str, int] | None = None
    merge_checks: Sequence[Mapping[str, Any]] | None = None


@dataclass(frozen=True)
class DynamicsCounters(Counters):
    """The dynamic stage's semantic thread: segmentations, mask refinement, warped masks."""

    segmented_frames: int | None = None
    segment_ms_median: float | None = None
    segment_ms_p95: float | None = None
    srm_ms_median: float | None = None
    semantic_wait_ms_median: float | None = None
    semantic_wait_ms_p95: float | None = None
    warped_frames: int | None = None
    warp_ms_median: float | None = None
    warp_ms_p95: float | None = None
    frames_without_own_mask: int | None = None
    resized_label_maps: int | None = None


@dataclass(frozen=True)
class MapBuildingCounters(Counters):
    """The map builders' worker (``maps.builders``): keyframes integrated, inpainting, and
    whether its queue kept pace."""

    map_keyframes: int | None = None
    map_segmented_keyframes: int | None = None
    map_keyframe_ms_median: float | None = None
    map_finish_s: float | None = None
    inpaint_ms_median: float | None = None
    inpaint_dynamic_px: int | None = None
    inpaint_filled_share: float | None = None
    inpaint_synthesized_share: float | None = None
    inpainted_frames_written: int | None = None
    map_queue_first_third_max: int | None = None
    map_queue_last_third_max: int | None = None
    map_queue_end: int | None = None
    map_queue_max: int | None = None


@dataclass(frozen=True)
class InputHealthCounters(Counters):
    """Frames the input checks flagged (``io.input_health``); the run went on through them."""

    frames_all_dynamic: int | None = None
    frames_featureless: int | None = None
    frames_without_depth: int | None = None


#: ``RunResult``'s block fields and their types.
BLOCKS: dict[str, type[Counters]] = {
    "tracking": TrackingCounters,
    "mapping": MappingCounters,
    "loop_closing": LoopClosingCounters,
    "atlas": AtlasCounters,
    "dynamics": DynamicsCounters,
    "map_building": MapBuildingCounters,
    "input_health": InputHealthCounters,
}

#: The counters' order in ``stats.json``: the tracker's (the ORB core's and SDF-SLAM's
#: interleaved, as each has always written them), the dynamic stage's, the map builders',
#: the input checks', then the JIT warm-up.
STATS_LAYOUT: tuple[str, ...] = (
    "map_points", "loops", "loop_pairs", "relocalisations", "depth_odometry_frames", "coasted_frames",
    "coast_keyframes", "coasted_on_shift_only", "depth_odometry_runs", "local_ba", "local_ba_failed",
    "local_ba_links", "local_ba_ms_median", "local_mapping_cpu_ms", "global_ba", "global_ba_failed",
    "tracking_edges", "reanchors", "fallback_reference", "global_rounds", "global_pairs_tried", "global_constraints",
    "pose_graph_failed",
    "alignment_kept", "depth_alignment_fits", "depth_alignment_power_p5_p50_p95", "depth_alignment_ratio_p5_p50_p95",
    "loops_dropped", "ba_worker_restarts", "culled_keyframes", "triangulated_points", "culled_dynamic_points",
    "threaded",
    "maps", "merges", "maps_unmerged", "trajectory_frames_by_map", "frames_outside_first_map", "trajectory_map_runs",
    "merges_rejected", "merge_checks", "mono_init_attempts", "mono_init_refused",
    "depth_prior_metric_init", "depth_prior_scale", "depth_prior_keyframes", "depth_prior_refused",
    "imu_initialisations", "imu_init_frame", "imu_init_after_s", "imu_refinements", "imu_only_frames",
    "imu_local_map_searches", "imu_only_spans", "imu_bridged_frames", "imu_weak_frames",
    "imu_refused_solutions", "imu_blind_lost", "imu_gravity_alignments", "imu_scale_unsure", "imu_scales", "imu_gravity", "imu_gyro_bias", "imu_acc_bias",
    "imu_keyframe_links", *DynamicsCounters.keys(), *MapBuildingCounters.keys(), *InputHealthCounters.keys(),
    "jit_warmup_s",
)
_POSITION = {key: i for i, key in enumerate(STATS_LAYOUT)}


def split_counters(counters: Mapping[str, Any]) -> tuple[dict[str, Counters], dict[str, Any]]:
    """A run's counters (one flat dict, ``stats.json`` names) as the blocks, by field name,
    and the counters no block knows (kept, so that none is lost)."""
    blocks = {name: cls.from_counters(counters) for name, cls in BLOCKS.items()}
    other = {k: v for k, v in counters.items() if k not in _POSITION}
    return blocks, other


def join_counters(blocks: Sequence[Counters], other: Mapping[str, Any]) -> dict[str, Any]:
    """The blocks' counters in ``STATS_LAYOUT`` order, then the ones no block knows."""
    known = {k: v for block in blocks for k, v in block.to_dict().items()}
    return {**dict(sorted(known.items(), key=lambda kv: _POSITION[kv[0]])), **other}
