"""Class names and colours for every label id semslam writes: PASCAL VOC (the segmenters),
the synthetic sequences' ids and their static NYU-40 classes at ``SYNTH_STATIC_OFFSET`` + id.

One id means one class across these sets (the synthetic ids reuse VOC's person), so one
table serves the Rerun recording and the report's map views alike.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import NYU40_CLASSES, SYNTH_CLASSES, SYNTH_STATIC_OFFSET, VOC_CLASSES

CLASS_NAMES: dict[int, str] = {**VOC_CLASSES, **SYNTH_CLASSES,
                               **{SYNTH_STATIC_OFFSET + k: v for k, v in NYU40_CLASSES.items()}}
_GREY = (128, 128, 128)
#: Fixed colours: background grey, the dynamic classes loud (person red, moving object magenta).
_FIXED = {0: _GREY, 15: (230, 25, 25), 21: (220, 0, 220)}
#: matplotlib's tab10 (its grey replaced by teal): ten hues made to be told apart.
_HUES = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
         (227, 119, 194), (0, 128, 128), (188, 189, 34), (23, 190, 207))


def class_name(label: int) -> str:
    return CLASS_NAMES.get(int(label), f"class {int(label)}")


def class_colour(label: int) -> tuple[int, int, int]:
    """A fixed colour per id: ids k = 1..40 of a set (VOC ids, NYU-40 ids after the offset)
    take hue k mod 10 in one of four shades (k // 10), so neighbouring ids (wall 1, floor 2)
    differ in hue; background and the dynamic classes have colours of their own."""
    label = int(label)
    if label in _FIXED:
        return _FIXED[label]
    k = label - SYNTH_STATIC_OFFSET if label > SYNTH_STATIC_OFFSET else label
    c = np.array(_HUES[k % 10], float)
    shade = (k // 10) % 4
    c = (c, 0.6 * c, c + 0.5 * (255 - c), 0.35 * c + 0.3 * (255 - c))[shade]
    return int(c[0]), int(c[1]), int(c[2])


def class_colours(labels: NDArray[np.integer]) -> NDArray[np.uint8]:
    """(N, 3) colours of N label ids."""
    ids, inverse = np.unique(np.asarray(labels), return_inverse=True)
    table = np.array([class_colour(i) for i in ids], np.uint8).reshape(-1, 3)
    return table[inverse.reshape(-1)]


def class_table(labels: NDArray[np.integer]) -> dict[int, tuple[str, tuple[int, int, int]]]:
    """id -> (name, colour) for the ids present in ``labels``."""
    return {int(i): (class_name(i), class_colour(i)) for i in np.unique(np.asarray(labels))}
