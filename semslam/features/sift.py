"""OpenCV's SIFT (Lowe 2004) as an extractor: float32 128-d RootSIFT descriptors, compared
by L2. It exists to show that the SLAM core is descriptor-neutral.

Descriptors: RootSIFT (Arandjelovic & Zisserman 2012): each SIFT vector L1-normalised,
then square-rooted, so L2 between them is the Hellinger distance of the SIFT histograms
(it matches better than plain SIFT's L2) and every descriptor has unit length: distances
lie in [0, sqrt(2)], whatever the image contrast.

Pyramid: SIFT detects in octaves of ``SIFT_LAYERS = 3`` DoG layers each (OpenCV's
default), starting from the image upsampled 2x (octave -1), so consecutive layers differ
by ``2^(1/3) = 1.26`` in scale: that is the spec's ``scale_factor`` (close to ORB's 1.2, so
the core's search windows of one or two levels mean about the same). A keypoint of octave
``o`` and layer ``l`` (1..3) is at level ``3 (o + 1) + l - 1``: level 0 is the finest
layer, sigma ~1 px as ORB's level 0 (FAST at full resolution). ``N_LEVELS = 12`` covers
octaves -1..2 (scales 1 to 2^(11/3) = 12.7); on the 59 real test frames 98.7 % of SIFT's
1000 keypoints fall there, the few coarser ones are put at level 11. With that, the core's
level weights ``1 / s^(2 level)`` and search radii ``~ s^level`` follow each keypoint's
sampling step as they do for ORB. ``features.scale_factor`` / ``n_levels`` (ORB's
pyramid) are not used.

Thresholds (``th_low`` / ``th_high``, ORB-SLAM's TH_LOW / TH_HIGH): the RootSIFT distances
with the same false-accept rate per comparison as ORB's 50 / 100 bits, measured by
``benchmarks/sift_thresholds.py`` over 37-45 M keypoint pairs of images of different
scenes (no true match among them): ORB's 50 / 100 bits accept 0.048 % / 14 % of such
pairs, RootSIFT distances 0.39 / 0.75 accept the same. At those thresholds SIFT keeps
79 % / 90 % of its ground-truth matches on freiburg2_desk frame pairs 3 and 10 frames
apart (ORB: 52 % / 84 %), so SIFT is as strict against wrong matches and looser with
true ones, as a more distinctive descriptor should be.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.features.inputs import check_extractor_inputs

__all__ = ["N_LEVELS", "SCALE_FACTOR", "SIFT_LAYERS", "TH_HIGH", "TH_LOW", "SiftExtractor",
           "create_extractor", "root_sift", "sift_levels"]

SIFT_LAYERS = 3  # OpenCV's nOctaveLayers
SCALE_FACTOR = 2.0 ** (1.0 / SIFT_LAYERS)
N_LEVELS = 12  # octaves -1..2
TH_LOW = 0.39  # RootSIFT L2 accepting as many unrelated pairs as ORB's 50 bits (0.048 %)
TH_HIGH = 0.75  # ... and as ORB's 100 bits (14 %)
_DIM = 128


def sift_levels(octave: NDArray[np.integer]) -> NDArray[np.int32]:
    """Pyramid level of OpenCV SIFT keypoints from their packed ``KeyPoint.octave``
    (octave in the low byte, signed; layer 1..3 in the next), clipped to the spec's levels."""
    packed = np.asarray(octave, np.int64)
    o = packed & 255
    o = np.where(o >= 128, o - 256, o)
    layer = (packed >> 8) & 255
    return np.clip(SIFT_LAYERS * (o + 1) + layer - 1, 0, N_LEVELS - 1).astype(np.int32)


def root_sift(desc: NDArray[np.float32]) -> NDArray[np.float32]:
    """L1-normalise, then square root (unit L2 length)."""
    desc = np.asarray(desc, np.float32)
    return np.sqrt(desc / np.maximum(desc.sum(axis=1, keepdims=True), 1e-12)).astype(np.float32)


class SiftExtractor:
    """``cv2.SIFT`` with the ``n_features`` strongest keypoints; ``Keypoints`` with
    positions in pixels, ``octave`` = pyramid level (see the module doc), SIFT's response
    and orientation (degrees), RootSIFT descriptors. ``mask`` (0 = forbidden) is SIFT's."""

    def __init__(self, n_features: int = 1000) -> None:
        if n_features < 0:
            raise ValueError("need n_features >= 0")
        self.n_features = int(n_features)
        self.spec = FeatureSpec(DescriptorKind.FLOAT, _DIM, SCALE_FACTOR, N_LEVELS, th_low=TH_LOW,
                                th_high=TH_HIGH)
        self._sift = cv2.SIFT_create(nfeatures=self.n_features, nOctaveLayers=SIFT_LAYERS)

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        gray, mask = check_extractor_inputs(gray, mask)
        if gray.size == 0 or self.n_features == 0:
            return Keypoints.empty(_DIM, np.float32)
        kps, desc = self._sift.detectAndCompute(gray, mask)
        if not kps or desc is None:
            return Keypoints.empty(_DIM, np.float32)
        return Keypoints(
            xy=cv2.KeyPoint_convert(kps).astype(np.float32).reshape(-1, 2),
            octave=sift_levels(np.fromiter((k.octave for k in kps), np.int64, len(kps))),
            response=np.fromiter((k.response for k in kps), np.float32, len(kps)),
            angle=np.fromiter((k.angle for k in kps), np.float32, len(kps)),
            descriptors=root_sift(desc),
        )


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None
                     ) -> SiftExtractor:
    """The registry's factory (``features.extractor: sift``): ``cfg.n_features`` keypoints;
    ORB's pyramid settings and FAST thresholds do not apply; the image size is not needed."""
    return SiftExtractor(cfg.n_features)
