"""Keypoint extractors and descriptor matchers, found by name through ``semslam.core.registry``.

``create_extractor(cfg)`` is the one call to make an extractor; its ``spec`` says what
its descriptors are, and ``matching.matcher_for(spec)`` gives the matcher for them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from semslam.core import registry

if TYPE_CHECKING:
    from semslam.config import FeatureConfig
    from semslam.core.protocols import Extractor
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
