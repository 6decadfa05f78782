"""Layout 1, the lounge: a second room, kept out of every network's training data.

Why: a network trained and evaluated in the same room (layout 0, :mod:`semslam.synth.scene`)
is never tested on geometry it has not seen. This room differs in size (7.6 x 5.9 x 3.0 m
against 6 x 5 x 2.8 m), in what stands where (a sofa under a whiteboard at the back, a TV
sideboard, a desk in the left corner, a window and curtain on the left wall, a tall
bookshelf on the right) and in its class set (sofa, table, pillow, whiteboard, window,
curtain, lamp, shelves are new). The zones that the camera motions, the people, the
rolling mover and the carried box use (``layouts.FREE_ZONES``, world coordinates shared by
all layouts) are kept free, so every sequence preset renders in it unchanged.
"""

from __future__ import annotations

import numpy as np

from semslam.synth.scene import Box, _box, _faces

#: The room's corners (min, max): larger than layout 0's, and not at the origin.
ROOM_MIN = (-0.7, -0.4, 0.0)
ROOM_MAX = (6.9, 5.5, 3.0)
#: Ceiling lights (position, relative intensity) baked into the textures.
LIGHTS = (
    (np.array([1.8, 2.0, 2.9]), 1.0),
    (np.array([4.6, 3.8, 2.9]), 0.8),
    (np.array([2.6, 4.9, 2.9]), 0.6),
)


def _legs(name: str, x0: float, x1: float, y0: float, y1: float, z1: float, cls: str) -> list[Box]:
    """Four 4 cm square legs under a top spanning (x0..x1, y0..y1), up to height z1."""
    out = []
    for i, (lx, ly) in enumerate(((x0, y0), (x1 - 0.04, y0), (x0, y1 - 0.04), (x1 - 0.04, y1 - 0.04))):
        out.append(_box(f"{name}_leg{i}", (lx, ly, 0.0), (lx + 0.04, ly + 0.04, z1), "metal_plain",
                        cls=cls, ppm=100.0))
    return out


def _back_wall() -> list[Box]:
    """Sofa with pillows under the whiteboard, coffee table, TV sideboard, lamp."""
    return [
        _box("sofa_seat", (1.2, 4.65, 0.0), (3.4, 5.45, 0.42), _faces("fabric"), cls="sofa", ppm=250.0),
        _box("sofa_back", (1.2, 5.15, 0.42), (3.4, 5.45, 0.9), _faces("fabric"), cls="sofa", ppm=250.0),
        _box("sofa_arm0", (1.2, 4.65, 0.42), (1.42, 5.15, 0.62), _faces("fabric"), cls="sofa", ppm=250.0),
        _box("sofa_arm1", (3.18, 4.65, 0.42), (3.4, 5.15, 0.62), _faces("fabric"), cls="sofa", ppm=250.0),
        _box("pillow0", (1.6, 4.98, 0.42), (2.05, 5.14, 0.8), _faces("poster"), yaw_deg=8,
             cls="pillow", ppm=300.0),
        _box("pillow1", (2.6, 4.98, 0.42), (3.0, 5.14, 0.78), _faces("fabric"), yaw_deg=-10,
             cls="pillow", ppm=300.0),
        _box("whiteboard", (1.3, 5.46, 1.05), (3.3, 5.5, 2.05), _faces("metal_plain", front="whiteboard"),
             cls="whiteboard", ppm=300.0),
        _box("coffee_table", (1.7, 4.0, 0.38), (2.9, 4.5, 0.42), _faces("wood", top="desk_top"),
             cls="table", ppm=300.0),
        *_legs("coffee_table", 1.72, 2.88, 4.02, 4.48, 0.38, "table"),
        _box("table_magazine", (1.85, 4.1, 0.42), (2.1, 4.35, 0.425), _faces("paper", top="poster"),
             yaw_deg=-20, cls="books", ppm=500.0),
        _box("table_box", (2.45, 4.15, 0.42), (2.7, 4.35, 0.55), "cardboard", yaw_deg=14, cls="box",
             ppm=400.0),
        _box("sideboard", (3.9, 5.0, 0.0), (5.6, 5.45, 0.6), _faces("wood", front="metal"),
             cls="cabinet", ppm=250.0),
        _box("tv", (4.2, 5.25, 0.68), (5.3, 5.31, 1.32), _faces("metal_plain", front="screen"),
             yaw_deg=-4, cls="television", ppm=400.0),
        _box("tv_stand", (4.65, 5.2, 0.6), (4.85, 5.35, 0.68), "metal_plain", cls="television",
             ppm=100.0),
        _box("speaker", (3.95, 5.1, 0.6), (4.12, 5.28, 0.95), _faces("fabric"), cls="otherprop",
             ppm=300.0),
        _box("lamp_base", (6.05, 4.95, 0.0), (6.35, 5.25, 0.05), "metal_plain", cls="lamp", ppm=150.0),
        _box("lamp_pole", (6.18, 5.08, 0.05), (6.22, 5.12, 1.45), "metal_plain", cls="lamp", ppm=150.0),
        _box("lamp_shade", (5.98, 4.88, 1.45), (6.42, 5.32, 1.75), _faces("paper"), cls="lamp",
             ppm=250.0),
    ]


def _left_side() -> list[Box]:
    """Window with a curtain on the left wall, a desk in the back-left corner."""
    return [
        _box("window", (-0.7, 1.3, 0.9), (-0.66, 3.3, 2.3), _faces("metal_plain", front="picture",
             front_axis=0), cls="window", ppm=250.0),
        _box("curtain", (-0.7, 3.35, 0.3), (-0.58, 3.9, 2.7), _faces("fabric"), cls="curtain",
             ppm=200.0),
        _box("corner_desk", (-0.7, 4.0, 0.72), (0.15, 5.5, 0.75), _faces("wood", top="desk_top"),
             cls="desk", ppm=300.0),
        *_legs("corner_desk", 0.08 - 0.75, 0.14, 4.02, 5.48, 0.72, "desk"),
        _box("corner_monitor", (-0.55, 4.4, 0.9), (-0.5, 5.0, 1.26), _faces("metal_plain", front="screen",
             front_axis=0), yaw_deg=5, cls="television", ppm=400.0),
        _box("corner_books", (-0.45, 5.05, 0.75), (-0.15, 5.35, 0.9), _faces("books", top="poster"),
             yaw_deg=-8, cls="books", ppm=400.0),
        _box("corner_chair_seat", (0.2, 4.3, 0.44), (0.65, 4.75, 0.5), _faces("fabric"), yaw_deg=-12,
             cls="chair", ppm=250.0),
        _box("corner_chair_post", (0.39, 4.49, 0.08), (0.46, 4.56, 0.44), "metal_plain", cls="chair",
             ppm=100.0),
        _box("corner_chair_back", (0.6, 4.3, 0.5), (0.65, 4.75, 0.92), _faces("fabric"), yaw_deg=-12,
             cls="chair", ppm=250.0),
    ]


def _right_and_front() -> list[Box]:
    """Tall bookshelf and a plant stand on the right; low shelves, door and boxes in front."""
    return [
        _box("bookshelf", (6.45, 1.9, 0.0), (6.9, 3.7, 2.1), _faces("wood", front="books", front_axis=1),
             cls="bookshelf", ppm=300.0),
        _box("bookshelf_box", (6.5, 2.2, 2.1), (6.85, 2.6, 2.35), "cardboard", yaw_deg=-5, cls="box",
             ppm=300.0),
        _box("side_table", (6.0, 0.6, 0.0), (6.6, 1.2, 0.55), _faces("wood", top="desk_top"),
             cls="otherfurniture", ppm=250.0),
        _box("low_shelves", (0.4, -0.4, 0.0), (2.4, -0.05, 1.2), _faces("wood", front="books", front_axis=2),
             cls="shelves", ppm=300.0),
        _box("door", (4.8, -0.4, 0.0), (5.7, -0.36, 2.05), _faces("wood", front="painted", front_axis=2),
             cls="door", ppm=200.0),
        _box("front_crate0", (-0.6, -0.3, 0.0), (0.0, 0.3, 0.5), "cardboard", yaw_deg=7, cls="box", ppm=300.0),
        _box("front_crate1", (-0.5, -0.2, 0.5), (-0.1, 0.2, 0.8), "cardboard", yaw_deg=-6, cls="box",
             ppm=300.0),
    ]


def lounge_boxes() -> list[Box]:
    """The room (parquet floor) and its furniture; textures vary with the seed."""
    room = _box("room", ROOM_MIN, ROOM_MAX, ("wall", "wall", "wall", "wall", "ceiling", "wood"),
                inside=True, cls=("wall", "wall", "wall", "wall", "ceiling", "floor"), ppm=200.0)
    return [room, *_back_wall(), *_left_side(), *_right_and_front()]
