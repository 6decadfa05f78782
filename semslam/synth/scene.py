"""The synthetic office: a room and furniture as textured (possibly rotated) boxes.

Everything static is a box because a ray/box test (slab method) is cheap to vectorise and
a box's six faces give walls, desks, shelves, monitors and parcels alike. The room is a
box seen from inside. World frame: x to the right of the rest view, y away from the
camera, z up; the floor is z = 0.

Every static box carries an NYU-40 class per face (label id ``100 + NYU id``, see
:mod:`semslam.core.labels`), given where the box is defined, so the semantic images label
walls, floor, desks, chairs ... and the movers keep their own ids (person 15, mover 21).
Things painted on a texture (posters and boards on the walls, the books on the shelf's
front) take the class of the face they are painted on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import NYU40_CLASSES, SYNTH_STATIC_OFFSET, synth_static_id
from semslam.geometry.se3 import so3_exp

Array = NDArray[np.float64]

ROOM_SIZE = (6.0, 5.0, 2.8)
#: Ceiling lights (position, relative intensity) used to bake shading into textures.
LIGHTS = (
    (np.array([2.0, 2.4, 2.7]), 1.0),
    (np.array([4.2, 3.6, 2.7]), 0.9),
    (np.array([3.0, 0.8, 2.7]), 0.5),
)

#: Face order of a box: +x, -x, +y, -y, +z, -z (index = 2 * axis + (0 if + else 1)).
FACE_AXES = ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1))

LABEL_NONE = 0  # "background": no surface hit (never inside the room)
LABEL_PERSON = 15
LABEL_MOVER = 21


@dataclass
class Box:
    """An oriented box with one texture kind per face.

    ``faces`` lists six texture kinds (see ``textures.GENERATORS``) in :data:`FACE_AXES`
    order; ``inside`` marks the room, whose faces are seen from within. A static box has
    ``classes``, six label ids (100 + NYU-40 id) in the same order; a mover has none and
    is labelled ``label`` on every face.
    """

    name: str
    center: Array
    size: Array
    rot: Array = field(default_factory=lambda: np.eye(3))
    faces: tuple[str, ...] = ("wood",) * 6
    label: int = LABEL_NONE
    inside: bool = False
    ppm: float = 256.0
    classes: tuple[int, ...] = ()

    @property
    def half(self) -> Array:
        return np.asarray(self.size, float) / 2.0

    def corners(self) -> Array:
        """The eight corners in world coordinates ``(8, 3)``."""
        s = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        return self.center + (s * self.half) @ self.rot.T

    def face_frame(self, f: int) -> tuple[Array, Array, Array, float, float]:
        """For face ``f``: viewer-facing normal, right and up axes (box-local), width, height.

        Texture coordinates are ``a`` (metres to the right) and ``b`` (metres down) seen
        from the side the face is viewed from, so text on textures reads correctly.
        """
        axis, sign = FACE_AXES[f]
        n = np.zeros(3)
        n[axis] = -sign if self.inside else sign
        if axis == 2:
            up = np.array([0.0, 1.0, 0.0])
        else:
            up = np.array([0.0, 0.0, 1.0])
        right = np.cross(up, n)
        half = self.half
        w = 2 * float(np.abs(right) @ half)
        h = 2 * float(np.abs(up) @ half)
        return n, right, up, w, h

    def face_point(self, f: int, a: Array, b: Array) -> Array:
        """World points ``(..., 3)`` of face ``f`` at texture coordinates (a, b) in metres."""
        axis, sign = FACE_AXES[f]
        _, right, up, w, h = self.face_frame(f)
        centre = np.zeros(3)
        centre[axis] = sign * self.half[axis]
        local = (
            centre
            + (np.asarray(a)[..., None] - w / 2) * right
            - (np.asarray(b)[..., None] - h / 2) * up
        )
        return self.center + local @ self.rot.T

    def world_normal(self, f: int) -> Array:
        return self.rot @ self.face_frame(f)[0]


def _box(
    name: str,
    lo: tuple[float, float, float],
    hi: tuple[float, float, float],
    faces,
    yaw_deg: float = 0.0,
    cls: str | tuple[str, ...] | None = None,
    **kw,
) -> Box:
    """Box from axis-aligned corners (before an optional yaw about its centre).

    ``cls`` is the NYU-40 class name of every face, or six names in :data:`FACE_AXES`
    order (static boxes); movers leave it out and pass ``label``.
    """
    lo_a, hi_a = np.array(lo, float), np.array(hi, float)
    if isinstance(faces, str):
        faces = (faces,) * 6
    if isinstance(cls, str):
        cls = (cls,) * 6
    classes = tuple(synth_static_id(c) for c in cls) if cls is not None else ()
    rot = so3_exp(np.array([0.0, 0.0, np.deg2rad(yaw_deg)]))
    return Box(name, (lo_a + hi_a) / 2, hi_a - lo_a, rot, tuple(faces), classes=classes, **kw)


def _faces(
    side: str,
    top: str | None = None,
    front: str | None = None,
    front_axis: int = 3,
    bottom: str | None = None,
) -> tuple[str, ...]:
    """Face kinds with one distinguished front face (default -y, towards the camera)."""
    f = [side] * 6
    f[4] = top or side
    f[5] = bottom or side
    if front is not None:
        f[front_axis] = front
    return tuple(f)


def static_boxes() -> list[Box]:
    """The room and its furniture (fixed layout; textures vary with the seed).

    The walking area of the people (x 0.6..5.4, y 2.5..3.95) is kept free.
    """
    rx, ry, rz = ROOM_SIZE
    boxes = [
        _box(
            "room",
            (0, 0, 0),
            (rx, ry, rz),
            ("wall", "wall", "wall", "wall", "ceiling", "floor"),
            inside=True,
            cls=("wall", "wall", "wall", "wall", "ceiling", "floor"),
            ppm=200.0,
        ),
        # partition board behind the desks, like the fr3 office
        _box(
            "partition",
            (1.2, 4.9, 0.0),
            (4.8, 4.95, 1.65),
            _faces("painted", front="partition"),
            cls="otherstructure",
            ppm=256.0,
        ),
    ]
    # two desks along the partition
    for i, (x0, x1) in enumerate(((1.45, 2.98), (3.02, 4.55))):
        boxes.append(
            _box(
                f"desk{i}_top",
                (x0, 4.15, 0.72),
                (x1, 4.88, 0.75),
                _faces("wood", top="desk_top"),
                cls="desk",
                ppm=300.0,
            )
        )
        for lx in (x0 + 0.03, x1 - 0.08):
            boxes.append(
                _box(
                    f"desk{i}_leg",
                    (lx, 4.2, 0.0),
                    (lx + 0.05, 4.25, 0.72),
                    "metal_plain",
                    cls="desk",
                    ppm=100.0,
                )
            )
        boxes.append(
            _box(
                f"desk{i}_panel",
                (x0 + 0.05, 4.8, 0.15),
                (x1 - 0.05, 4.83, 0.72),
                _faces("wood", front="painted"),
                cls="desk",
                ppm=150.0,
            )
        )
    # things on desk 0: monitor, stand, keyboard, books, parcel
    boxes += [
        _box(
            "monitor",
            (1.85, 4.55, 0.92),
            (2.45, 4.6, 1.28),
            _faces("metal_plain", front="screen"),
            yaw_deg=-6,
            cls="television",
            ppm=400.0,
        ),
        _box(
            "monitor_stand",
            (2.1, 4.55, 0.75),
            (2.2, 4.62, 0.92),
            "metal_plain",
            cls="television",
            ppm=100.0,
        ),
        _box(
            "keyboard",
            (1.9, 4.25, 0.75),
            (2.35, 4.4, 0.77),
            _faces("metal_plain", top="keyboard"),
            yaw_deg=3,
            cls="otherprop",
            ppm=500.0,
        ),
        _box(
            "books_stack",
            (1.55, 4.3, 0.75),
            (1.8, 4.52, 0.87),
            _faces("books", top="poster"),
            yaw_deg=12,
            cls="books",
            ppm=400.0,
        ),
        _box(
            "parcel",
            (2.55, 4.45, 0.75),
            (2.9, 4.75, 1.0),
            "cardboard",
            yaw_deg=-15,
            cls="box",
            ppm=350.0,
        ),
    ]
    # things on desk 1: white cabinet with stickers, dice, laptop, magazine, bottles
    boxes += [
        _box(
            "cabinet_small",
            (3.2, 4.45, 0.75),
            (4.0, 4.8, 1.1),
            _faces("painted", top="paper", front="poster"),
            cls="cabinet",
            ppm=300.0,
        ),
        _box(
            "dice",
            (3.45, 4.2, 0.75),
            (3.6, 4.35, 0.9),
            "fabric",
            yaw_deg=20,
            cls="otherprop",
            ppm=400.0,
        ),
        _box(
            "laptop_base",
            (4.05, 4.2, 0.75),
            (4.4, 4.45, 0.77),
            _faces("metal_plain", top="keyboard"),
            yaw_deg=-10,
            cls="otherprop",
            ppm=500.0,
        ),
        _box(
            "laptop_screen",
            (4.05, 4.45, 0.77),
            (4.4, 4.47, 1.0),
            _faces("metal_plain", front="screen"),
            yaw_deg=-10,
            cls="otherprop",
            ppm=500.0,
        ),
        _box(
            "magazine",
            (3.7, 4.18, 0.75),
            (3.93, 4.42, 0.755),
            _faces("paper", top="poster"),
            yaw_deg=25,
            cls="books",
            ppm=500.0,
        ),
        _box(
            "bottle0",
            (3.15, 4.3, 0.75),
            (3.22, 4.37, 1.02),
            _faces("poster"),
            cls="otherprop",
            ppm=500.0,
        ),
        _box(
            "bottle1",
            (4.45, 4.6, 0.75),
            (4.52, 4.67, 1.0),
            _faces("poster"),
            cls="otherprop",
            ppm=500.0,
        ),
    ]
    # bookshelf on the left wall, filing cabinets and boxes on the right
    boxes += [
        _box(
            "shelf",
            (0.0, 2.6, 0.0),
            (0.42, 4.7, 1.95),
            _faces("wood", front="books", front_axis=0),
            cls="bookshelf",
            ppm=300.0,
        ),
        _box(
            "shelf_top_box", (0.05, 3.0, 1.95), (0.4, 3.4, 2.2), "cardboard", cls="box", ppm=300.0
        ),
        _box(
            "filing0",
            (5.52, 3.4, 0.0),
            (6.0, 4.0, 1.1),
            _faces("metal", front="metal", front_axis=1),
            cls="cabinet",
            ppm=300.0,
        ),
        _box(
            "filing1",
            (5.52, 4.05, 0.0),
            (6.0, 4.65, 1.1),
            _faces("metal", front="metal", front_axis=1),
            cls="cabinet",
            ppm=300.0,
        ),
        _box(
            "filing_box",
            (5.55, 3.5, 1.1),
            (5.95, 3.9, 1.4),
            "cardboard",
            yaw_deg=8,
            cls="box",
            ppm=300.0,
        ),
        _box(
            "crate0",
            (0.1, 1.4, 0.0),
            (0.65, 1.95, 0.45),
            "cardboard",
            yaw_deg=6,
            cls="box",
            ppm=300.0,
        ),
        _box(
            "crate1",
            (0.15, 1.5, 0.45),
            (0.55, 1.85, 0.75),
            "cardboard",
            yaw_deg=-9,
            cls="box",
            ppm=300.0,
        ),
        _box(
            "bin",
            (4.7, 4.3, 0.0),
            (4.95, 4.55, 0.38),
            _faces("metal_plain", top="metal_plain"),
            cls="otherfurniture",
            ppm=200.0,
        ),
        _box(
            "chair_seat",
            (1.95, 3.95, 0.44),
            (2.42, 4.4, 0.5),
            _faces("fabric"),
            yaw_deg=10,
            cls="chair",
            ppm=250.0,
        ),
        _box(
            "chair_post",
            (2.15, 4.14, 0.08),
            (2.22, 4.21, 0.44),
            "metal_plain",
            cls="chair",
            ppm=100.0,
        ),
        _box(
            "chair_back",
            (1.97, 4.36, 0.5),
            (2.4, 4.41, 0.9),
            _faces("fabric"),
            yaw_deg=10,
            cls="chair",
            ppm=250.0,
        ),
        _box(
            "radiator",
            (2.2, 0.0, 0.15),
            (3.8, 0.1, 0.75),
            _faces("metal_plain", front="metal", front_axis=2),
            cls="otherfurniture",
            ppm=150.0,
        ),
        _box(
            "door",
            (4.5, 0.0, 0.0),
            (5.4, 0.04, 2.05),
            _faces("wood", front="painted", front_axis=2),
            cls="door",
            ppm=200.0,
        ),
    ]
    return boxes


def static_class_names(boxes: list[Box]) -> dict[int, str]:
    """Label id -> NYU-40 class name of every class that ``boxes`` carry (sorted by id)."""
    ids = sorted({c for b in boxes for c in b.classes})
    return {i: NYU40_CLASSES[i - SYNTH_STATIC_OFFSET] for i in ids}


def mover_box(t: float) -> Box:
    """The "unknown mover": a rolling cabinet covered in posters, pushed across the room.

    It slides 1.6 m either side of the centre with a 10 s period (peak ~1 m/s) and yaws a
    little, in front of the desks, so that it fills a large part of the view.
    """
    x = 3.0 + 1.6 * np.sin(2 * np.pi * t / 10.0)
    y = 3.35 + 0.15 * np.sin(2 * np.pi * t / 7.0)
    yaw = 8.0 * np.sin(2 * np.pi * t / 6.0)
    box = _box(
        "mover",
        (x - 0.45, y - 0.25, 0.02),
        (x + 0.45, y + 0.25, 1.12),
        _faces("partition", top="cardboard", front="poster"),
        yaw_deg=yaw,
        label=LABEL_MOVER,
        ppm=256.0,
    )
    return box
