"""Oracle segmenter: the sequence's own per-pixel labels (``semantic/<stamp>.png``).

Why: ablations need an upper bound of segmentation quality (what would the SLAM do with
a perfect segmenter?), and tests need labels that are exactly known. semslam's synthetic
sequences write ``semantic/<rgb stamp>.png`` (uint8 class ids) and
``semantic/labels.json`` ({"id": "name"}) next to ``rgb/``; any dataset laid out the
same way works.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import ConfigError, DataError
from semslam.core.types import LabelMap
from semslam.config import SemanticsConfig

if TYPE_CHECKING:
    from semslam.core.types import Frame

LABELS_FILE = "labels.json"


def semantic_path(rgb_path: Path) -> Path:
    """``.../rgb/<stamp>.<ext>`` -> ``.../semantic/<stamp>.png``."""
    return rgb_path.parent.parent / "semantic" / f"{rgb_path.stem}.png"


def read_label_names(path: Path) -> dict[int, str]:
    """Parse a ``labels.json`` ({"0": "background", "15": "person", ...})."""
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(path, "label names not found (the ground_truth segmenter needs semantic/labels.json)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(path, f"cannot read label names ({exc})") from None
    if not isinstance(raw, dict):
        raise DataError(path, 'expected a mapping {"id": "name"}')
    names: dict[int, str] = {}
    for key, value in raw.items():
        try:
            idx = int(key)
        except ValueError:
            raise DataError(path, f"label id {key!r} is not an integer") from None
        if not 0 <= idx <= 255 or not isinstance(value, str):
            raise DataError(path, f"bad entry {key!r}: {value!r} (ids 0..255, names strings)")
        names[idx] = value
    return names


def read_label_image(path: Path) -> NDArray[np.uint8]:
    """A single-channel 8-bit label image (ids, not colours)."""
    if not path.is_file():
        raise DataError(
            path, "no ground-truth labels for this frame (the ground_truth segmenter needs semantic/<stamp>.png)"
        )
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataError(path, "not a readable image")
    if img.ndim != 2 or img.dtype != np.uint8:
        raise DataError(path, f"expected a single-channel 8-bit label image, got {img.dtype} {img.shape}")
    return img


class GroundTruthSegmenter:
    """Reads the labels stored with the sequence; the label set comes from labels.json."""

    name = "ground_truth"

    def __init__(self, cfg: SemanticsConfig) -> None:
        self.names: dict[int, str] | None = None  # known after the first frame
        self._names_by_dir: dict[Path, dict[int, str]] = {}

    def close(self) -> None:
        """Nothing to free: labels are read per frame."""

    def segment(self, rgb: NDArray[np.uint8], frame: Frame | None = None) -> LabelMap:
        if frame is None or frame.rgb_path is None:
            raise ConfigError(
                "semantics.backend=ground_truth needs frames read from a sequence folder with semantic/ labels "
                "(no frame or no rgb path was given)"
            )
        path = semantic_path(Path(frame.rgb_path))
        labels = read_label_image(path)
        if labels.shape != rgb.shape[:2]:
            raise DataError(
                path, f"labels are {labels.shape[1]}x{labels.shape[0]} but the image is {rgb.shape[1]}x{rgb.shape[0]}"
            )
        folder = path.parent
        names = self._names_by_dir.get(folder)
        if names is None:
            names = read_label_names(folder / LABELS_FILE)
            self._names_by_dir[folder] = names
        present = np.flatnonzero(np.bincount(labels.ravel(), minlength=256))
        unknown = [int(i) for i in present if int(i) not in names]
        if unknown:
            raise DataError(path, f"label ids {unknown} are not named in {folder / LABELS_FILE}")
        self.names = names
        return LabelMap(labels, dict(names), None)


def create_segmenter(cfg: SemanticsConfig) -> GroundTruthSegmenter:
    return GroundTruthSegmenter(cfg)
