"""Default segmenter: MediaPipe's selfie-segmentation person models, bundled in the wheel.

Why this one: it is pretrained, ships inside the ``mediapipe`` PyPI wheel (0.10.21:
``mediapipe/modules/selfie_segmentation/*.tflite``), runs offline on a CPU and never
downloads anything. It only knows "person" (VOC id 15), which is the dynamic class that
matters in TUM's dynamic sequences.

Two registered variants (numbers: tests/test_semantics.py and benchmarks/semantics_timing.py):

* ``mediapipe_person`` (default) - the general model (256x256 input) run on overlapping
  crops of aspect 0.8 (two crops of 60 % of the width for a 4:3 frame), combined by the
  maximum. On rendered people it finds people cut by the image border that the
  landscape model misses, and on the real TUM office frames it makes no false positives
  (the general model on the whole frame, stretched to a square, marked up to 42 % of a
  real office frame as person; letterboxed, 3 %). About 10 ms per 640x480 frame.
* ``mediapipe_person_fast`` - the landscape model (256x144) on the whole frame: same
  masks of people well inside the view, no false positives on the real office frames,
  but it misses most people who are only partly in view at the border. About 3 ms.

Inference is the MediaPipe Tasks ``ImageSegmenter`` in IMAGE mode: stateless (frames can
come in any order) and no temporal smoothing.
"""

from __future__ import annotations

import logging
import os
import tempfile
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from semslam.errors import ConfigError
from semslam.core.types import LabelMap
from semslam.semantics.base import missing_package_error, resize_input, resize_score
from semslam.config import SemanticsConfig
from semslam.core.labels import VOC_PERSON

if TYPE_CHECKING:
    from semslam.core.types import Frame

log = logging.getLogger(__name__)

PERSON_NAMES: dict[int, str] = {0: "background", VOC_PERSON: "person"}

MODEL_FILES = {
    "landscape": "selfie_segmentation_landscape.tflite",
    "general": "selfie_segmentation.tflite",
}
BACKEND_NAMES = {"general": "mediapipe_person", "landscape": "mediapipe_person_fast"}

# Width / height of the crops the general model sees (4:3 frame -> two crops of 60 % width).
CROP_ASPECT = 0.8


def crop_columns(width: int, height: int, aspect: float = CROP_ASPECT) -> list[tuple[int, int]]:
    """Evenly spaced, overlapping column ranges of width ``aspect * height`` covering the image."""
    cw = min(width, max(1, round(aspect * height)))
    n = -(-width // cw)  # ceil
    if n == 1 or height < 64:  # tiny images: one pass
        return [(0, width)]
    return [(x, x + cw) for x in (round(k * (width - cw) / (n - 1)) for k in range(n))]


def bundled_model_path(model: str) -> Path:
    """Path of a selfie-segmentation model inside the installed mediapipe package."""
    import importlib.util

    spec = importlib.util.find_spec("mediapipe")
    if spec is None or spec.origin is None:
        raise missing_package_error("mediapipe_person", "mediapipe")
    path = Path(spec.origin).parent / "modules" / "selfie_segmentation" / MODEL_FILES[model]
    if not path.is_file():
        raise ConfigError(
            f"the installed mediapipe has no bundled {MODEL_FILES[model]} (looked at {path}); "
            "install mediapipe==0.10.21, whose wheel carries it"
        )
    return path


@contextmanager
def _quiet_stderr() -> Iterator[list[str]]:
    """Capture what MediaPipe's C++ side prints on stderr while a graph starts (GPU/EGL
    probing, XNNPACK notes): noise on every run. It is logged at DEBUG level instead."""
    captured: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no real stderr (embedded interpreters): nothing to hide
        yield captured
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=".*MessageFactory.*")
                yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            captured.append(tmp.read().decode(errors="replace"))
            for line in captured[-1].splitlines():
                log.debug("mediapipe: %s", line)


class MediapipePersonSegmenter:
    """Person / background per pixel from a bundled MediaPipe selfie-segmentation model."""

    names: dict[int, str] | None = PERSON_NAMES

    def __init__(self, cfg: SemanticsConfig, model: str = "general") -> None:
        if model not in MODEL_FILES:
            raise ConfigError(f"mediapipe person model {model!r} unknown (known: {', '.join(MODEL_FILES)})")
        try:
            import mediapipe as mp
            from mediapipe.tasks.python import vision
            from mediapipe.tasks.python.core.base_options import BaseOptions
        except ImportError as exc:
            if (exc.name or "").split(".")[0] != "mediapipe":
                raise ConfigError(f"mediapipe is installed but cannot be loaded ({exc})") from None
            raise missing_package_error(self._backend_name(model), "mediapipe") from None
        self._mp = mp
        self.name = self._backend_name(model)
        self.model = model
        self.model_path = bundled_model_path(model)
        self.threshold = float(cfg.threshold)
        self.input_width = int(cfg.input_width)
        options = vision.ImageSegmenterOptions(
            # A buffer, not a path: nothing is looked up or fetched anywhere at run time.
            base_options=BaseOptions(model_asset_buffer=self.model_path.read_bytes()),
            running_mode=vision.RunningMode.IMAGE,
            output_confidence_masks=True,
            output_category_mask=False,
        )
        with _quiet_stderr() as captured:
            try:
                self._segmenter: Any = vision.ImageSegmenter.create_from_options(options)
                self._infer(np.zeros((48, 64, 3), np.uint8))  # warm-up: first call sets up XNNPACK
            except Exception as exc:  # noqa: BLE001 - MediaPipe raises RuntimeError/ValueError variants
                failure: Exception | None = exc
            else:
                failure = None
        if failure is not None:
            detail = "".join(captured).strip().splitlines()[-3:]
            raise ConfigError(f"{self.name}: cannot start the MediaPipe segmenter ({failure}) {' '.join(detail)}")
        # One graph runs one image at a time; the lock makes a shared instance safe.
        self._lock = threading.Lock()

    @staticmethod
    def _backend_name(model: str) -> str:
        return BACKEND_NAMES.get(model, f"mediapipe_person_{model}")

    def _infer(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Person probability at the resolution of ``rgb``."""
        if self.model != "general":
            return self._run(rgb)
        # The general model's input is square: a whole 4:3 frame stretched to it gave
        # confident false positives on real desks, letterboxed it made people small.
        h, w = rgb.shape[:2]
        cols = crop_columns(w, h)
        if len(cols) == 1:
            return self._run(rgb)
        prob = np.zeros((h, w), np.float32)
        for x0, x1 in cols:
            np.maximum(prob[:, x0:x1], self._run(rgb[:, x0:x1]), out=prob[:, x0:x1])
        return prob

    def _run(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        image = self._mp.Image(image_format=self._mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        result = self._segmenter.segment(image)
        # The mask's buffer belongs to the result object: copy before it goes away.
        return np.array(result.confidence_masks[0].numpy_view(), dtype=np.float32, copy=True)

    def segment(self, rgb: NDArray[np.uint8], frame: Frame | None = None) -> LabelMap:
        """Label 15 (person) where the person probability exceeds ``threshold``, else 0."""
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"expected an HxWx3 uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        shape = rgb.shape[:2]
        small = resize_input(rgb, self.input_width)
        with self._lock:
            if self._segmenter is None:
                raise RuntimeError(f"{self.name}: segment() after close()")
            prob = self._infer(small)
        prob = resize_score(prob, shape)
        person = prob > self.threshold
        labels = np.where(person, np.uint8(VOC_PERSON), np.uint8(0))
        # Score of the chosen label: p where person, 1 - p where background.
        confidence = np.subtract(np.float32(1.0), prob)
        np.copyto(confidence, prob, where=person)
        return LabelMap(labels, dict(PERSON_NAMES), confidence)

    def close(self) -> None:
        """Release the MediaPipe graph; the segmenter cannot be used afterwards."""
        seg = getattr(self, "_segmenter", None)
        if seg is not None:
            self._segmenter = None
            seg.close()

    def __enter__(self) -> MediapipePersonSegmenter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def create_general(cfg: SemanticsConfig) -> MediapipePersonSegmenter:
    return MediapipePersonSegmenter(cfg, "general")


def create_fast(cfg: SemanticsConfig) -> MediapipePersonSegmenter:
    return MediapipePersonSegmenter(cfg, "landscape")
