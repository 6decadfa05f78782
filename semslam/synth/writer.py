"""Writing a rendered sequence as a TUM RGB-D folder.

The layout is exactly that of the TUM benchmark (plus ``semantic/`` and ``calib.txt``), so
the same loader reads real and synthetic data.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import SYNTH_CLASSES
from semslam.errors import DataError
from semslam.geometry.se3 import pose_to_tum
from semslam.synth.scene import Box, static_boxes, static_class_names
from semslam.synth.stereo import RIGHT_DIR, RIGHT_LIST, SETTINGS_FILE


def labels_for(boxes: list[Box]) -> dict[str, str]:
    """``semantic/labels.json`` of a room: every id a sequence in it can contain. The
    dynamic ids (0 nothing hit, 15 person, 21 unlabelled mover) and the NYU-40 classes of
    the room's static boxes at 100 + NYU id."""
    return {str(k): v for k, v in {**SYNTH_CLASSES, **static_class_names(boxes)}.items()}


#: The labels of layout 0 (the office), which every sequence had before layouts existed.
LABELS = labels_for(static_boxes())


def stamp(t: float) -> str:
    """Timestamp as written in TUM file names and lists (6 decimals)."""
    return f"{t:.6f}"


#: Image folders of a sequence; the ``background/`` ones only with ``SynthConfig.background``.
IMAGE_DIRS = ("rgb", "depth", "semantic")
BACKGROUND_DIRS = ("background/rgb", "background/depth")


def prepare_dir(out: Path, background: bool = False, right: bool = False) -> None:
    """Create ``out`` and its image folders; remove PNGs of an earlier rendering there
    (the background and stereo folders too, so that a render without them leaves none
    behind; and a stereo render's lists, which would announce a right camera)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        for sub in IMAGE_DIRS + BACKGROUND_DIRS + (RIGHT_DIR,):
            d = out / sub
            wanted = right if sub == RIGHT_DIR else (sub in IMAGE_DIRS or background)
            if wanted:
                d.mkdir(parents=True, exist_ok=True)
            for old in d.glob("*.png"):
                old.unlink()
        if not right:
            for name in (RIGHT_LIST, SETTINGS_FILE):
                (out / name).unlink(missing_ok=True)
    except OSError as exc:
        raise DataError(out, f"cannot create the output folder: {exc.strerror or exc}") from exc


def write_png(path: Path, img: NDArray[Any]) -> None:
    """Write a PNG (RGB input is converted to OpenCV's BGR first); raise DataError on failure."""
    data = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
    if not cv2.imwrite(str(path), data):
        raise DataError(path, "cannot write PNG")


def write_list(path: Path, kind: str, stamps: list[str], folder: str) -> None:
    """``rgb.txt``/``depth.txt``: three comment lines, then ``timestamp folder/timestamp.png``."""
    lines = [
        f"# {kind} images",
        f"# file: '{path.parent.name}' (semslam synth)",
        "# timestamp filename",
    ]
    lines += [f"{s} {folder}/{s}.png" for s in stamps]
    path.write_text("\n".join(lines) + "\n")


def write_groundtruth(path: Path, stamps: list[str], poses: NDArray[np.float64]) -> None:
    """Camera-to-world poses of the RGB camera, exactly those used to render each frame."""
    rows = pose_to_tum(poses)
    lines = [
        "# ground truth trajectory",
        f"# file: '{path.parent.name}' (semslam synth, exact)",
        "# timestamp tx ty tz qx qy qz qw",
    ]
    lines += [s + " " + " ".join(f"{v:.9f}" for v in row) for s, row in zip(stamps, rows)]
    path.write_text("\n".join(lines) + "\n")


def write_calib(path: Path, intrinsics: tuple[float, float, float, float]) -> None:
    path.write_text(" ".join(f"{v:.6g}" for v in intrinsics) + "\n")


def write_json(path: Path, data: dict[str, Any], indent: int | None = 2) -> None:
    """Sorted keys; ``indent=None`` for compact files (one line per file)."""
    path.write_text(json.dumps(data, indent=indent, sort_keys=True) + "\n")
