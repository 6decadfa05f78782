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

# semslam's synthetic sequences (semslam/synth/writer.py LABELS): the unlabelled mover is
# deliberately not a VOC class, so only geometry (not semantics) can catch it.
SYNTH_MOVING_OBJECT = 21
SYNTH_CLASSES: dict[int, str] = {0: "background", VOC_PERSON: "person", SYNTH_MOVING_OBJECT: "moving_object"}

# Every class name semslam knows of. A dynamic class that is known but absent from a
# backend's label set (e.g. "car" for the person segmenter) simply never matches; a name
# known nowhere is a typo and an error.
KNOWN_CLASS_NAMES: frozenset[str] = frozenset(VOC_CLASSES.values()) | frozenset(SYNTH_CLASSES.values())
