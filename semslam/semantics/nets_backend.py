"""The papers' own networks as segmenter backends: ``stdc`` (STDC-SLAM) and ``dunet``
(DDL-SLAM), with the small person models the project trains and ships
(``semslam/data/NETS.md``; run by ONNX Runtime, no torch) or the weights given in
``semantics.weights`` (``.onnx``, or a ``.pt`` checkpoint, which needs torch)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.types import LabelMap
from semslam.config import SemanticsConfig


class _NetSegmenter:
    """Adapts a ``semslam.nets`` segmenter to the Segmenter protocol."""

    def __init__(self, impl: Any, name: str) -> None:
        self.impl = impl
        self.name = name
        self.names = dict(impl.names)

    def segment(self, rgb: NDArray[np.uint8], frame: Any = None) -> LabelMap:
        labels, names, confidence = self.impl.segment_with_confidence(rgb)
        return LabelMap(labels, dict(names), confidence)

    def close(self) -> None:
        """Nothing to free: the session is released with the object."""


def create_stdc(cfg: SemanticsConfig) -> _NetSegmenter:
    from semslam.nets.segmenters import StdcSegmenter

    return _NetSegmenter(StdcSegmenter(cfg.weights or None, cfg.threshold, cfg.input_width), "stdc")


def create_dunet(cfg: SemanticsConfig) -> _NetSegmenter:
    from semslam.nets.segmenters import DunetSegmenter

    return _NetSegmenter(DunetSegmenter(cfg.weights or None, cfg.threshold, cfg.input_width), "dunet")
