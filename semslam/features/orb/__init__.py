"""The ORB kernels both ORB extractors share (ORB-SLAM2's and STDC-SLAM's Qtree-ORB): the
scale pyramid, FAST detection per cell, the quadtree with its split rule, IC angle and
steered rBRIEF. Each extractor module is then only its own choices on top of these.

The per-pixel and per-keypoint work runs in numba kernels (``fast_kernels``,
``quadtree_kernels``, ``brief_kernels``, ``pyramid_kernels``, ``blur_kernels``, ``harris_kernels``: ``nogil``,
cached on disk;
``warm_up`` compiles them once per process); the numpy / OpenCV versions they replaced
are kept next to them as references (``fast_points_cv2``, ``detect_level_reference``,
``*_numpy``) and the tests check they agree exactly.
"""

from semslam.features.orb.descriptors import (
    BIT_PATTERN_31,
    PATCH,
    Scratch,
    SteeredBrief,
    ic_angles,
    ic_angles_numpy,
    orb_descriptors,
    orb_descriptors_numpy,
    umax,
)
from semslam.features.orb.detection import (
    BORDER,
    CELL_SIZE,
    EMPTY_DETECTION,
    CellGrid,
    cell_grid,
    detect_level,
    detect_level_reference,
    detect_levels,
    detect_levels_two_thresholds,
    detection_levels,
    detection_region,
    fast_points,
    fast_points_cv2,
    region_sizes,
)
from semslam.features.orb.harris import HARRIS_K, harris_responses, harris_responses_numpy
from semslam.features.orb.jit import warm_up
from semslam.features.orb.pyramid import (
    EDGE_THRESHOLD,
    HALF_PATCH_SIZE,
    PATCH_SIZE,
    MaskSampler,
    StackedPyramid,
    build_pyramid,
    features_per_level,
    inv_level_sigma2,
    inv_scale_factors,
    level0_xy,
    level_mask,
    level_mask_indices,
    level_mask_samplers,
    level_masks,
    level_sigma2,
    level_sizes,
    scale_factors,
)
from semslam.features.orb.quadtree import (
    SplitRule,
    distribute_quadtree,
    distribute_quadtree_leaves,
    distribute_quadtree_levels,
)

__all__ = [
    "BIT_PATTERN_31", "BORDER", "CELL_SIZE", "EDGE_THRESHOLD", "EMPTY_DETECTION", "HALF_PATCH_SIZE", "HARRIS_K",
    "MaskSampler", "PATCH", "PATCH_SIZE", "CellGrid", "Scratch", "SplitRule", "StackedPyramid", "SteeredBrief",
    "build_pyramid", "cell_grid", "detect_level", "detect_level_reference", "detect_levels", "detect_levels_two_thresholds",
    "detection_levels", "detection_region", "distribute_quadtree", "distribute_quadtree_leaves",
    "distribute_quadtree_levels", "fast_points", "fast_points_cv2", "features_per_level", "harris_responses", "harris_responses_numpy", "ic_angles", "ic_angles_numpy",
    "inv_level_sigma2", "inv_scale_factors", "level0_xy", "level_mask", "level_mask_indices",
    "level_mask_samplers", "level_masks",
    "level_sigma2", "level_sizes", "orb_descriptors", "orb_descriptors_numpy", "region_sizes", "scale_factors", "umax",
    "warm_up",
]
