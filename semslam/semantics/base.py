"""Building segmenters by name and the class-name -> dynamic-mask mapping.

A backend is one module implementing ``core.protocols.Segmenter`` with a factory listed in
``core.registry``. Backend modules are imported only when their backend is chosen, so an
optional package (mediapipe, torch) is needed only by the runs that use it, and its
absence is a ConfigError that says what to install instead of an ImportError at startup.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core import registry
from semslam.core.protocols import Segmenter
from semslam.core.types import LabelMap
from semslam.errors import ConfigError
from semslam.config.checks import check_values
from semslam.config import SemanticsConfig
from semslam.core.labels import KNOWN_CLASS_NAMES
from semslam.core.map_classes import possible_class_names

log = logging.getLogger(__name__)

#: A segmenter with this many classes or fewer (besides background) is named at start-up.
FEW_CLASSES = 3
_TOLD_FEW_CLASSES: set[str] = set()

# Optional package (import name) -> what to install, for the error message.
_INSTALL_HINTS: dict[str, str] = {
    # --no-deps: mediapipe's metadata would pull jax, jaxlib, sounddevice and the GUI
    # opencv-contrib-python (which clashes with the headless build); none is needed here.
    "mediapipe": "pip install --no-deps mediapipe==0.10.21 absl-py==2.5.1 attrs==26.1.0 flatbuffers==25.12.19 "
                 "protobuf==4.25.9 sentencepiece==0.2.3",
    "torch": "pip install torch (CPU wheel: --index-url https://download.pytorch.org/whl/cpu)",
}


def available_segmenters() -> list[str]:
    return registry.names("segmenter")


def missing_package_error(backend: str, package: str) -> ConfigError:
    """The error for a backend whose optional package is not installed."""
    hint = _INSTALL_HINTS.get(package, f"pip install {package}")
    return ConfigError(
        f"semantics.backend={backend!r} needs the {package!r} package, which is not installed; "
        f"install it with: {hint}"
    )


def create_segmenter(cfg: SemanticsConfig) -> Segmenter:
    """Build the configured backend; ConfigError for unknown names, bad settings or missing packages."""
    check_values(cfg, "semantics")
    cfg.check()
    name = registry.resolve("segmenter", cfg.backend)
    try:
        factory = registry.load("segmenter", name)
    except ImportError as exc:
        package = (exc.name or "").split(".")[0]
        if package == "semslam":
            raise
        if not package:  # the package is there but broken (e.g. built for another numpy)
            raise ConfigError(
                f"semantics.backend={name!r}: its packages are installed but cannot be loaded ({exc})"
            ) from None
        raise missing_package_error(name, package) from None
    segmenter: Segmenter = factory(cfg)
    if segmenter.names is not None:
        dynamic_ids(segmenter.names, cfg.dynamic_classes)  # report a bad class list now, not on frame 1
        _say_if_few_classes(name, segmenter.names)
    return segmenter


def _say_if_few_classes(backend: str, names: dict[int, str]) -> None:
    """Warn once per backend and process when a segmenter knows only a few classes (the bundled
    person segmenters): a user reading the maps should know the rest is 'unknown' by design."""
    known = possible_class_names(names)
    if len(known) > FEW_CLASSES or backend in _TOLD_FEW_CLASSES:
        return
    _TOLD_FEW_CLASSES.add(backend)
    log.warning("segmenter %s knows only: %s; the maps will label everything else 'unknown'", backend,
                ", ".join(known) or "no class")


def dynamic_ids(names: dict[int, str], dynamic_classes: Iterable[str]) -> NDArray[np.uint8]:
    """Ids of ``names`` whose class is in ``dynamic_classes``.

    A class that semslam knows (a VOC or synthetic class) but this backend cannot output,
    such as "car" for the person segmenter, matches nothing. A name that is neither in the
    backend's label set nor known at all is almost certainly a typo: ConfigError listing
    the backend's classes.
    """
    by_name = {n: i for i, n in names.items()}
    ids: list[int] = []
    for cls in dynamic_classes:
        if cls in by_name:
            ids.append(by_name[cls])
        elif cls not in KNOWN_CLASS_NAMES:
            raise ConfigError(
                f"semantics.dynamic_classes: unknown class {cls!r}; this backend's classes are: "
                f"{', '.join(names[i] for i in sorted(names))}"
            )
    return np.array(sorted(set(ids)), np.uint8)


def dynamic_mask(label_map: LabelMap, dynamic_classes: Iterable[str]) -> NDArray[np.bool_]:
    """Boolean HxW mask of the pixels whose class is one of ``dynamic_classes`` (by name)."""
    lut = np.zeros(256, np.bool_)
    lut[dynamic_ids(label_map.names, dynamic_classes)] = True
    return lut[label_map.labels]


def fit_labels(label_map: LabelMap, shape: tuple[int, int]) -> LabelMap:
    """A backend's labels at the image's size ``(H, W)``: a network that answers at its own
    resolution still covers the whole image, so nearest-neighbour resizing puts each label
    back where it belongs (label ids are not interpolated). Labels read from files are
    checked by their reader instead: a file of another size belongs to another image."""
    if label_map.shape == shape:
        return label_map
    h, w = shape
    labels = cv2.resize(label_map.labels, (w, h), interpolation=cv2.INTER_NEAREST)
    conf = label_map.confidence
    if conf is not None:
        conf = cv2.resize(conf, (w, h), interpolation=cv2.INTER_LINEAR)
    return LabelMap(labels, label_map.names, conf)


def inference_size(shape: tuple[int, int], input_width: int) -> tuple[int, int]:
    """(height, width) to run a network at: native for 0, else ``input_width`` wide, same aspect."""
    h, w = shape
    if input_width <= 0 or input_width == w:
        return h, w
    return max(1, round(h * input_width / w)), input_width


def resize_input(rgb: NDArray[np.uint8], input_width: int) -> NDArray[np.uint8]:
    """Downscale (area) or upscale (linear) an image to the inference width."""
    h, w = inference_size(rgb.shape[:2], input_width)
    if (h, w) == rgb.shape[:2]:
        return rgb
    interp = cv2.INTER_AREA if w < rgb.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(rgb, (w, h), interpolation=interp)


def resize_score(score: NDArray[np.float32], shape: tuple[int, int]) -> NDArray[np.float32]:
    """Bring a per-pixel score back to the native image size (linear, then thresholded by the caller)."""
    if score.shape == shape:
        return score
    return cv2.resize(score, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
