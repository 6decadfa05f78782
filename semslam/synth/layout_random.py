"""Layouts 2 and up: rooms furnished at random (seeded by the layout number), for training.

Why: one room teaches a depth network that room (trained in layout 0 only, SDFCNN's depth on
the lounge, layout 1, is worse than a constant); many rooms of other sizes, with furniture of
other kinds in other places, are what generalisation needs, and hand-made rooms are slow to
make. Layout ``n`` is always the same room. Furniture goes along the walls, each unit a few
boxes in wall coordinates (``a`` along the wall, ``d`` out of it, ``z`` up), kept out of
:data:`~semslam.synth.layouts.FREE_ZONES`: the back wall's units start 3.95 m into the room,
the side walls' stop 0.42 m / 5.5 m into it, the front wall's at 0.8 m.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from semslam.synth.texture_atlas import Lights
from semslam.synth.scene import Box, _box, _faces

Rng = np.random.Generator
#: (name, a0, a1, d0, d1, z0, z1, side, top, front, class, ppm, yaw) in wall coordinates.
Part = tuple[str, float, float, float, float, float, float, str, str, str, str, float, float]
#: Inward face of a box standing against each wall (FACE_AXES order: +x -x +y -y).
_FRONT = {"back": 3, "front": 2, "left": 0, "right": 1}


def _p(name: str, a: tuple[float, float], d: tuple[float, float], z: tuple[float, float], side: str,
       cls: str, top: str | None = None, front: str | None = None, ppm: float = 300.0,
       yaw: float = 0.0) -> Part:
    return (name, a[0], a[1], d[0], d[1], z[0], z[1], side, top or side, front or side, cls, ppm, yaw)


def _legs(name: str, a0: float, a1: float, d0: float, d1: float, z1: float, cls: str) -> list[Part]:
    return [_p(f"{name}_leg{i}", (a, a + 0.04), (d, d + 0.04), (0.0, z1), "metal_plain", cls, ppm=100.0)
            for i, (a, d) in enumerate(((a0, d0), (a1 - 0.04, d0), (a0, d1 - 0.04), (a1 - 0.04, d1 - 0.04)))]


def _desk(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    m = a0 + w * rng.uniform(0.3, 0.7)
    parts = [_p("desk_top", (a0, a0 + w), (0.0, 0.75), (0.72, 0.75), "wood", "desk", top="desk_top"),
             *_legs("desk", a0, a0 + w, 0.05, 0.75, 0.72, "desk"),
             _p("monitor", (m - 0.3, m + 0.3), (0.12, 0.17), (0.9, 1.26), "metal_plain", "television",
                front="screen", ppm=400.0, yaw=rng.uniform(-8, 8)),
             _p("monitor_stand", (m - 0.05, m + 0.05), (0.1, 0.2), (0.75, 0.9), "metal_plain", "television",
                ppm=100.0),
             _p("keyboard", (m - 0.22, m + 0.22), (0.35, 0.5), (0.75, 0.77), "metal_plain", "otherprop",
                top="keyboard", ppm=500.0, yaw=rng.uniform(-5, 5))]
    b = a0 + 0.1 if m - a0 > 0.55 else a0 + w - 0.35
    parts.append(_p("desk_books", (b, b + 0.25), (0.15, 0.4), (0.75, 0.75 + rng.uniform(0.05, 0.2)), "books",
                    "books", top="poster", ppm=400.0, yaw=rng.uniform(-15, 15)))
    if depth >= 1.35:
        c = m + rng.uniform(-0.2, 0.2)
        parts += [_p("chair_seat", (c - 0.23, c + 0.23), (0.8, 1.25), (0.44, 0.5), "fabric", "chair",
                     ppm=250.0, yaw=rng.uniform(-15, 15)),
                  _p("chair_post", (c - 0.035, c + 0.035), (0.99, 1.06), (0.08, 0.44), "metal_plain", "chair",
                     ppm=100.0),
                  _p("chair_back", (c - 0.22, c + 0.22), (1.2, 1.25), (0.5, 0.92), "fabric", "chair",
                     ppm=250.0)]
    return parts


def _sofa(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    a1 = a0 + w
    parts = [_p("sofa_seat", (a0, a1), (0.0, 0.8), (0.0, 0.42), "fabric", "sofa", ppm=250.0),
             _p("sofa_back", (a0, a1), (0.0, 0.28), (0.42, 0.88), "fabric", "sofa", ppm=250.0),
             _p("sofa_arm0", (a0, a0 + 0.2), (0.28, 0.8), (0.42, 0.62), "fabric", "sofa", ppm=250.0),
             _p("sofa_arm1", (a1 - 0.2, a1), (0.28, 0.8), (0.42, 0.62), "fabric", "sofa", ppm=250.0)]
    for i in range(int(rng.integers(1, 4))):
        c = a0 + 0.45 + i * (w - 0.9) / 2
        parts.append(_p(f"pillow{i}", (c - 0.2, c + 0.2), (0.3, 0.44), (0.42, 0.78),
                        str(rng.choice(["fabric", "poster"])), "pillow", yaw=rng.uniform(-12, 12)))
    return parts


def _sideboard(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    h = rng.uniform(0.5, 0.8)
    m = a0 + w / 2
    return [_p("sideboard", (a0, a0 + w), (0.0, 0.45), (0.0, h), "wood", "cabinet", top="wood", front="metal"),
            _p("tv", (m - 0.5, m + 0.5), (0.18, 0.24), (h + 0.08, h + 0.66), "metal_plain", "television",
               front="screen", ppm=400.0, yaw=rng.uniform(-5, 5)),
            _p("tv_stand", (m - 0.1, m + 0.1), (0.12, 0.28), (h, h + 0.08), "metal_plain", "television", ppm=100.0)]


def _bookshelf(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    h = rng.uniform(1.5, 2.2)
    parts = [_p("bookshelf", (a0, a0 + w), (0.0, 0.4), (0.0, h), "wood", "bookshelf", front="books")]
    if rng.random() < 0.5:
        parts.append(_p("shelf_box", (a0 + 0.1, a0 + 0.45), (0.02, 0.37), (h, h + 0.25), "cardboard", "box"))
    return parts


def _low_shelves(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    return [_p("low_shelves", (a0, a0 + w), (0.0, 0.35), (0.0, rng.uniform(0.7, 1.2)), "wood", "shelves",
               front="books")]


def _cabinet(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    h = rng.uniform(0.7, 1.35)
    parts = [_p("cabinet", (a0, a0 + w), (0.0, 0.6), (0.0, h), "metal", "cabinet", front="metal")]
    if rng.random() < 0.6:
        parts.append(_p("cabinet_box", (a0 + 0.05, a0 + 0.45), (0.1, 0.5), (h, h + 0.3), "cardboard", "box",
                        yaw=rng.uniform(-10, 10)))
    return parts


def _counter(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    s = a0 + rng.uniform(0.2, w - 0.7)
    return [_p("counter", (a0, a0 + w), (0.0, 0.6), (0.0, 0.9), "painted", "counter", top="desk_top",
               front="wood"),
            _p("sink", (s, s + 0.5), (0.1, 0.45), (0.9, 0.95), "metal_plain", "sink", ppm=300.0),
            _p("wall_cabinet", (a0, a0 + w), (0.0, 0.35), (1.5, 2.2), "wood", "cabinet", front="painted")]


def _fridge(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    return [_p("fridge", (a0, a0 + w), (0.0, 0.68), (0.0, rng.uniform(1.6, 1.9)), "metal_plain",
               "refridgerator", front="paper")]


def _table(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    d0 = 0.15
    parts = [_p("table_top", (a0, a0 + w), (d0, d0 + 0.8), (0.72, 0.75), "wood", "table", top="desk_top"),
             *_legs("table", a0, a0 + w, d0, d0 + 0.8, 0.72, "table"),
             _p("table_box", (a0 + 0.2, a0 + 0.45), (d0 + 0.2, d0 + 0.45), (0.75, 0.87), "cardboard", "box",
                yaw=rng.uniform(-20, 20))]
    c = a0 + w / 2
    parts += [_p("tchair_seat", (c - 0.22, c + 0.22), (d0 + 0.85, d0 + 1.25), (0.44, 0.5), "fabric", "chair",
                 ppm=250.0)] if depth >= d0 + 1.3 else []
    return parts


def _boxes(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    h0 = rng.uniform(0.3, 0.5)
    parts = [_p("crate0", (a0, a0 + w), (0.0, min(depth, 0.55)), (0.0, h0), "cardboard", "box", yaw=0.0)]
    if rng.random() < 0.6:
        parts.append(_p("crate1", (a0 + 0.05, a0 + w - 0.1), (0.05, min(depth, 0.55) - 0.05), (h0, h0 + 0.3),
                        "cardboard", "box", yaw=rng.uniform(-8, 8)))
    return parts


def _plant(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    return [_p("pot", (a0 + 0.05, a0 + w - 0.05), (0.05, 0.35), (0.0, 0.35), "painted", "otherprop"),
            _p("leaves", (a0, a0 + w), (0.0, 0.4), (0.35, rng.uniform(0.9, 1.4)), "fabric", "otherprop", ppm=250.0)]


def _lamp(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    m = a0 + w / 2
    return [_p("lamp_base", (m - 0.15, m + 0.15), (0.05, 0.35), (0.0, 0.05), "metal_plain", "lamp", ppm=150.0),
            _p("lamp_pole", (m - 0.02, m + 0.02), (0.18, 0.22), (0.05, 1.45), "metal_plain", "lamp", ppm=150.0),
            _p("lamp_shade", (m - 0.2, m + 0.2), (0.0, 0.4), (1.45, 1.75), "paper", "lamp", ppm=250.0)]


def _door(a0: float, w: float, depth: float, rng: Rng) -> list[Part]:
    return [_p("door", (a0, a0 + w), (0.0, 0.04), (0.0, 2.05), "wood", "door", front="painted", ppm=200.0)]


@dataclass(frozen=True)
class Unit:
    make: Callable[[float, float, float, Rng], list[Part]]
    width: tuple[float, float]
    depth: float  # needed out of the wall
    height: float  # of its tallest part (wall decorations go above low units)


UNITS = {
    "desk": Unit(_desk, (1.2, 1.6), 0.8, 1.3), "sofa": Unit(_sofa, (1.6, 2.2), 0.82, 0.9),
    "sideboard": Unit(_sideboard, (1.2, 1.8), 0.47, 1.5), "bookshelf": Unit(_bookshelf, (0.8, 1.6), 0.42, 2.5),
    "low_shelves": Unit(_low_shelves, (1.0, 2.0), 0.37, 1.2), "cabinet": Unit(_cabinet, (0.5, 1.2), 0.62, 1.7),
    "counter": Unit(_counter, (1.2, 2.4), 0.62, 2.2), "fridge": Unit(_fridge, (0.65, 0.8), 0.7, 1.9),
    "table": Unit(_table, (1.2, 1.6), 1.0, 0.9), "boxes": Unit(_boxes, (0.5, 0.9), 0.4, 0.8),
    "plant": Unit(_plant, (0.35, 0.5), 0.42, 1.4), "lamp": Unit(_lamp, (0.4, 0.45), 0.42, 1.75),
    "door": Unit(_door, (0.85, 1.0), 0.05, 2.1),
}
#: Wall decorations above low units: (texture, class).
DECOR = (("whiteboard", "whiteboard"), ("picture", "picture"), ("picture", "window"),
         ("notice_board", "otherstructure"), ("poster", "picture"))


def _to_world(part: Part, wall: str, room_lo: np.ndarray, room_hi: np.ndarray, tag: str) -> Box:
    """A part in wall coordinates as a world box with its front face towards the room."""
    name, a0, a1, d0, d1, z0, z1, side, top, front, cls, ppm, yaw = part
    if wall == "back":
        lo, hi = (a0, room_hi[1] - d1, z0), (a1, room_hi[1] - d0, z1)
    elif wall == "front":
        lo, hi = (a0, room_lo[1] + d0, z0), (a1, room_lo[1] + d1, z1)
    elif wall == "left":
        lo, hi = (room_lo[0] + d0, a0, z0), (room_lo[0] + d1, a1, z1)
    else:
        lo, hi = (room_hi[0] - d1, a0, z0), (room_hi[0] - d0, a1, z1)
    return _box(f"{tag}_{name}", lo, hi, _faces(side, top=top, front=front, front_axis=_FRONT[wall]),
                yaw_deg=yaw, cls=cls, ppm=ppm)


def _furnish(wall: str, a_range: tuple[float, float], depth: float, rng: Rng,
             room_lo: np.ndarray, room_hi: np.ndarray) -> list[Box]:
    """Units side by side along one wall, each chosen among those that fit its depth."""
    fits = [k for k, u in UNITS.items() if u.depth <= depth]
    a, end = a_range[0] + rng.uniform(0.0, 0.3), a_range[1]
    out: list[Box] = []
    for i in range(12):
        kind = str(rng.choice(fits))
        unit = UNITS[kind]
        w = float(rng.uniform(*unit.width))
        if a + w > end:
            break
        tag = f"{wall}{i}_{kind}"
        out += [_to_world(p, wall, room_lo, room_hi, tag) for p in unit.make(a, w, depth, rng)]
        if unit.height < 1.0 and rng.random() < 0.7:
            tex, cls = DECOR[int(rng.integers(len(DECOR)))]
            z0 = rng.uniform(1.05, 1.3)
            deco = _p("decor", (a + 0.1, a + w - 0.1), (0.0, 0.03), (z0, z0 + rng.uniform(0.5, 1.0)), "metal_plain",
                      cls, front=tex)
            out.append(_to_world(deco, wall, room_lo, room_hi, tag))
        a += w + float(rng.uniform(0.05, 0.6))
    return out


def random_room(number: int) -> tuple[list[Box], Lights]:
    """Layout ``number``'s boxes (the room first) and its three ceiling lights."""
    rng = np.random.default_rng([number, 4242])
    lo = np.array([-rng.uniform(0.1, 1.0), -rng.uniform(0.1, 0.6), 0.0])
    hi = np.array([rng.uniform(5.8, 7.0), rng.uniform(4.4, 5.8), rng.uniform(2.6, 3.2)])
    walls, floor = str(rng.choice(["wall", "painted"])), str(rng.choice(["floor", "wood"]))
    room = _box("room", tuple(lo), tuple(hi), (walls,) * 4 + ("ceiling", floor), inside=True,
                cls=("wall", "wall", "wall", "wall", "ceiling", "floor"), ppm=200.0)
    boxes = [room]
    boxes += _furnish("back", (lo[0], hi[0]), hi[1] - 3.95, rng, lo, hi)
    boxes += _furnish("left", (0.85, 3.9), 0.42 - lo[0], rng, lo, hi)
    boxes += _furnish("right", (0.85, 3.9), hi[0] - 5.5, rng, lo, hi)
    boxes += _furnish("front", (0.45, 5.45), 0.8 - lo[1], rng, lo, hi)
    lights = tuple((np.array([rng.uniform(lo[0] + 0.5, hi[0] - 0.5), rng.uniform(lo[1] + 0.5, hi[1] - 0.5),
                              hi[2] - 0.1]), float(rng.uniform(0.5, 1.0))) for _ in range(3))
    return boxes, lights
