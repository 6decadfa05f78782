"""STDC-SLAM's improved Qtree-ORB extractor (Hu et al., "STDC-SLAM", IEEE Access 2023,
section III.C): ORB-SLAM's extractor with (1) a pyramid whose depth follows the image
size and per-level budgets proportional to level *area*, (2) a two-threshold FAST
detection that only falls back to the low threshold when the high one cannot fill the
level's budget, (3) a quadtree that only splits nodes holding a high-quality point and
(4) Harris instead of the FAST score to pick each node's point.

Why: ORB-SLAM's quadtree spreads the points so evenly that it keeps many weak (low
threshold) corners in texture-poor cells; the paper trades a little uniformity for more
strong corners (its Table 2: 155 -> 183 high, 63 -> 35 low of ~218 per frame).

What is reused (imported from ``semslam.features.orb``, not copied): the stacked pyramid,
the compiled FAST and ORB-SLAM's cell grid and detection region, the compiled quadtree
(Algorithm 3 is its ``SplitRule.HIGH_QUALITY``), IC angle and steered rBRIEF. Every
per-pixel and per-keypoint loop runs compiled (numba): Algorithm 2 in one call for all
levels (``semslam.features.qtree_detection``, on the FAST kernels of ``orb.fast_kernels``),
Harris at the candidates (``orb.harris``). ``QtreeOrbExtractor(reference=True)`` runs
the numpy versions they replaced instead (Algorithm 2's Python loop, Harris by matmul);
same keypoints and descriptors (tests), 2-3x slower.

The paper's equations and how ``s`` relates to ORB-SLAM's ``scale_factor``:
- eq. 2: ``M = Round(max(W, H) / 100)`` levels (6 at 640x480, 12 at 1241x376);
- eq. 3-5: level ``i`` has area ``HW (s^2)^i``, so ``s`` is the *linear* size ratio of
  consecutive levels, ``s = 1 / scale_factor`` (0.833 for ORB-SLAM's 1.2) and ``s^2 =
  1 / 1.44`` is the area ratio; ``N_i = N (1 - s^2) / (1 - (s^2)^M) (s^2)^i`` is a
  geometric series summing to ``N`` (1000, 6 levels, 1.2 -> 344 239 166 115 80 56).
  ORB-SLAM instead uses the linear ratio ``1/s`` per level (217 181 ... 60 for 8
  levels), i.e. budgets per unit *length*; ``budget="orb_slam"`` selects that.

Choices where the paper is vague (all commented where they are made):
- Algorithm 2 regions are ORB-SLAM's ~30 px FAST cells; FAST (the compiled OpenCV FAST
  of ``orb.fast_points``) runs once per level on the whole detection region and points
  are assigned to the cells (so, unlike ORB-SLAM's per-cell FAST, non-max suppression
  can see across cell boundaries; the paper does not say). The low-threshold pass is
  one FAST call at ``T_L`` on the region; its points with score >= ``T_H`` are exactly
  the high pass's points (OpenCV's FAST score does not depend on the threshold and a
  pixel is a corner at ``t`` iff its score >= ``t``; checked in the tests), the others
  form ``P^L``. Algorithm 2 inserts ``P^L_j`` cell by cell in raster order and stops
  as soon as ``|P^H| + |P^L| >= N_i`` (lines 8-16): we keep exactly those cells' low
  points (literal; it favours the top of the level). Text and Algorithm 2 line 7
  disagree on ``N^H == N_i`` (text: done, code: ``<=`` runs the low pass); we follow
  the text.
- Algorithm 3 stops when nodes > ``N_i^T`` (``while N^n <= N_i^T``) and has no way to
  stop when nothing can split; we stop at nodes >= ``N_i`` (ORB-SLAM's rule, so both
  extractors aim at the same count) or when no node can split. A full pass can
  overshoot ``N_i`` up to 4x; the paper says nothing, its Table 2 shows the same T as
  ORB-SLAM, so we keep ORB-SLAM's last phase: when the next pass could overshoot, split
  the splittable nodes with the most points first, one at a time, until ``N_i`` (may
  overshoot by <= 3). A node of 1x1 px is never split (it cannot separate points).
- Harris: OpenCV ORB's ``HarrisResponses`` (7x7 block of 3x3 Sobel gradients,
  k = 0.04, same scaling, integer sums) on the level image, evaluated at the candidate
  points only (``cv2.cornerHarris`` over all levels costs ~15 ms).
- Quality of a kept point: high iff its FAST score >= ``T_H`` (i.e. it is in ``P^H``).
  The same rule classifies ORB-SLAM's keypoints (their response is the FAST score),
  see ``fast_quality``.

Consequences worth knowing: on textured 640x480 frames every level has ``|P^H| >= N_i``,
so the low pass never runs and no low-quality point is kept; on texture-poor frames a
level can end with fewer than ``N_i`` points, because nodes holding only low-quality
points are never split (one point each). With eq. 2 the number of levels depends on
the image size (6 at 640x480, 12 at 1241x376); the extractor's ``spec`` says the
pyramid it really extracts with, and the SLAM core sizes its per-level tables from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import FeatureSpec, Keypoints, orb_spec
from semslam.features.inputs import check_extractor_inputs
from semslam.features.orb import (
    BORDER,
    Scratch,
    SplitRule,
    StackedPyramid,
    SteeredBrief,
    build_pyramid,
    detection_levels,
    distribute_quadtree_leaves,
    features_per_level,
    harris_responses,
    harris_responses_numpy,
    level0_xy,
    level_mask_samplers,
    region_sizes,
    scale_factors,
    warm_up,
)
from semslam.features.orb.timing import StageClock
from semslam.features.qtree_detection import Detection, detect_two_thresholds, detect_two_thresholds_numpy

__all__ = [
    "Detection", "QtreeOrbCounts", "QtreeOrbExtractor", "detect_two_thresholds", "detect_two_thresholds_numpy",
    "distribute_improved_quadtree", "harris_responses", "harris_responses_numpy",
    "distribution_uniformity", "fast_quality", "levels_for_image", "paper_features_per_level",
    "create_extractor",
]

PIXELS_PER_LEVEL = 100  # eq. 2's divisor
_STAGES = ("pyramid", "fast", "harris", "quadtree", "orientation", "blur", "descriptors")


# --------------------------------------------------------------------------- eq. 2-5

def levels_for_image(width: int, height: int) -> int:
    """Eq. 2: ``M = Round(max(W, H) / 100)`` (round half up), at least 1."""
    return max(1, int(math.floor(max(width, height) / PIXELS_PER_LEVEL + 0.5)))


def paper_features_per_level(n_features: int, n_levels: int, scale_factor: float) -> NDArray[np.int64]:
    """Eq. 5: ``N_i = N (1 - s^2) / (1 - (s^2)^M) (s^2)^i`` with ``s = 1 / scale_factor``,
    rounded half to even, the remainder going to the last level so the sum is exactly
    ``N`` (as ORB-SLAM does with its own formula). Decreasing for ``scale_factor > 1``."""
    if n_levels < 1:
        raise ValueError("n_levels must be >= 1")
    if n_levels == 1:
        return np.array([n_features], np.int64)
    q = 1.0 / float(scale_factor) ** 2  # s^2: area ratio of consecutive levels
    exact = n_features * (1.0 - q) / (1.0 - q**n_levels) * q ** np.arange(n_levels)
    counts = np.rint(exact).astype(np.int64)
    counts[-1] = max(n_features - int(counts[:-1].sum()), 0)
    return counts


# --------------------------------------------------------------------------- Algorithm 3

def distribute_improved_quadtree(x: NDArray[np.integer], y: NDArray[np.integer], response: NDArray[np.floating],
                                 high: NDArray[np.bool_], level: NDArray[np.integer], widths: NDArray[np.integer],
                                 heights: NDArray[np.integer], n_wanted: NDArray[np.integer],
                                 scratch: Scratch | None = None) -> tuple[NDArray[np.intp], NDArray[np.int64]]:
    """Algorithm 3 for all levels at once: the indices (sorted) of the kept points and
    every point's final leaf (-1 for levels with ``n_wanted <= 0``, which keep nothing).

    ``semslam.features.orb.distribute_quadtree_leaves`` with ``SplitRule.HIGH_QUALITY``:
    same frame, initial nodes, split lines, ORB-SLAM-style last phase and tie rule
    (first in input order) as ORB-SLAM's quadtree; the differences:
    a node is split only if it holds > 1 points *and* >= 1 high-quality point and is
    larger than 1x1 px; the level stops at ``n_wanted`` nodes or when no node can split
    (instead of ORB-SLAM's "a pass changed nothing"); ``response`` is Harris."""
    return distribute_quadtree_leaves(x, y, response, level, widths, heights, n_wanted, high,
                                      SplitRule.HIGH_QUALITY, scratch)


# --------------------------------------------------------------------------- metrics

def fast_quality(keypoints: Keypoints, fast_threshold: int = 20) -> NDArray[np.bool_]:
    """High-quality flag of keypoints whose ``response`` is the FAST score (ORB-SLAM's
    extractor): score >= ``T_H``. Same rule as ``QtreeOrbExtractor.last_quality``."""
    return np.asarray(keypoints.response) >= fast_threshold


def distribution_uniformity(xy: NDArray[np.floating], width: int, height: int) -> float:
    """Uniformity ``U`` of a point set (larger = less uniform).

    STDC-SLAM cites Yao et al. 2020 (Comput. Eng. Des. 41(6)) for it; that paper was not
    available, so this is the measure commonly used in that literature: split the image
    in 5 ways into two parts of equal area -- left/right, top/bottom, either side of each
    image diagonal, and a centred rectangle of sides ``W/sqrt(2)`` x ``H/sqrt(2)``
    (half the area) against the rest -- count the points in the 10 parts and return the
    population variance of the 10 counts. Uniformly random points give about ``T/4``;
    a point exactly on a dividing line goes to the right / bottom / outer part."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return 0.0
    u, v = xy[:, 0] / width, xy[:, 1] / height  # normalised so every split halves the area
    c = 0.5 / math.sqrt(2.0)
    parts = [
        u < 0.5,                                  # vertical line
        v < 0.5,                                  # horizontal line
        v < u,                                    # main diagonal (top-left to bottom-right)
        u + v < 1.0,                              # anti-diagonal
        (np.abs(u - 0.5) < c) & (np.abs(v - 0.5) < c),  # centre vs periphery
    ]
    n = len(xy)
    counts = np.array([[int(p.sum()), n - int(p.sum())] for p in parts], np.float64).reshape(-1)
    return float(counts.var())


# --------------------------------------------------------------------------- extractor

@dataclass
class QtreeOrbCounts:
    """Per-level numbers of the last frame: budget ``N_i``, detected ``|P^H|`` and
    inserted ``|P^L|``, and the kept high / low points; ``H``, ``L``, ``T`` are the
    frame totals of kept points (the paper's Table 2 columns)."""

    n_wanted: list[int] = field(default_factory=list)
    detected_high: list[int] = field(default_factory=list)
    detected_low: list[int] = field(default_factory=list)
    kept_high: list[int] = field(default_factory=list)
    kept_low: list[int] = field(default_factory=list)

    @property
    def H(self) -> int:  # noqa: N802  (the paper's names)
        return int(sum(self.kept_high))

    @property
    def L(self) -> int:  # noqa: N802
        return int(sum(self.kept_low))

    @property
    def T(self) -> int:  # noqa: N802
        return self.H + self.L

    def as_dict(self) -> dict[str, Any]:
        return {"n_wanted": self.n_wanted, "detected_high": self.detected_high, "detected_low": self.detected_low,
                "kept_high": self.kept_high, "kept_low": self.kept_low, "H": self.H, "L": self.L, "T": self.T}


class QtreeOrbExtractor:
    """STDC-SLAM's improved Qtree-ORB (defaults: 1000 features, scale 1.2, FAST 20/7,
    ``M`` levels from eq. 2, budgets from eq. 5).

    ``extract(gray, mask)`` returns ``Keypoints`` like ``OrbSlamExtractor``: level by
    level, positions in level-0 px (``level px * scale_factor^level``), ``octave`` =
    level, ``response`` = Harris, IC angle in degrees, 32-byte steered rBRIEF. ``mask``
    (0 = forbidden) drops keypoints before Algorithms 2 and 3, so they neither count for
    the budget nor reach the quadtree.

    After each call: ``last_quality`` (bool per returned keypoint, True = high quality,
    i.e. FAST score >= ``T_H``), ``last_fast_score`` (float32 per keypoint),
    ``last_counts`` (``QtreeOrbCounts``), ``last_stage_ms`` and ``last_stage_cpu_ms``.

    ``levels_from_image_size=False`` uses ``n_levels`` instead of eq. 2;
    ``budget="orb_slam"`` uses ORB-SLAM's per-level budgets instead of eq. 5.
    ``image_size`` (width, height) fixes the image size: with eq. 2 the pyramid, hence
    ``spec``, depends on it, so ``spec`` needs it and ``extract`` then refuses other sizes.
    ``reference=True`` runs Algorithm 2 and Harris in numpy (the versions the compiled
    ones replaced; same output, slower; kept to check against)."""

    def __init__(self, n_features: int = 1000, scale_factor: float = 1.2, n_levels: int = 8,
                 fast_threshold: int = 20, fast_min_threshold: int = 7, levels_from_image_size: bool = True,
                 budget: Literal["paper", "orb_slam"] = "paper",
                 image_size: tuple[int, int] | None = None, reference: bool = False) -> None:
        if n_levels < 1 or scale_factor <= 1.0 or n_features < 0:
            raise ValueError("need n_levels >= 1, scale_factor > 1 and n_features >= 0")
        if not 0 < fast_min_threshold <= fast_threshold:
            raise ValueError("need 0 < fast_min_threshold <= fast_threshold")
        if budget not in ("paper", "orb_slam"):
            raise ValueError(f"budget must be 'paper' or 'orb_slam', got {budget!r}")
        self.n_features = int(n_features)
        self.scale_factor = float(scale_factor)
        self.n_levels = int(n_levels)
        self.fast_threshold = int(fast_threshold)
        self.fast_min_threshold = int(fast_min_threshold)
        self.levels_from_image_size = bool(levels_from_image_size)
        self.budget = budget
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        self.reference = bool(reference)
        self._detect = detect_two_thresholds_numpy if reference else detect_two_thresholds
        self._harris = harris_responses_numpy if reference else harris_responses
        warm_up()  # compile the kernels now, not in the first frame
        self._brief = SteeredBrief()
        self._pyramid_buffer: NDArray[np.uint8] | None = None
        self.last_pyramid: StackedPyramid | None = None
        self.last_quality: NDArray[np.bool_] = np.zeros(0, bool)
        self.last_fast_score: NDArray[np.float32] = np.zeros(0, np.float32)
        self.last_counts = QtreeOrbCounts()
        self.last_stage_ms: dict[str, float] = {}
        self.last_stage_cpu_ms: dict[str, float] = {}

    @property
    def spec(self) -> FeatureSpec:
        """ORB descriptors on the pyramid this extractor really uses: eq. 2's level count
        for ``image_size`` when it is on, else ``n_levels``."""
        if not self.levels_from_image_size:
            return orb_spec(self.scale_factor, self.n_levels)
        if self.image_size is None:
            raise ValueError("qtree_orb with eq. 2 levels needs image_size to know its pyramid")
        return orb_spec(self.scale_factor, self.levels_for(*self.image_size))

    def levels_for(self, width: int, height: int) -> int:
        """Number of pyramid levels for an image (eq. 2, or ``n_levels``)."""
        return levels_for_image(width, height) if self.levels_from_image_size else self.n_levels

    def features_per_level(self, width: int, height: int) -> NDArray[np.int64]:
        """The per-level budgets ``N_i`` for an image (eq. 5, or ORB-SLAM's)."""
        m = self.levels_for(width, height)
        if self.budget == "paper":
            return paper_features_per_level(self.n_features, m, self.scale_factor)
        return features_per_level(self.n_features, m, self.scale_factor)

    def _reset(self) -> Keypoints:
        self.last_quality = np.zeros(0, bool)
        self.last_fast_score = np.zeros(0, np.float32)
        self.last_counts = QtreeOrbCounts()
        return Keypoints.empty()

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        gray, mask = check_extractor_inputs(gray, mask)
        size = (gray.shape[1], gray.shape[0])
        if self.levels_from_image_size and self.image_size not in (None, size):
            w, h = self.image_size
            raise ValueError(f"qtree_orb was made for {w}x{h} images (eq. 2 levels), "
                             f"got {size[0]}x{size[1]}")
        if gray.size == 0 or self.n_features == 0:
            return self._reset()

        clock = StageClock()
        n_levels = self.levels_for(gray.shape[1], gray.shape[0])
        wanted_all = self.features_per_level(gray.shape[1], gray.shape[0])
        pyr = build_pyramid(gray, n_levels, self.scale_factor, pad=3, buffer=self._pyramid_buffer)
        self._pyramid_buffer = pyr.buffer
        self.last_pyramid = pyr  # the stereo matcher's SAD reads it (until the next extract)
        scales = scale_factors(n_levels, self.scale_factor)
        clock.lap()
        images = detection_levels(pyr.levels)
        if not images:
            return self._reset()
        n_used = len(images)
        wanted = wanted_all[:n_used]
        masks = level_mask_samplers(mask, images, scales)
        det = self._detect(images, wanted, self.fast_threshold, self.fast_min_threshold, masks, self._brief.scratch)
        clock.lap()
        # Harris on the level images in the stacked buffer (the points are >= 19 px inside
        # their level, so the 9x9 windows never reach the padding or another level).
        sx_all, sy_all = det.x + BORDER + pyr.pad, det.y + BORDER + pyr.rows[det.level]
        harris = self._harris(pyr.buffer, sx_all, sy_all, scratch=self._brief.scratch)
        clock.lap()
        widths, heights = region_sizes(images)
        keep, _ = distribute_improved_quadtree(det.x, det.y, harris, det.high, det.level, widths, heights, wanted,
                                               self._brief.scratch)
        clock.lap()
        klv = det.level[keep]
        quality = det.high[keep]
        kept_high = np.bincount(klv[quality], minlength=n_used)
        kept_low = np.bincount(klv[~quality], minlength=n_used)
        self.last_counts = QtreeOrbCounts(wanted.tolist(), det.n_high.tolist(), det.n_low.tolist(),
                                          kept_high.tolist(), kept_low.tolist())
        if len(keep) == 0:
            self.last_quality = np.zeros(0, bool)
            self.last_fast_score = np.zeros(0, np.float32)
            return Keypoints.empty()
        kx, ky = det.x[keep] + BORDER, det.y[keep] + BORDER
        angle, desc = self._brief.compute(pyr, sx_all[keep], sy_all[keep], clock)
        xy = level0_xy(kx, ky, klv, scales)
        clock.lap()
        self.last_stage_ms, self.last_stage_cpu_ms = clock.stage_ms(_STAGES)
        self.last_quality = quality
        self.last_fast_score = det.score[keep].astype(np.float32)
        return Keypoints(xy=xy, octave=klv.astype(np.int32), response=harris[keep].astype(np.float32),
                         angle=angle.astype(np.float32), descriptors=desc)


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None
                     ) -> QtreeOrbExtractor:
    """The registry's factory (``features.extractor: qtree_orb``). With the image size
    (width, height) the level count is the paper's eq. 2 for it; without it,
    ``cfg.n_levels`` (the ``stdc`` preset sets 6, eq. 2's value at 640x480). Either way
    ``spec`` says the pyramid it extracts with."""
    return QtreeOrbExtractor(cfg.n_features, cfg.scale_factor, cfg.n_levels, cfg.fast_threshold,
                             cfg.fast_min_threshold, levels_from_image_size=image_size is not None,
                             image_size=image_size)
