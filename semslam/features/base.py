"""The extractor protocol and its registry: adding a backend is one file."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.errors import ConfigError


@dataclass
class Keypoints:
    """Keypoints of one image: pixel positions (as detected, distorted), pyramid level,
    detector response, orientation in degrees and one descriptor row per keypoint."""

    xy: NDArray[np.float32]
    octave: NDArray[np.int32]
    response: NDArray[np.float32]
    angle: NDArray[np.float32]
    descriptors: NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.xy)

    def subset(self, keep: NDArray[np.bool_] | NDArray[np.intp]) -> "Keypoints":
        return Keypoints(self.xy[keep], self.octave[keep], self.response[keep], self.angle[keep], self.descriptors[keep])

    @staticmethod
    def empty(descriptor_bytes: int = 32) -> "Keypoints":
        return Keypoints(
            np.zeros((0, 2), np.float32), np.zeros(0, np.int32), np.zeros(0, np.float32),
            np.zeros(0, np.float32), np.zeros((0, descriptor_bytes), np.uint8),
        )


class Extractor(Protocol):
    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints: ...


_REGISTRY: dict[str, Callable[[FeatureConfig], Extractor]] = {}


def register_extractor(name: str) -> Callable[[Callable[[FeatureConfig], Extractor]], Callable[[FeatureConfig], Extractor]]:
    def deco(factory: Callable[[FeatureConfig], Extractor]) -> Callable[[FeatureConfig], Extractor]:
        _REGISTRY[name] = factory
        return factory

    return deco


def create_extractor(cfg: FeatureConfig) -> Extractor:
    import semslam.features.orb_opencv  # noqa: F401  (each backend registers itself)
    import semslam.features.orb_slam  # noqa: F401
    import semslam.features.qtree_orb  # noqa: F401

    if cfg.extractor not in _REGISTRY:
        raise ConfigError(f"features.extractor: unknown extractor {cfg.extractor!r} (known: {', '.join(sorted(_REGISTRY))})")
    return _REGISTRY[cfg.extractor](cfg)
