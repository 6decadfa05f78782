"""OpenCV's ORB as the foundation extractor (ORB-SLAM's own distribution comes later)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import FeatureSpec, Keypoints, orb_spec


class OpenCvOrbExtractor:
    """cv2.ORB with ORB-SLAM's pyramid settings (8 levels, scale 1.2, FAST threshold 20)."""

    def __init__(self, cfg: FeatureConfig) -> None:
        self.spec: FeatureSpec = orb_spec(float(cfg.scale_factor), int(cfg.n_levels))
        self._orb = cv2.ORB_create(
            nfeatures=cfg.n_features,
            scaleFactor=cfg.scale_factor,
            nlevels=cfg.n_levels,
            fastThreshold=cfg.fast_threshold,
            edgeThreshold=19,
            patchSize=31,
        )

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        kps, desc = self._orb.detectAndCompute(gray, mask)
        if not kps or desc is None:
            return Keypoints.empty()
        return Keypoints(
            xy=np.array([k.pt for k in kps], dtype=np.float32),
            octave=np.array([k.octave for k in kps], dtype=np.int32),
            response=np.array([k.response for k in kps], dtype=np.float32),
            angle=np.array([k.angle for k in kps], dtype=np.float32),
            descriptors=desc,
        )


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None
                     ) -> OpenCvOrbExtractor:
    """The registry's factory (``features.extractor: orb_opencv``); the image size is not needed."""
    return OpenCvOrbExtractor(cfg)
