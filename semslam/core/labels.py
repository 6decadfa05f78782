"""Label sets: PASCAL VOC (what DDL-SLAM's DUNet and STDC nets are trained on) and the
synthetic sequences' ids, which reuse VOC's id for person so one id means one class."""

from __future__ import annotations

# PASCAL VOC 2012 segmentation classes, id -> name (255 = "void" border in the ground truth).
VOC_CLASSES: dict[int, str] = {
    0: "background",
    1: "aeroplane",
    2: "bicycle",
    3: "bird",
    4: "boat",
    5: "bottle",
    6: "bus",
    7: "car",
    8: "cat",
    9: "chair",
    10: "cow",
    11: "diningtable",
    12: "dog",
    13: "horse",
    14: "motorbike",
    15: "person",
    16: "pottedplant",
    17: "sheep",
    18: "sofa",
    19: "train",
    20: "tvmonitor",
}

VOC_PERSON = 15

# DDL-SLAM (Sec. III-A): the VOC classes that are "potentially movable".
DDL_SLAM_DYNAMIC_CLASSES: tuple[str, ...] = (
    "aeroplane",
    "bicycle",
    "bird",
    "boat",
    "bus",
    "car",
    "cat",
    "cow",
    "dog",
    "horse",
    "motorbike",
    "person",
    "sheep",
    "train",
)

# semslam's synthetic sequences, their dynamic ids (semslam/synth/writer.py LABELS adds the
# static scene's NYU-40 classes, below): the unlabelled mover is deliberately not a VOC
# class, so only geometry (not semantics) can catch it.
SYNTH_MOVING_OBJECT = 21
SYNTH_CLASSES: dict[int, str] = {0: "background", VOC_PERSON: "person", SYNTH_MOVING_OBJECT: "moving_object"}

# NYU Depth v2's 40-class set (Gupta et al. 2013), id -> name, as SDF-SLAM's segmentation head
# uses it. 0 is "unlabelled" in NYU's own files.
NYU40_CLASSES: dict[int, str] = {
    1: "wall", 2: "floor", 3: "cabinet", 4: "bed", 5: "chair", 6: "sofa", 7: "table", 8: "door",
    9: "window", 10: "bookshelf", 11: "picture", 12: "counter", 13: "blinds", 14: "desk",
    15: "shelves", 16: "curtain", 17: "dresser", 18: "pillow", 19: "mirror", 20: "floor mat",
    21: "clothes", 22: "ceiling", 23: "books", 24: "refridgerator", 25: "television", 26: "paper",
    27: "towel", 28: "shower curtain", 29: "box", 30: "whiteboard", 31: "person", 32: "night stand",
    33: "toilet", 34: "sink", 35: "lamp", 36: "bathtub", 37: "bag", 38: "otherstructure",
    39: "otherfurniture", 40: "otherprop",
}

# The synthetic sequences label static surfaces with NYU-40 classes at id 100 + NYU id, so the
# dynamic ids above (person 15, moving_object 21) keep their meaning and every existing
# sequence reads the same; NYU's own "person" (31) is never written (people are 15).
SYNTH_STATIC_OFFSET = 100


def synth_static_id(nyu_name: str) -> int:
    """The synthetic label id of a static NYU-40 class name (KeyError for an unknown name)."""
    return SYNTH_STATIC_OFFSET + {v: k for k, v in NYU40_CLASSES.items()}[nyu_name]


# Every class name semslam knows of. A dynamic class that is known but absent from a
# backend's label set (e.g. "car" for the person segmenter) simply never matches; a name
# known nowhere is a typo and an error.
KNOWN_CLASS_NAMES: frozenset[str] = (frozenset(VOC_CLASSES.values()) | frozenset(SYNTH_CLASSES.values())
                                      | frozenset(NYU40_CLASSES.values()))
