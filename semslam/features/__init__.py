"""Keypoint extractors and descriptor matchers, found by name through ``semslam.core.registry``.

``create_extractor(cfg)`` is the one call to make an extractor; its ``spec`` says what
its descriptors are, and ``matching.matcher_for(spec)`` gives the matcher for them;
``create_matcher(cfg, spec)`` the frame-to-frame matcher ``features.matcher`` selects.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from semslam.core import registry

if TYPE_CHECKING:
    from semslam.config import FeatureConfig
    from semslam.core.protocols import Extractor, Matcher
    from semslam.core.types import FeatureSpec


def create_extractor(cfg: "FeatureConfig", image_size: tuple[int, int] | None = None
                     ) -> "Extractor":
    """The extractor ``cfg.extractor`` names (ConfigError if unknown); ``image_size`` is
    (width, height) where known (qtree_orb's eq. 2 level count depends on it)."""
    return registry.create("extractor", cfg.extractor, cfg, image_size)


def feature_spec(cfg: "FeatureConfig", image_size: tuple[int, int] | None = None) -> "FeatureSpec":
    """What the configured extractor's descriptors and pyramid are, without keeping it
    (extractors are cheap to make: detectors and tables, no images)."""
    return create_extractor(cfg, image_size).spec


def create_matcher(cfg: "FeatureConfig", spec: "FeatureSpec") -> "Matcher":
    """The frame-to-frame matcher ``cfg.matcher`` selects: ``default`` is the descriptor
    kind's matcher (``matching.matcher_for``), ``range`` SDF-SLAM's window matcher (eq. 8;
    float descriptors only: ConfigError otherwise)."""
    from semslam.core.types import DescriptorKind
    from semslam.errors import ConfigError
    from semslam.features.matching import matcher_for

    if cfg.matcher == "default":
        return matcher_for(spec)
    if spec.kind is not DescriptorKind.FLOAT:
        raise ConfigError(f"features.matcher: {cfg.matcher!r} compares float descriptors by L2, "
                          f"but features.extractor {cfg.extractor!r} gives {spec.kind.value} ones")
    return registry.create("matcher", cfg.matcher)
