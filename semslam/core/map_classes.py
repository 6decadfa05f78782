"""The maps' class table: one global index and one colour per class *name*.

A ``LabelMap``'s ids belong to the backend that made it (VOC 15 is a person, NYU 31 too, the
synthetic sequences write 100 + NYU id); ``labels.names`` turns them into names, and the maps
store this module's index of the name, so octree, semantic cloud and mesh share one legend.

Index layout (stable: new classes are only ever appended):

- 0: ``unknown``: no segmenter, "background", "void", or a name known nowhere;
- 1..40: the NYU-40 classes at their NYU ids (``semslam.core.labels.NYU40_CLASSES``), so a
  map's label is the NYU id itself and people are 31 whichever backend saw them;
- 41: ``moving_object`` (the synthetic sequences' unlabelled mover);
- 42..58: the PASCAL VOC classes NYU-40 lacks, in VOC order (aeroplane ... tvmonitor).

Colours: NYU-40 uses the palette of the NYUv2/ScanNet tools (ScanNet's
``BenchmarkScripts/util.py::create_color_palette``, written out below); unknown is its entry
0, black. The VOC extras take the PASCAL VOC colour map of their VOC id (the bit-interleaved
palette of the VOC devkit, ``VOCdevkit/VOCcode/VOClabelcolormap.m``); ``moving_object`` is
magenta, which neither palette uses.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import NYU40_CLASSES, VOC_CLASSES
from semslam.core.types import LabelMap

UNKNOWN = 0
UNKNOWN_NAME = "unknown"
MOVING_OBJECT = 41

# NYU-40 colour per NYU id (0 = unlabelled), as ScanNet's create_color_palette() lists them.
NYU40_PALETTE: tuple[tuple[int, int, int], ...] = (
    (0, 0, 0),        # 0 unlabelled
    (174, 199, 232),  # 1 wall
    (152, 223, 138),  # 2 floor
    (31, 119, 180),   # 3 cabinet
    (255, 187, 120),  # 4 bed
    (188, 189, 34),   # 5 chair
    (140, 86, 75),    # 6 sofa
    (255, 152, 150),  # 7 table
    (214, 39, 40),    # 8 door
    (197, 176, 213),  # 9 window
    (148, 103, 189),  # 10 bookshelf
    (196, 156, 148),  # 11 picture
    (23, 190, 207),   # 12 counter
    (178, 76, 76),    # 13 blinds
    (247, 182, 210),  # 14 desk
    (66, 188, 102),   # 15 shelves
    (219, 219, 141),  # 16 curtain
    (140, 57, 197),   # 17 dresser
    (202, 185, 52),   # 18 pillow
    (51, 176, 203),   # 19 mirror
    (200, 54, 131),   # 20 floor mat
    (92, 193, 61),    # 21 clothes
    (78, 71, 183),    # 22 ceiling
    (172, 114, 82),   # 23 books
    (255, 127, 14),   # 24 refridgerator
    (91, 163, 138),   # 25 television
    (153, 98, 156),   # 26 paper
    (140, 153, 101),  # 27 towel
    (158, 218, 229),  # 28 shower curtain
    (100, 125, 154),  # 29 box
    (178, 127, 135),  # 30 whiteboard
    (120, 185, 128),  # 31 person
    (146, 111, 194),  # 32 night stand
    (44, 160, 44),    # 33 toilet
    (112, 128, 144),  # 34 sink
    (96, 207, 209),   # 35 lamp
    (227, 119, 194),  # 36 bathtub
    (213, 92, 176),   # 37 bag
    (94, 106, 211),   # 38 otherstructure
    (82, 84, 163),    # 39 otherfurniture
    (100, 85, 144),   # 40 otherprop
)

MOVING_OBJECT_COLOUR = (255, 0, 255)

# Names that mean "no class" in the label sets semslam reads.
_NO_CLASS = frozenset({"unknown", "background", "void", "unlabelled", "unlabeled"})


def voc_colour(voc_id: int) -> tuple[int, int, int]:
    """The PASCAL VOC devkit's colour of a VOC id (bits of the id spread over r, g, b)."""
    r = g = b = 0
    c = voc_id
    for shift in range(7, -1, -1):
        r |= (c & 1) << shift
        g |= ((c >> 1) & 1) << shift
        b |= ((c >> 2) & 1) << shift
        c >>= 3
    return r, g, b


def _build() -> tuple[tuple[str, ...], NDArray[np.uint8]]:
    names = [UNKNOWN_NAME] + [NYU40_CLASSES[i] for i in range(1, 41)] + ["moving_object"]
    colours = list(NYU40_PALETTE) + [MOVING_OBJECT_COLOUR]
    for voc_id, name in sorted(VOC_CLASSES.items()):
        if voc_id != 0 and name not in names:
            names.append(name)
            colours.append(voc_colour(voc_id))
    return tuple(names), np.array(colours, np.uint8)


#: index -> class name, and index -> RGB colour (K, 3) uint8.
CLASS_NAMES, CLASS_COLOURS = _build()
CLASS_INDEX: dict[str, int] = {name: i for i, name in enumerate(CLASS_NAMES)}
N_CLASSES = len(CLASS_NAMES)


def class_index(name: str) -> int:
    """Global index of a class name (case and surrounding blanks ignored); 0 if unknown."""
    key = name.strip().lower()
    return UNKNOWN if key in _NO_CLASS else CLASS_INDEX.get(key, UNKNOWN)


def label_lut(names: dict[int, str]) -> NDArray[np.uint8]:
    """Backend id (0..255) -> global index, for ``lut[labels.labels]``; ids without a name are 0."""
    lut = np.zeros(256, np.uint8)
    for backend_id, name in names.items():
        if 0 <= backend_id < 256:
            lut[backend_id] = class_index(name)
    return lut


def class_image(labels: LabelMap | None, shape: tuple[int, int]) -> NDArray[np.uint8]:
    """Per-pixel global class index at image ``shape``: all unknown without labels; a label
    map of another size is sampled at the nearest pixel."""
    if labels is None:
        return np.zeros(shape, np.uint8)
    idx = label_lut(labels.names)[labels.labels]
    return idx if idx.shape == shape else _resample_nearest(idx, shape)


def confidence_image(labels: LabelMap | None, shape: tuple[int, int]) -> NDArray[np.float32] | None:
    """The segmenter's confidence at image ``shape`` (None when it gives none)."""
    if labels is None or labels.confidence is None:
        return None
    conf = labels.confidence.astype(np.float32, copy=False)
    return conf if conf.shape == shape else _resample_nearest(conf, shape)


def _resample_nearest(img: NDArray[Any], shape: tuple[int, int]) -> NDArray[Any]:
    h, w = img.shape
    rows = np.arange(shape[0]) * h // shape[0]
    cols = np.arange(shape[1]) * w // shape[1]
    return img[rows[:, None], cols[None, :]]


def possible_classes(names: dict[int, str] | None) -> set[int]:
    """The map classes a segmenter with label set ``names`` can give (unknown always: the
    pixels it labels background, and every pixel without labels)."""
    return {UNKNOWN} | {class_index(n) for n in (names or {}).values()}


def possible_class_names(names: dict[int, str]) -> list[str]:
    """The real classes (not background / unknown) of a segmenter's label set, by map index."""
    return [CLASS_NAMES[i] for i in sorted(possible_classes(names) - {UNKNOWN})]


def classes_table(counts: dict[int, int] | None = None, count_key: str = "count",
                  possible: set[int] | None = None) -> dict[str, dict[str, Any]]:
    """The legend as JSON: ``{"index": {"name": ..., "colour": [r, g, b]}}`` for every class
    (the layout ``semslam.eval.map_eval.read_class_table`` reads), with ``count_key`` where
    ``counts`` gives how many voxels or points a map has of a class, and ``"possible"``
    (whether the run's segmenter could give the class at all) where ``possible`` is known:
    a class at 0 that was never possible says nothing about the scene."""
    table: dict[str, dict[str, Any]] = {}
    for i, name in enumerate(CLASS_NAMES):
        row: dict[str, Any] = {"name": name, "colour": [int(c) for c in CLASS_COLOURS[i]]}
        if counts is not None:
            row[count_key] = int(counts.get(i, 0))
        if possible is not None:
            row["possible"] = i in possible
        table[str(i)] = row
    return table


def write_classes_json(path: Path, labels: NDArray[np.integer], count_key: str,
                       possible: set[int] | None = None) -> Path:
    """A map's legend next to it, with how many of its elements each class has and, given
    ``possible``, which classes the segmenters of its keyframes could give."""
    present, n = np.unique(np.asarray(labels, np.int64), return_counts=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = classes_table(dict(zip(present.tolist(), n.tolist())), count_key, possible)
    path.write_text(json.dumps(table, indent=1))
    return path
