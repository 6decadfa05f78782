"""ORB extraction as ORB-SLAM2/3 does it (``ORBextractor.cc``), with OpenCV (resize) and
compiled numba kernels for the rest: scale pyramid, FAST per ~30 px cell with a
lower threshold for empty cells, quadtree distribution, intensity-centroid orientation,
steered rBRIEF on the blurred level image.

Why not ``cv2.ORB``: OpenCV keeps the strongest Harris responses over the whole image,
which clusters keypoints on texture; ORB-SLAM's cells + quadtree spread them over the
image, which is what tracking and pose estimation need.

Stages and where they differ from ORB-SLAM (all else is meant to be identical):
- pyramid: ``semslam.features.orb.pyramid`` (each level resized from the previous one as
  in ORB-SLAM; all levels in one reused buffer with 3 px of reflect padding for the
  blur, instead of ORB-SLAM's EDGE_THRESHOLD padding that nothing reads);
- detection: exactly ORB-SLAM's. ORB-SLAM runs OpenCV's FAST (9-16, non-max
  suppression) on every ~30 px cell ROI, again with ``fast_min_threshold`` where
  nothing was found; so a corner's non-max suppression only sees neighbours inside its
  cell. ``semslam.features.orb.detect_levels`` does the same in one compiled call for
  all levels (``orb.fast_kernels``, a numba port of OpenCV's FAST): same keypoints,
  scores and order as the literal per-cell OpenCV calls of ``detect_level_reference``
  (``reference_detection=True``), checked on the real and synthetic test frames with
  and without mask. Why compiled: the per-cell calls (~70 per frame) and the
  ``cv2.KeyPoint`` objects they return cost more than the detection itself. (Earlier
  versions ran FAST once per level and so differed from ORB-SLAM at cell borders; that
  difference is gone.);
- mask: FAST's own mask (applied after its non-max suppression) so masked corners
  neither count for a cell nor reach the quadtree and the budget goes to allowed pixels;
- quadtree: ``semslam.features.orb.quadtree`` (``SplitRule.ORB_SLAM``, compiled; ties
  between equal-sized nodes broken by position instead of heap address);
- orientation: ``IC_Angle`` with ORB-SLAM's ``umax`` circle (compiled moments, exact
  integers) for all levels at once (levels stacked in one buffer,
  ``orb.pyramid.StackedPyramid``); ``cv2.phase`` gives OpenCV's ``fastAtan2`` (what
  ORB-SLAM calls);
- descriptors: ORB-SLAM's ``computeOrbDescriptor`` (pattern ``bit_pattern_31_`` from
  OpenCV's orb.cpp, the learned rBRIEF test pairs, round-half-even like ``cvRound``;
  each rotated offset is ``rint(fma(b, -y, a x))``, i.e. one product rounded and one
  fused, as the float32 BLAS product of the earlier numpy version did), compiled, for
  all levels at once; the 7x7 sigma-2 blur is one compiled call on the stacked levels'
  pixels (``orb.blur``: OpenCV's fixed-point 8-bit arithmetic, each level padded with
  BORDER_REFLECT_101, so the bytes of ORB-SLAM's per-level ``GaussianBlur``); bit ``k``
  of byte ``i`` is test ``8 i + k``.

The kernels live in ``semslam.features.orb`` (shared with ``qtree_orb``); this module is
the extractor that puts them together and its registry factory. Its constructor calls
``orb.warm_up()``, so the numba kernels are compiled (or loaded from numba's disk
cache) before the first frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.config import FeatureConfig
from semslam.core.types import FeatureSpec, Keypoints, orb_spec
from semslam.features.inputs import check_extractor_inputs
from semslam.features.orb import (
    BORDER,
    Scratch,
    StackedPyramid,
    SteeredBrief,
    build_pyramid,
    detect_level_reference,
    detect_levels,
    detection_levels,
    distribute_quadtree_levels,
    features_per_level,
    inv_level_sigma2,
    level0_xy,
    level_mask_samplers,
    level_masks,
    level_sigma2,
    region_sizes,
    scale_factors,
    warm_up,
)
from semslam.features.orb.timing import StageClock

__all__ = ["OrbSlamExtractor", "create_extractor"]

_STAGES = ("pyramid", "fast_cells", "quadtree", "orientation", "blur", "descriptors")


class OrbSlamExtractor:
    """ORB-SLAM2/3's ORB extractor (defaults: 1000 features, 8 levels x 1.2, FAST 20/7).

    ``extract(gray, mask)`` returns keypoints level by level (ORB-SLAM's output order),
    positions in level-0 pixels (``level pixel * s^level``, float32), ``octave`` = level,
    FAST score as response, angle in degrees, 32-byte descriptors. ``mask`` (same size,
    0 = forbidden) drops keypoints whose nearest level-0 pixel is forbidden before the
    distribution, so the budget still goes to allowed pixels.

    ``reference_detection=True`` runs ORB-SLAM's literal per-cell OpenCV FAST calls
    instead of the compiled detection (same output, slow; kept to check it against)."""

    def __init__(self, n_features: int = 1000, scale_factor: float = 1.2, n_levels: int = 8,
                 fast_threshold: int = 20, fast_min_threshold: int = 7, reference_detection: bool = False) -> None:
        if n_levels < 1 or scale_factor <= 1.0 or n_features < 0:
            raise ValueError("need n_levels >= 1, scale_factor > 1 and n_features >= 0")
        self.n_features = int(n_features)
        self.scale_factor = float(scale_factor)
        self.n_levels = int(n_levels)
        self.fast_threshold = int(fast_threshold)
        self.fast_min_threshold = int(fast_min_threshold)
        self.reference_detection = reference_detection
        self.spec: FeatureSpec = orb_spec(self.scale_factor, self.n_levels)
        self.scale_factors = scale_factors(self.n_levels, self.scale_factor)
        self.level_sigma2 = level_sigma2(self.n_levels, self.scale_factor)
        self.inv_level_sigma2 = inv_level_sigma2(self.n_levels, self.scale_factor)
        self.features_per_level = features_per_level(self.n_features, self.n_levels, self.scale_factor)
        warm_up()  # compile the kernels now, not in the first frame
        # Reused from frame to frame (an extractor is not meant to be shared by threads).
        self._scratch = Scratch()
        self._brief = SteeredBrief()
        self._pyramid_buffer: NDArray[np.uint8] | None = None
        self.last_pyramid: StackedPyramid | None = None
        # Wall and thread-CPU time of each stage of the last extract() (ms), for profiling.
        self.last_stage_ms: dict[str, float] = {}
        self.last_stage_cpu_ms: dict[str, float] = {}

    def extract(self, gray: NDArray[np.uint8], mask: NDArray[np.uint8] | None = None) -> Keypoints:
        gray, mask = check_extractor_inputs(gray, mask)
        if gray.size == 0 or self.n_features == 0:
            return Keypoints.empty()

        clock = StageClock()
        pyr = build_pyramid(gray, self.n_levels, self.scale_factor, pad=3, buffer=self._pyramid_buffer)
        self._pyramid_buffer = pyr.buffer
        self.last_pyramid = pyr  # the stereo matcher's SAD reads it (until the next extract)
        clock.lap()
        images = detection_levels(pyr.levels)
        n_used = len(images)
        if n_used == 0:
            return Keypoints.empty()
        if self.reference_detection:
            masks = level_masks(mask, images, self.scale_factors)
            found = [detect_level_reference(image, self.fast_threshold, self.fast_min_threshold,
                                            None if masks is None else masks[level])
                     for level, image in enumerate(images)]
            x, y, resp = (np.concatenate([f[i] for f in found]) for i in range(3))
            level = np.concatenate([np.full(len(f[0]), lvl, np.int64) for lvl, f in enumerate(found)])
        else:
            x, y, resp, level = detect_levels(images, self.fast_threshold, self.fast_min_threshold,
                                              level_mask_samplers(mask, images, self.scale_factors), self._scratch)
        widths, heights = region_sizes(images)
        clock.lap()
        keep = distribute_quadtree_levels(x, y, resp, level, widths, heights, self.features_per_level[:n_used],
                                          scratch=self._scratch)
        clock.lap()
        if len(keep) == 0:
            return Keypoints.empty()
        kx, ky, klv = x[keep] + BORDER, y[keep] + BORDER, level[keep]
        sx, sy = kx + pyr.pad, ky + pyr.rows[klv]
        angle, desc = self._brief.compute(pyr, sx, sy, clock)
        xy = level0_xy(kx, ky, klv, self.scale_factors)
        clock.lap()
        self.last_stage_ms, self.last_stage_cpu_ms = clock.stage_ms(_STAGES)
        return Keypoints(xy=xy, octave=klv.astype(np.int32), response=resp[keep].astype(np.float32),
                         angle=angle.astype(np.float32), descriptors=desc)


def create_extractor(cfg: FeatureConfig, image_size: tuple[int, int] | None = None
                     ) -> OrbSlamExtractor:
    """The registry's factory (``features.extractor: orb_slam2``); the image size is not needed."""
    return OrbSlamExtractor(cfg.n_features, cfg.scale_factor, cfg.n_levels, cfg.fast_threshold, cfg.fast_min_threshold)
