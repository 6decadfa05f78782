"""SDF-SLAM's FPFDCNN (``nets/fpfdcnn.py``) as an extractor: float32 256-d descriptors
compared by L2, one pyramid level.

Keypoints: the network's per-pixel probability map, local maxima in a 5x5 window
(``nets.outputs.NMS_RADIUS`` = 2, measured there) above ``THRESHOLD``, outside the mask (0 = forbidden, the dynamic
mask tracking passes), the ``n_features`` most probable first. The network sees the
whole image once (no pyramid: it was trained at one scale), so the spec has one level;
``scale_factor`` 1.2 only gives the core's level tables their usual meaning (unused with
one level). Angles are 0: the descriptors are not rotation-normalised, so ORB-SLAM's
rotation-consistency histogram sees one bin.

Descriptors are unit length (distances in [0, 2]). ``TH_LOW`` / ``TH_HIGH`` (ORB-SLAM's
TH_LOW / TH_HIGH) are the distances accepting as many keypoint pairs of unrelated images
as ORB's 50 / 100 bits do (0.049 % / 14 % of 45 M pairs, the rule ``features/sift.py``
uses), measured for the shipped weights by ``python benchmarks/sift_thresholds.py --other
fpfdcnn``: 0.62 / 1.21 for the weights shipped 2026-11-29 (cell-softmax detector; at those
98.5 % / 100 % of the true matches of freiburg2_desk pairs 3 and 10 frames apart are kept,
ORB 52 % / 84 %). The earlier weights measured 0.55 / 1.20 (9x9 NMS window) and 0.51 / 1.18
(5x5).

Weights (``semslam/data/fpfdcnn.onnx``, run by ONNX Runtime without torch, unless given:
an ``.onnx`` from ``semslam export-onnx`` or a ``.pt`` checkpoint, which torch runs) are
loaded at the first ``extract``, so building an extractor (e.g. to read its spec) needs
neither the session's time nor the file; a missing file is one ``DataError`` line naming it.
The network's graph gives the probability map and the coarse descriptor map
(``nets.onnx_graphs``); points and descriptors are taken from them in NumPy
(``nets.outputs``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.features.inputs import check_extractor_inputs
from semslam.nets.outputs import NMS_RADIUS

if TYPE_CHECKING:
    from semslam.nets.onnx_runtime import Net

__all__ = ["DEFAULT_WEIGHTS", "FpfdcnnExtractor", "create_extractor"]

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "fpfdcnn.onnx"
DIM = 256
THRESHOLD = 0.015  # keypoint probability floor
#: A keypoint needs image structure: the strongest intensity gradient (Sobel, grey levels per
#: pixel) within 2 px must reach this. The shipped detector's probabilities do not separate
#: texture from none (a black frame gave 1000 points above THRESHOLD), as FAST's threshold does.
MIN_GRADIENT = 8.0
TH_LOW = 0.62  # see the module doc
TH_HIGH = 1.21


class FpfdcnnExtractor:
    """The ``n_features`` most probable FPFDCNN points with their descriptors."""

    def __init__(self, n_features: int = 1000, weights: str | Path | None = None,
                 threshold: float = THRESHOLD, nms_radius: int = NMS_RADIUS) -> None:
        if n_features < 0:
            raise ValueError("need n_features >= 0")
        self.n_features = int(n_features)
        self.weights = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        self.threshold = float(threshold)
        self.nms_radius = int(nms_radius)
        self.spec = FeatureSpec(DescriptorKind.FLOAT, DIM, 1.2, 1, th_low=TH_LOW, th_high=TH_HIGH)
        self._model: Net | None = None
        self.meta: dict[str, Any] = {}

    @property
    def model(self) -> "Net":
        """The network (loaded on first use)."""
        if self._model is None:
            from semslam.nets.onnx_load import load_net

            self._model = load_net(self.weights, "fpfdcnn")
            self.meta = self._model.meta
        return self._model

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        from semslam.nets.outputs import CELL, descriptors_at, select_points

        gray, mask = check_extractor_inputs(gray, mask)
        model = self.model
        if gray.size == 0 or self.n_features == 0:
            return Keypoints.empty(DIM, np.float32)
        h, w = gray.shape
        textured = structure_mask(gray)
        mask = textured if mask is None else np.where(textured > 0, mask, 0).astype(np.uint8)
        if not textured.any():  # a covered lens, a blank wall: nothing to detect
            return Keypoints.empty(DIM, np.float32)
        ph, pw = -h % CELL, -w % CELL  # the network needs sides that are multiples of 16
        padded = np.pad(gray, ((0, ph), (0, pw)), mode="edge") if ph or pw else gray
        prob, coarse = model.run(padded[None, None])
        xy, p = select_points(prob[0, 0, :h, :w], self.n_features, self.threshold, self.nms_radius, mask)
        desc = descriptors_at(coarse[0], xy, CELL)
        n = len(xy)
        return Keypoints(xy=xy, octave=np.zeros(n, np.int32), response=p, angle=np.zeros(n, np.float32),
                         descriptors=np.ascontiguousarray(desc, np.float32))


def structure_mask(gray: NDArray[np.uint8], min_gradient: float = MIN_GRADIENT) -> NDArray[np.uint8]:
    """255 where the image has a gradient of at least ``min_gradient`` within 2 px, else 0."""
    import cv2

    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.dilate(cv2.magnitude(gx, gy), np.ones((5, 5), np.uint8))
    return np.where(mag >= 8.0 * min_gradient, 255, 0).astype(np.uint8)  # 3x3 Sobel = 8 x the slope per pixel


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None) -> FpfdcnnExtractor:
    """The registry's factory (``features.extractor: fpfdcnn``): ``cfg.n_features`` points
    with ``cfg.weights`` (empty: the shipped ones); ORB's pyramid and FAST settings do not apply."""
    return FpfdcnnExtractor(cfg.n_features, cfg.weights or None)
