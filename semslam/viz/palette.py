"""Class names and colours of the maps' class indices (``core.map_classes``: NYU-40 at their
ids, then moving_object and the VOC classes NYU lacks), as the map files' ``label`` field
holds them; one table for the Rerun recording and the report's map views alike."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.core.map_classes import CLASS_COLOURS, CLASS_NAMES


def class_name(index: int) -> str:
    i = int(index)
    return CLASS_NAMES[i] if 0 <= i < len(CLASS_NAMES) else f"class {i}"


def class_colour(index: int) -> tuple[int, int, int]:
    i = int(index)
    c = CLASS_COLOURS[i] if 0 <= i < len(CLASS_COLOURS) else CLASS_COLOURS[0]
    return int(c[0]), int(c[1]), int(c[2])


def class_colours(labels: NDArray[np.integer]) -> NDArray[np.uint8]:
    """(N, 3) colours of N class indices."""
    idx = np.asarray(labels, np.int64)
    return CLASS_COLOURS[np.where((idx >= 0) & (idx < len(CLASS_COLOURS)), idx, 0)]


def class_table(labels: NDArray[np.integer]) -> dict[int, tuple[str, tuple[int, int, int]]]:
    """index -> (name, colour) for the indices present in ``labels``."""
    return {int(i): (class_name(i), class_colour(i)) for i in np.unique(np.asarray(labels))}
