"""The semantics layer: segmenters (pluggable backends) and a-priori dynamic classes.

``create_segmenter(cfg).segment(rgb, frame)`` gives a LabelMap; ``dynamic_mask`` turns
it into the dynamic pixels by class name. Backends are imported only when chosen.
STDC-SLAM's depth refinement of the mask (SRM) is in ``semslam.dynamics.srm``.
"""

from semslam.semantics.base import (
    available_segmenters,
    create_segmenter,
    dynamic_ids,
    dynamic_mask,
)
from semslam.core.protocols import Segmenter
from semslam.core.types import LabelMap
from semslam.config import SemanticsConfig
from semslam.core.labels import DDL_SLAM_DYNAMIC_CLASSES, SYNTH_CLASSES, VOC_CLASSES

__all__ = [
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
]
