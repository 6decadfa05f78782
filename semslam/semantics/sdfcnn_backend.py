"""SDFCNN (SDF-SLAM) as two backends over one inference: depth source ``sdfcnn`` (metric depth
for monocular runs) and segmenter ``sdfcnn`` (the 40 NYU classes).

Both ask one :class:`SdfcnnPredictor` per weights file (``shared_predictor``), which runs a
frame through the network once and keeps the last few results, so the depth the tracker
reads and the labels the semantic thread or the map builders read come from the same
forward pass. A frame is identified by its image content (a hash of the pixels), because
the callers differ: tracking passes the Frame, the map builders a keyframe snapshot's copy
of the image. Concurrent requests for the same image wait for the one inference.

The network output stays at its own resolution (1/4 of Layer 0) in the cache; depth is
upsampled bilinearly to the frame's size and labels by an exact bilinear-logits argmax
(``nets.outputs.upsampled_argmax``) when first asked for. Weights are
``semslam/data/sdfcnn.onnx`` (run by ONNX Runtime, no torch) unless ``depth.weights`` /
``semantics.weights`` name others (``depth.weights`` empty follows ``semantics.weights``
when both backends are sdfcnn, so one predictor serves both) (an ``.onnx`` from ``semslam export-onnx``, or a ``.pt`` checkpoint, which
torch runs); the file must exist when the backend is built (one clear error before the
run starts) and is loaded at the first frame. The backend lives here, above ``nets``, so it needs no change to the import
layers: the System finds depth sources through the registry by name.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import DepthConfig, SemanticsConfig
from semslam.core.labels import NYU40_CLASSES
from semslam.core.types import Frame, LabelMap
from semslam.errors import DataError

if TYPE_CHECKING:
    from semslam.nets.onnx_runtime import Net

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "sdfcnn.onnx"
#: Results kept per predictor: the semantic thread may run a few frames ahead of tracking.
CACHE_FRAMES = 8


class Prediction:
    """One frame's network output; full-size depth and labels are made on first request."""

    def __init__(self, seg: NDArray[np.float32], depth: NDArray[np.float32], size: tuple[int, int],
                 class_ids: NDArray[np.uint8]) -> None:
        self.seg, self.depth_low, self.size, self.class_ids = seg, depth, size, class_ids
        self._depth: NDArray[np.float32] | None = None
        self._labels: NDArray[np.uint8] | None = None

    def depth(self) -> NDArray[np.float32]:
        """Metres at the frame's size (bilinear, half-pixel centres as the output layer)."""
        if self._depth is None:
            d = cv2.resize(self.depth_low, self.size, interpolation=cv2.INTER_LINEAR)
            self._depth = np.maximum(d, 0.0).astype(np.float32, copy=False)
        return self._depth

    def labels(self) -> NDArray[np.uint8]:
        """NYU-40 ids (1..40) at the frame's size."""
        if self._labels is None:
            from semslam.nets.outputs import upsampled_argmax

            self._labels = self.class_ids[upsampled_argmax(self.seg, self.size)]
        return self._labels


def image_key(rgb: NDArray[np.uint8]) -> tuple[tuple[int, ...], bytes]:
    """A frame's identity: its shape and a 128-bit hash of its pixels (~1 ms at 640x480)."""
    data = np.ascontiguousarray(rgb)
    return data.shape, hashlib.blake2b(memoryview(data).cast("B"), digest_size=16).digest()


class SdfcnnPredictor:
    """Runs SDFCNN once per distinct image (thread-safe) and caches the last results."""

    def __init__(self, weights: str | Path | None = None) -> None:
        self.weights = Path(weights) if weights else DEFAULT_WEIGHTS
        if not self.weights.is_file():
            raise DataError(self.weights, "SDFCNN weights not found; train them with `semslam train sdfcnn` "
                                          "(semslam/data/NETS.md) or set semantics.weights")
        self._net: Net | None = None
        self._class_ids: NDArray[np.uint8] | None = None
        self._lock = threading.Lock()
        self._cache: OrderedDict[Any, Future[Prediction]] = OrderedDict()
        self.inferences = 0  # forward passes run (for tests and stats)

    def _load(self) -> Net:
        with self._lock:
            if self._net is None:
                from semslam.nets.onnx_load import load_net

                net = load_net(self.weights, "sdfcnn")
                ids = [int(i) for i in net.meta["class_ids"]]
                if ids != sorted(NYU40_CLASSES):
                    raise DataError(self.weights, "SDFCNN weights must predict the 40 NYU classes (ids 1..40)")
                self._class_ids = np.array(ids, np.uint8)
                self._net = net
            return self._net

    def parameter_count(self) -> int:
        """Parameters of the loaded network (loads it; recorded in its metadata)."""
        return int(self._load().meta["parameters"])

    def predict(self, rgb: NDArray[np.uint8]) -> Prediction:
        """The cached prediction of this image, or one forward pass."""
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"sdfcnn: expected an RGB image (H, W, 3), got shape {rgb.shape}")
        key = image_key(rgb)
        with self._lock:
            fut = self._cache.get(key)
            owner = fut is None
            if fut is None:
                fut = self._cache[key] = Future()
                while len(self._cache) > CACHE_FRAMES:
                    self._cache.popitem(last=False)
            else:
                self._cache.move_to_end(key)
        if owner:
            try:
                fut.set_result(self._run(rgb))
            except BaseException as exc:
                with self._lock:
                    self._cache.pop(key, None)
                fut.set_exception(exc)
                raise
        return fut.result()

    def _run(self, rgb: NDArray[np.uint8]) -> Prediction:
        seg, depth = self._load().run(rgb[None])
        self.inferences += 1
        assert self._class_ids is not None
        h, w = rgb.shape[:2]
        return Prediction(seg[0], depth[0, 0], (w, h), self._class_ids)


_PREDICTORS: dict[Path, SdfcnnPredictor] = {}
_PREDICTORS_LOCK = threading.Lock()


def shared_predictor(weights: str | Path | None = None) -> SdfcnnPredictor:
    """The one predictor of a weights file in this process (depth and labels share it)."""
    path = (Path(weights) if weights else DEFAULT_WEIGHTS).resolve()
    with _PREDICTORS_LOCK:
        if path not in _PREDICTORS:
            _PREDICTORS[path] = SdfcnnPredictor(path)
        return _PREDICTORS[path]


class SdfcnnDepth:
    """DepthSource: SDFCNN's predicted depth in metres at the frame's size."""

    def __init__(self, predictor: SdfcnnPredictor) -> None:
        self.predictor = predictor

    def depth(self, frame: Frame) -> NDArray[np.float32] | None:
        return self.predictor.predict(frame.rgb).depth()


class SdfcnnSegmenter:
    """Segmenter: SDFCNN's 40 NYU classes (ids 1..40, ``core.labels.NYU40_CLASSES``)."""

    name = "sdfcnn"

    def __init__(self, predictor: SdfcnnPredictor) -> None:
        self.predictor = predictor
        self.names: dict[int, str] | None = dict(NYU40_CLASSES)

    def segment(self, rgb: NDArray[np.uint8], frame: Frame | None = None) -> LabelMap:
        return LabelMap(self.predictor.predict(rgb).labels(), dict(NYU40_CLASSES))

    def close(self) -> None:
        """Nothing to free: the shared predictor's session is kept for the other backend."""


def create_depth(cfg: DepthConfig) -> SdfcnnDepth:
    """Registry factory of depth source ``sdfcnn`` (``depth.weights``, resolved by the System to
    ``semantics.weights`` when the segmenter is sdfcnn too, or the shipped weights)."""
    return SdfcnnDepth(shared_predictor(cfg.weights or None))


def create_segmenter(cfg: SemanticsConfig) -> SdfcnnSegmenter:
    """Registry factory of segmenter ``sdfcnn`` (``semantics.weights`` or the shipped weights)."""
    return SdfcnnSegmenter(shared_predictor(cfg.weights or None))
