"""Segmenter backends running the trained networks: ``StdcSegmenter`` and ``DunetSegmenter``.

``segment(rgb)`` resizes the frame to the network input (the checkpoint's training width
unless ``input_width`` says otherwise; sides rounded to the network's multiple), runs the
network (``nets.onnx_runtime``: the shipped ``.onnx`` in ONNX Runtime, or a ``.pt`` given
as weights in torch), upsamples the class probabilities bilinearly to the frame size and
labels each pixel with its most likely non-background class if that class's probability
exceeds ``threshold`` (else background). ``input_width=0`` means the width the network was
trained at (320 for the shipped weights), not the frame's native width: the nets are
scale-specific, and 640 px costs 4x the time. Labels are the checkpoint's dataset ids (VOC
ids: person = 15), so the output plugs into code that expects VOC/synthetic label maps.
No torch is imported for ``.onnx`` weights. Thread settings: ``nets.onnx_runtime``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import ConfigError
from semslam.nets.onnx_load import load_net
from semslam.nets.onnx_runtime import input_multiple
from semslam.nets.outputs import upsample

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
#: Weights shipped with the package (``semslam export-onnx`` writes them from the ``.pt``).
DEFAULT_WEIGHTS = {"stdc1": DATA_DIR / "stdc_person.onnx", "dunet": DATA_DIR / "dunet_person.onnx"}


class NetSegmenter:
    """Common code of the network backends (one checkpoint, one architecture)."""

    arch = ""
    name = "net"

    def __init__(self, weights_path: str | Path | None = None, threshold: float = 0.5, input_width: int = 0) -> None:
        path = Path(weights_path) if weights_path else DEFAULT_WEIGHTS[self.arch]
        if not 0.0 <= threshold < 1.0:
            raise ConfigError(f"segmenter threshold must be in [0, 1), got {threshold}")
        self.net = load_net(path, self.arch)
        self.meta = self.net.meta
        self.weights_path = path
        self.threshold = float(threshold)
        self.input_width = int(input_width) or int(self.meta["input_size"][0])
        self.class_ids = np.array(self.meta["class_ids"], np.uint8)
        self.names: dict[int, str] = {int(i): str(n) for i, n in zip(self.meta["class_ids"], self.meta["class_names"])}
        self.multiple = input_multiple(self.arch)

    def input_size(self, w: int, h: int) -> tuple[int, int]:
        """Network input (w, h) for a w x h frame: ``input_width`` wide, same aspect, rounded."""
        m = self.multiple
        nw = max(m, int(round(self.input_width / m)) * m)
        nh = max(m, int(round(self.input_width * h / w / m)) * m)
        return nw, nh

    def probabilities(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Class probabilities (C, H, W) at the frame's size."""
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"segment: expected an RGB image (H, W, 3), got shape {rgb.shape}")
        h, w = rgb.shape[:2]
        nw, nh = self.input_size(w, h)
        small = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_AREA if nw < w else cv2.INTER_LINEAR)
        (prob,) = self.net.run(small[None])
        return upsample(prob[0], (w, h))

    def segment(self, rgb: NDArray[np.uint8], frame: Any = None) -> tuple[NDArray[np.uint8], dict[int, str]]:
        """(label map uint8 HxW with the checkpoint's class ids, {id: name}); ``frame`` is unused."""
        labels, names, _ = self.segment_with_confidence(rgb)
        return labels, names

    def segment_with_confidence(
        self, rgb: NDArray[np.uint8]
    ) -> tuple[NDArray[np.uint8], dict[int, str], NDArray[np.float32]]:
        """Like :meth:`segment`, plus the probability of each pixel's chosen label (float32 HxW)."""
        prob = self.probabilities(rgb)
        fg_idx = prob[1:].argmax(axis=0)
        fg_prob = np.take_along_axis(prob[1:], fg_idx[None], axis=0)[0]
        is_fg = fg_prob > self.threshold
        labels = self.class_ids[np.where(is_fg, fg_idx + 1, 0)]
        conf = np.where(is_fg, fg_prob, prob[0]).astype(np.float32, copy=False)
        return labels, dict(self.names), conf


class StdcSegmenter(NetSegmenter):
    """STDC1-Seg (STDC-SLAM's network); default weights ``semslam/data/stdc_person.onnx``."""

    arch = "stdc1"
    name = "stdc"


class DunetSegmenter(NetSegmenter):
    """Deformable U-Net (DDL-SLAM's network); default weights ``semslam/data/dunet_person.onnx``."""

    arch = "dunet"
    name = "dunet"
