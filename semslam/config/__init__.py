"""The config tree (``schema``) and how presets and ``--set`` overrides fill it (``load``)."""

from semslam.config.load import (PRESET_DIR, available_presets, config_from_dict, config_to_dict, load_config,
                                 parse_override)
from semslam.config.schema import (
    SENSORS,
    DepthConfig,
    DynamicsConfig,
    FeatureConfig,
    FrameToKeyframeConfig,
    InpaintingConfig,
    MapsConfig,
    SdfSlamConfig,
    SemanticsConfig,
    SlamConfig,
    SystemConfig,
    TrackingConfig,
)

__all__ = [
    "PRESET_DIR", "SENSORS", "DepthConfig", "DynamicsConfig", "InpaintingConfig", "MapsConfig", "SdfSlamConfig", "FeatureConfig", "FrameToKeyframeConfig", "SemanticsConfig",
    "SlamConfig", "SystemConfig", "TrackingConfig", "available_presets", "config_from_dict", "config_to_dict", "load_config",
    "parse_override",
]
