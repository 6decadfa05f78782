"""Room layouts of the synthetic sequences, by number (``SynthConfig.layout``).

Why numbers: a layout is part of a sequence's identity (``sequence.json``) and of the
training recipes (NETS.md), so it must be a stable name; layout 0 is the office every
sequence had before layouts existed, rendered byte for byte as then. Every layout keeps
:data:`FREE_ZONES` empty, because the camera motions (:mod:`camera_motion`), the people's
paths, the rolling mover and the carried box are defined in world coordinates for all.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from semslam.errors import ConfigError
from semslam.synth import layout_lounge, layout_random, scene
from semslam.synth.texture_atlas import Lights
from semslam.synth.scene import Box

#: World boxes (min, max) that no static box of any layout may enter: where every camera
#: motion's eye goes (with >= 0.2 m to spare), and the floor where people, the mover and the
#: carried box go (the carried box's leftmost key reaches x = 0.40, 2 cm into the office's
#: shelf, as it always did).
CAMERA_ZONE = ((0.85, 0.8, 1.0), (5.1, 2.6, 2.0))
FLOOR_ZONE = ((0.42, 2.1, 0.0), (5.5, 3.9, 2.2))
FREE_ZONES = (CAMERA_ZONE, FLOOR_ZONE)


@dataclass(frozen=True)
class Layout:
    """A room: its static boxes (the room first) and the lights baked into the textures."""

    name: str
    boxes: Callable[[], list[Box]]
    lights: Lights


LAYOUTS: dict[int, Layout] = {
    0: Layout("office", scene.static_boxes, scene.LIGHTS),
    1: Layout("lounge", layout_lounge.lounge_boxes, layout_lounge.LIGHTS),
}
#: Layouts 2..MAX_LAYOUT are furnished at random, seeded by their number (for training).
MAX_LAYOUT = 99


def get_layout(number: int) -> Layout:
    """Layout ``number``; :class:`ConfigError` naming the layouts otherwise."""
    if number in LAYOUTS:
        return LAYOUTS[number]
    if 2 <= number <= MAX_LAYOUT:
        boxes, lights = layout_random.random_room(number)  # furnished once, not again per call
        return Layout(f"random {number}", lambda: list(boxes), lights)
    raise ConfigError(f"synth: unknown layout {number} (choose from 0 (office), 1 (lounge), "
                      f"2-{MAX_LAYOUT} (furnished at random))")
