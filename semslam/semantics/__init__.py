"""The semantics layer: segmenters (pluggable backends), a-priori dynamic classes and
STDC-SLAM's depth-based Segmentation Refinement Module.

``create_segmenter(cfg).segment(rgb, frame)`` gives a LabelMap; ``dynamic_mask`` turns
it into the dynamic pixels by class name; ``refine_segmentation`` grows that mask along
continuous depth (SRM). Backends are imported only when chosen.
"""

from semslam.semantics.base import (
    BACKEND_MODULES,
    LabelMap,
    Segmenter,
    available_segmenters,
    create_segmenter,
    dynamic_ids,
    dynamic_mask,
    register_segmenter,
)
from semslam.semantics.config import SemanticsConfig
from semslam.semantics.labels import DDL_SLAM_DYNAMIC_CLASSES, SYNTH_CLASSES, VOC_CLASSES
from semslam.semantics.refinement import refine_brute_force, refine_segmentation

__all__ = [
    "BACKEND_MODULES",
    "DDL_SLAM_DYNAMIC_CLASSES",
    "SYNTH_CLASSES",
    "VOC_CLASSES",
    "LabelMap",
    "SemanticsConfig",
    "Segmenter",
    "available_segmenters",
    "create_segmenter",
    "dynamic_ids",
    "dynamic_mask",
    "refine_brute_force",
    "refine_segmentation",
    "register_segmenter",
]
