"""What every config value may be: one table per config dataclass, checked once at load.

Each field has a rule: a numeric range (``Num``), a set of words (``OneOf``), a registry
kind whose backend names it takes (``Backend``), or free text (``Text``, paths). A value
outside its rule is a ConfigError naming the key and what is allowed, raised by
``load_config`` before the first frame; the components never see it. Booleans need no rule
(the loader already refuses anything but true/false). Checks between fields (min < max)
are in ``CROSS_CHECKS``; the dataclasses' own ``check`` methods keep what is specific to
one component (an odd window, weights only for one extractor).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from semslam.config import schema as s
from semslam.core import registry
from semslam.errors import ConfigError

INF = math.inf


def _fmt(x: float) -> str:
    """A bound as written: 4294967295, not 4.29497e+09."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


@dataclass(frozen=True)
class Num:
    """A finite number in [lo, hi] (an end is excluded when ``*_open``); ints stay ints."""

    lo: float = -INF
    hi: float = INF
    lo_open: bool = False
    hi_open: bool = False

    def describe(self, integer: bool) -> str:
        kind = "an integer" if integer else "a number"
        if self.lo == -INF and self.hi == INF:
            return f"a finite {kind[2:] if integer else 'number'}"
        if self.hi == INF:
            return f"{kind} {'>' if self.lo_open else '>='} {_fmt(self.lo)}"
        if self.lo == -INF:
            return f"{kind} {'<' if self.hi_open else '<='} {_fmt(self.hi)}"
        left, right = "(" if self.lo_open else "[", ")" if self.hi_open else "]"
        return f"{kind} in {left}{_fmt(self.lo)}, {_fmt(self.hi)}{right}"

    def allows(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below


@dataclass(frozen=True)
class OneOf:
    """One of a fixed set of words."""

    choices: tuple[str, ...]


@dataclass(frozen=True)
class Backend:
    """A backend name of a registry kind (aliases accepted); ``many``: a list of them."""

    kind: str
    many: bool = False


@dataclass(frozen=True)
class Text:
    """Free text: a path, a name (checked by the component that opens it)."""

    many: bool = False


Rule = Num | OneOf | Backend | Text

POSITIVE = Num(0.0, INF, lo_open=True)
NON_NEGATIVE = Num(0.0)
AT_LEAST_1 = Num(1)
RATIO = Num(0.0, 1.0, lo_open=True)          # (0, 1]
FRACTION = Num(0.0, 1.0)                     # [0, 1]
PROBABILITY = Num(0.0, 1.0, True, True)      # (0, 1)
ANGLE = Num(0.0, 180.0, lo_open=True)        # (0, 180] degrees
ANGLE_OR_OFF = Num(0.0, 180.0)               # [0, 180] degrees, 0 = off
PNP_POINTS = Num(6)                          # PnP-RANSAC needs at least 6 correspondences
RANSAC_ITERATIONS = Num(1, 1_000_000)
PIXELS = Num(0, 10_000)                      # a margin or radius in pixels, 0 allowed
VOXEL_M = Num(0.001, 10.0)                   # map resolutions: 1 mm (memory) to 10 m

RULES: dict[type, dict[str, Rule]] = {
    s.SystemConfig: {
        "preset": Text(), "sensor": OneOf(s.SENSORS), "seed": Num(0, 2**32 - 1), "depth_scale": POSITIVE,
    },
    s.FeatureConfig: {
        "extractor": Backend("extractor"),
        "n_features": Num(1, 100_000),
        "scale_factor": Num(1.0, 4.0, lo_open=True),  # the pyramid must shrink: log(scale) divides
        "n_levels": Num(1, 32),
        "fast_threshold": Num(1, 255),  # grey-level differences of uint8 images
        "fast_min_threshold": Num(1, 255),
        "matcher": OneOf(s.FEATURE_MATCHERS),
        "weights": Text(),
    },
    s.TrackingConfig: {"method": Backend("tracker")},
    s.FrameToKeyframeConfig: {
        "max_hamming": Num(0, 256),  # 256-bit descriptors
        "ratio": RATIO,
        "search_radius_px": Num(0, 10_000, lo_open=True),
        "refine_radius_px": PIXELS,
        "ransac_reprojection_px": Num(0, 1000, lo_open=True),
        "ransac_iterations": RANSAC_ITERATIONS,
        "ransac_confidence": PROBABILITY,
        "depth_check_m": POSITIVE,
        "min_inliers": PNP_POINTS,
        "min_inliers_unguided": PNP_POINTS,
        "min_depth_m": NON_NEGATIVE,
        "max_depth_m": POSITIVE,
        "keyframe_min_inliers": NON_NEGATIVE,
        "keyframe_max_translation_m": POSITIVE,
        "keyframe_max_rotation_deg": ANGLE,
    },
    s.SdfSlamConfig: {
        "reference": OneOf(("keyframe", "frame")),
        "ratio": RATIO,
        "search_radius_px": Num(0, 10_000, lo_open=True),
        "ransac_reprojection_px": Num(0, 1000, lo_open=True),
        "ransac_iterations": RANSAC_ITERATIONS,
        "ransac_confidence": PROBABILITY,
        "min_inliers": PNP_POINTS,
        "min_depth_m": POSITIVE,
        "max_depth_m": POSITIVE,
        "keyframe_min_inliers": NON_NEGATIVE,
        "keyframe_max_translation_m": POSITIVE,
        "keyframe_max_rotation_deg": ANGLE,
        "reanchor_after": AT_LEAST_1,
        "global_every": AT_LEAST_1,
        "global_pairs": NON_NEGATIVE,
        "global_max_distance_m": POSITIVE,
        "global_max_angle_deg": ANGLE,
        "global_min_inliers": PNP_POINTS,
        "min_parallax_deg": Num(0.0, 180.0, hi_open=True),
        "depth_alignment": OneOf(("none", "scale", "power")),
        "alignment_min_points": Num(3),
    },
    s.ImuConfig: {
        "init_s": POSITIVE,
        "init_step_s": POSITIVE,
        "refine_first_s": POSITIVE,
        "refine_second_s": POSITIVE,
        "refine_window_s": POSITIVE,
        "max_blind_s": NON_NEGATIVE,
        "keyframe_every_s": NON_NEGATIVE,
        "window_s": POSITIVE,
        "window_step_s": POSITIVE,
        "min_inliers": NON_NEGATIVE,
        "pose_prior_rotation_deg": Num(0.0, 180.0, lo_open=True),
        "pose_prior_translation_m": POSITIVE,
        "velocity_sigma_m_s": NON_NEGATIVE,
        "max_scale_spread": POSITIVE,
        "provisional_scale_spread": POSITIVE,
        "scale_step_s": POSITIVE,
        "scale_refine_s": POSITIVE,
        "gyro_noise_density": NON_NEGATIVE,
        "acc_noise_density": NON_NEGATIVE,
        "gyro_random_walk": NON_NEGATIVE,
        "acc_random_walk": NON_NEGATIVE,
    },
    s.SlamConfig: {
        "bf": POSITIVE,
        "rolling_shutter_ms": Num(0.0, 1000.0),
        "depth_odometry": OneOf(("none", *s.DEPTH_ODOMETRY_METHODS)),
        "depth_odometry_below": NON_NEGATIVE,
        "depth_odometry_turn_deg": ANGLE_OR_OFF,
        "depth_odometry_max_deg": ANGLE_OR_OFF,
        "depth_odometry_keyframe_deg": ANGLE_OR_OFF,
        "depth_odometry_sharp_ratio": FRACTION,
        "blur_coast_sharp_ratio": FRACTION,
        "blur_coast_turn_deg": ANGLE_OR_OFF,
        "blur_coast_max_frames": NON_NEGATIVE,
        "th_depth": POSITIVE,
        "min_frames": NON_NEGATIVE,
        "max_frames": AT_LEAST_1,
        "max_queued_keyframes_when_weak": NON_NEGATIVE,
        "min_init_keypoints": AT_LEAST_1,
        "local_ba_max_keyframes": AT_LEAST_1,
        "local_ba_max_fixed": NON_NEGATIVE,
        "loop_min_keyframes": NON_NEGATIVE,
        "loop_consistency": AT_LEAST_1,
        "loop_min_matches": Num(3),  # the loop's SE(3) RANSAC samples 3 matches
        "vocabulary": Text(),
        "yield_to_tracking_ms": Num(0.0, 1000.0),
        "new_map_after_s": Num(),  # 0 or negative: never a new map
    },
    s.DynamicsConfig: {
        "border_px": PIXELS,
        "multiview_keyframes": AT_LEAST_1,
        "multiview_min_age_s": NON_NEGATIVE,
        "parallax_deg": ANGLE,
        "depth_threshold_m": POSITIVE,
        "depth_threshold_rel": FRACTION,
        "edge_m": POSITIVE,
        "min_seeds": AT_LEAST_1,
        "min_dynamic_ratio": FRACTION,
        "downscale": Num(1, 64),
    },
    s.SemanticsConfig: {
        "backend": Backend("segmenter"),
        "dynamic_classes": Text(many=True),  # names checked against the backend's classes when it is built
        "weights": Text(),
        "threshold": Num(0.0, 1.0, hi_open=True),
        "srm_window": Num(1, 1001),
        "srm_tau_m": POSITIVE,
        "input_width": Num(0, 10_000),
        "schedule": OneOf(s.SEMANTIC_SCHEDULES),
        "stride": AT_LEAST_1,
        "warp": OneOf(s.MASK_WARPS),
        "warp_margin_px": PIXELS,
    },
    s.DepthConfig: {"source": Backend("depth_source"), "weights": Text(), "use": OneOf(("measurement", "prior")),
                    "prior_sigma": Num(0.01, 2.0), "prior_max_spread": POSITIVE, "prior_max_jump": POSITIVE,
                    "prior_max_unexplained": POSITIVE, "stereo_dense": OneOf(s.STEREO_DENSE),
                    "stereo_downscale": Num(1, 8)},
    s.InpaintingConfig: {
        "keyframes": AT_LEAST_1,
        "depth_tolerance_m": POSITIVE,
        "hole_fill_px": PIXELS,
    },
    s.MapsConfig: {
        "builders": Backend("map_builder", many=True),
        "octree_resolution_m": VOXEL_M,
        # OctoMap's sensor model: a hit must raise occupancy, a miss lower it.
        "octree_prob_hit": Num(0.5, 1.0, True, True),
        "octree_prob_miss": Num(0.0, 0.5, True, True),
        "octree_clamping_max": Num(0.5, 1.0, lo_open=True),
        "octree_appear_free_below": Num(0.0, 1.0, hi_open=True),
        "cloud_voxel_m": VOXEL_M,
        "mesh_voxel_m": VOXEL_M,
        "max_depth_m": POSITIVE,
        "dynamic_margin_px": PIXELS,
        "save_inpainted": Text(),
    },
}


def _ordered(lo_key: str, hi_key: str, strict: bool = True) -> Callable[[Any, str], str | None]:
    """A check that field ``lo_key`` is below (or, not strict, at most) ``hi_key``."""
    def check(section: Any, prefix: str) -> str | None:
        lo, hi = getattr(section, lo_key), getattr(section, hi_key)
        if lo < hi or (not strict and lo == hi):
            return None
        return (f"{prefix}{lo_key} / {prefix}{hi_key}: expected {lo_key} {'<' if strict else '<='} {hi_key}, "
                f"got {lo} / {hi}")
    return check


def _off_or_at_least(key: str, least: int, why: str) -> Callable[[Any, str], str | None]:
    """A check that field ``key`` is 0 (off) or at least ``least``."""
    def check(section: Any, prefix: str) -> str | None:
        value = getattr(section, key)
        return None if value == 0 or value >= least else f"{prefix}{key}: expected 0 or >= {least} ({why}), got {value}"
    return check


def _srm_needs_depth(cfg: Any, prefix: str) -> str | None:
    """SRM grows the mask over a depth image; a monocular run reads the colour images only
    (``io.sequence.kind_for_sensor``), so without a depth network it would silently do nothing."""
    if cfg.sensor == "mono" and cfg.depth.source == "sensor" and cfg.dynamics.semantic and cfg.semantics.srm:
        return ("semantics.srm: STDC-SLAM's refinement grows the mask over a depth image, which sensor: mono "
                "has only from a depth network (depth.source: sdfcnn); set semantics.srm=false (the "
                "mono_dynamic preset does)")
    return None


#: Checks between two fields of one section: (section, "section.") -> a message, or None.
CROSS_CHECKS: dict[type, tuple[Callable[[Any, str], str | None], ...]] = {
    s.SystemConfig: (_srm_needs_depth,),
    s.FeatureConfig: (_ordered("fast_min_threshold", "fast_threshold", strict=False),),
    s.FrameToKeyframeConfig: (_ordered("min_depth_m", "max_depth_m"),),
    s.SdfSlamConfig: (_ordered("min_depth_m", "max_depth_m"),),
    s.SlamConfig: (_ordered("min_frames", "max_frames", strict=False),),
    s.ImuConfig: (_ordered("refine_first_s", "refine_second_s"),),
    # The segmentation networks downsample by up to 32 (STDC's last stage).
    s.SemanticsConfig: (_off_or_at_least("input_width", 32, "0 = native width; networks downsample by 32"),),
}


def _problem(rule: Rule, value: Any, integer: bool) -> str | None:
    """What is wrong with ``value`` under ``rule`` (None if nothing)."""
    if isinstance(rule, Num):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not rule.allows(float(value)):
            return f"expected {rule.describe(integer)}, got {value!r}"
        return None
    if isinstance(rule, OneOf):
        return None if value in rule.choices else f"expected one of {', '.join(rule.choices)}, got {value!r}"
    if isinstance(rule, Text):
        items = value if rule.many else [value]
        ok = isinstance(items, list) and all(isinstance(v, str) for v in items)
        return None if ok else f"expected {'a list of strings' if rule.many else 'a string'}, got {value!r}"
    items = value if rule.many else [value]
    if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
        return f"expected {'a list of names' if rule.many else 'a name'}, got {value!r}"
    for name in items:
        registry.resolve(rule.kind, name)  # ConfigError naming the key and the known names
    return None


def check_values(section: Any, where: str = "") -> None:
    """Every field of ``section`` (a config dataclass) and its sub-sections against its rule;
    ConfigError ``key: expected ..., got ...`` on the first value outside it."""
    rules = RULES.get(type(section), {})
    for f in dataclasses.fields(section):
        key = f"{where}.{f.name}" if where else f.name
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(value):
            check_values(value, key)
            continue
        rule = rules.get(f.name)
        if rule is None:
            continue  # booleans (the loader checks their type)
        problem = _problem(rule, value, f.type in (int, "int"))
        if problem is not None:
            raise ConfigError(f"{key}: {problem}")
    prefix = f"{where}." if where else ""
    for cross in CROSS_CHECKS.get(type(section), ()):
        problem = cross(section, prefix)
        if problem is not None:
            raise ConfigError(problem)
