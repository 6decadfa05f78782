"""OpenCV's ORB as the foundation extractor (ORB-SLAM's own distribution comes later)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.features.base import Keypoints, register_extractor


class OpenCvOrbExtractor:
    """cv2.ORB with ORB-SLAM's pyramid settings (8 levels, scale 1.2, FAST threshold 20)."""

    def __init__(self, cfg: FeatureConfig) -> None:
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


@register_extractor("orb_opencv")
def _make(cfg: FeatureConfig) -> OpenCvOrbExtractor:
    return OpenCvOrbExtractor(cfg)
