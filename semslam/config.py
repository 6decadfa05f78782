"""One config tree for the whole system; presets are YAML files that set fields of it.

``load_config("orb", overrides=["tracking.min_inliers=30"])`` reads
``semslam/presets/orb.yaml`` (or a YAML path), applies ``--set`` overrides and checks
every key, so a typo in a preset is an error instead of a silently ignored setting.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from semslam.errors import ConfigError
from semslam.semantics.config import SemanticsConfig

PRESET_DIR = Path(__file__).parent / "presets"


@dataclass
class FeatureConfig:
    """Keypoint extractor. Defaults are ORB-SLAM2's for 640x480 RGB-D."""

    extractor: str = "orb_opencv"
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20
    fast_min_threshold: int = 7


@dataclass
class TrackingConfig:
    """Frame-to-keyframe tracking with PnP-RANSAC on depth-backed keyframe points."""

    method: str = "frame_to_keyframe"
    # Hamming distances: ORB-SLAM uses TH_LOW=50 for guided search, TH_HIGH=100 otherwise.
    max_hamming: int = 64
    ratio: float = 0.8
    # Search radius in pixels around the motion-model prediction (ORB-SLAM: 7-15 px x scale).
    search_radius_px: float = 24.0
    # After an unguided pose, re-match by projection within this radius (ORB-SLAM: 10 px).
    refine_radius_px: float = 10.0
    ransac_reprojection_px: float = 3.0
    ransac_iterations: int = 200
    ransac_confidence: float = 0.999
    # A matched point whose measured depth disagrees with the estimated pose by more than
    # this (metres, plus 3 % of depth for Kinect noise) is an outlier.
    depth_check_m: float = 0.05
    min_inliers: int = 20
    # Without a motion prior a wrong pose can gather a few dozen inliers; ORB-SLAM's
    # relocalisation asks for 50.
    min_inliers_unguided: int = 50
    min_depth_m: float = 0.2
    max_depth_m: float = 6.0
    # New keyframe when the tracked points fall below this or the camera moved this far.
    keyframe_min_inliers: int = 200
    keyframe_max_translation_m: float = 0.25
    keyframe_max_rotation_deg: float = 15.0


@dataclass
class SlamConfig:
    """ORB-SLAM2-class core (tracking.method = orb_slam). Defaults are ORB-SLAM2's TUM RGB-D settings."""

    # Virtual stereo baseline x fx (ORB-SLAM TUM yaml Camera.bf = 40): ur = u - bf / z.
    bf: float = 40.0
    # Close/far depth threshold in baselines (ThDepth = 40): close if z < th_depth * bf / fx.
    th_depth: float = 40.0
    # Keyframe insertion: at most every max_frames frames without one (ORB-SLAM: fps).
    min_frames: int = 0
    max_frames: int = 30
    min_init_keypoints: int = 500
    local_mapping: bool = True
    local_ba: bool = True
    # ORB-SLAM optimises all covisible keyframes; when keyframes pile up (a large mover
    # makes tracking weak), that grew to seconds per BA here. Cap the window (best
    # covisibles first) and the fixed keyframes (most observations first).
    local_ba_max_keyframes: int = 20
    local_ba_max_fixed: int = 20
    triangulation: bool = True
    keyframe_culling: bool = True
    loop_closing: bool = True
    global_ba: bool = True
    # Loop detection: keyframes since the last loop before a new one is searched.
    loop_min_keyframes: int = 10
    loop_consistency: int = 3
    loop_min_matches: int = 40
    vocabulary: str = "default"
    # Run local mapping and loop closing as threads (ORB-SLAM) or inline (deterministic).
    sequential: bool = False
    localization_only: bool = False


@dataclass
class DynamicsConfig:
    """What to do about moving content (DDL-SLAM, STDC-SLAM). Off in the plain presets."""

    # Reject keypoints on a-priori dynamic classes found by the segmenter (semantics: section).
    semantic: bool = False
    # Reject keypoints in a band this wide around dynamic masks (DDL-SLAM: mask borders).
    border_px: int = 8
    # DDL-SLAM's multi-view geometry check against the best-overlapping keyframes.
    multiview: bool = False
    multiview_keyframes: int = 5
    parallax_deg: float = 30.0
    depth_threshold_m: float = 0.15
    depth_threshold_rel: float = 0.03
    edge_m: float = 0.05


@dataclass
class SystemConfig:
    """Root of the config tree."""

    preset: str = "custom"
    sensor: str = "rgbd"
    seed: int = 0
    depth_scale: float = 5000.0
    features: FeatureConfig = field(default_factory=FeatureConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    semantics: SemanticsConfig = field(default_factory=SemanticsConfig)


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def _apply(obj: Any, values: dict[str, Any], where: str) -> None:
    """Set dataclass fields from a nested dict, refusing unknown keys and wrong types."""
    fields = {f.name: f for f in dataclasses.fields(obj)}
    for key, value in values.items():
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r} (known: {', '.join(sorted(fields))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}.{key}: expected a mapping")
            _apply(current, value, f"{where}.{key}")
            continue
        setattr(obj, key, _coerce(value, current, f"{where}.{key}"))


def _coerce(value: Any, current: Any, where: str) -> Any:
    if isinstance(current, bool):
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if isinstance(current, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if isinstance(current, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    if isinstance(current, str):
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    if isinstance(current, list):
        if isinstance(value, list):
            return value
        raise ConfigError(f"{where}: expected a list, got {value!r}")
    return value


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def parse_override(text: str) -> tuple[list[str], Any]:
    """``section.key=value`` with the value parsed as YAML (numbers, booleans, lists)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        value = raw
    return key.strip().split("."), value


def load_config(preset: str | Path = "default", overrides: list[str] | None = None) -> SystemConfig:
    """Config of a named preset (or a YAML file) with ``--set`` overrides applied."""
    path = Path(preset)
    if path.suffix not in (".yaml", ".yml"):
        path = PRESET_DIR / f"{preset}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown preset {preset!r} (available: {', '.join(available_presets())})")
    elif not path.is_file():
        raise ConfigError(f"{path}: preset file not found")
    data = _read_yaml(path)
    base = data.pop("inherit", None)
    cfg = load_config(base) if base else SystemConfig()
    _apply(cfg, data, path.stem)
    cfg.preset = data.get("preset", path.stem)
    for text in overrides or []:
        keys, value = parse_override(text)
        nested: dict[str, Any] = {keys[-1]: value}
        for k in reversed(keys[:-1]):
            nested = {k: nested}
        _apply(cfg, nested, "--set")
    return cfg


def config_to_dict(cfg: SystemConfig) -> dict[str, Any]:
    return dataclasses.asdict(cfg)
