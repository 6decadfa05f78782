"""A person who pushes a large box across the room, lifts it and carries it to the camera.

The box is the hard case for semantic SLAM: it is no person (label 21, "moving_object"),
so no person segmenter flags it. It is pushed into the view from the left along the
floor, stops, is lifted to chest height, carried to about 1 m in front of the camera,
where it covers up to ~60 % of the image, then carried out of the view to the left and
set down where it started. The person walks behind it (the box hides the lower body).

Everything is a function of time with a 10 s period: key poses joined by smoothstep
segments (zero velocity at every key, so the box and the person start and stop like real
ones; the fastest segment peaks at ~1.3 m/s).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.synth.scene import LABEL_MOVER, Box, _box, _faces

PERIOD = 10.0
#: Width (x), depth (y), height (z) in metres: a large moving carton.
BOX_SIZE = (1.0, 0.6, 0.8)

#: Box keys: (time s, centre x, centre y, bottom z, yaw deg). The camera rests at
#: (3.0, 1.45, 1.4) looking along +y (a ~64 deg wide view): A = (1.1, 3.2) and
#: D = (0.9, 2.9) are just outside its left border, B = (3.6, 3.3) is right of the view
#: centre at ~2 m, C = (3.0, 2.5) is 0.8-1.2 m in front of the camera (its xyz motion moves
#: it +-0.2 m along the view), where the box covers ~60 % of the image.
_BOX_KEYS = np.array(
    [
        (0.0, 1.1, 3.2, 0.0, 0.0),  # at A, out of view
        (0.4, 1.1, 3.2, 0.0, 0.0),
        (3.6, 3.6, 3.3, 0.0, 6.0),  # pushed along the floor into the view to B
        (4.1, 3.6, 3.3, 0.0, 6.0),  # the person steps behind it
        (4.8, 3.6, 3.3, 0.6, 4.0),  # lifted to chest height
        (6.4, 3.0, 2.5, 0.6, -6.0),  # carried to C, close to the camera
        (6.7, 3.0, 2.55, 0.6, -4.0),
        (9.2, 0.9, 2.9, 0.6, 0.0),  # carried out of view to the left (D)
        (10.0, 1.1, 3.2, 0.0, 0.0),  # set down at A, out of view
    ]
)

_PUSH = (-0.45, BOX_SIZE[1] / 2 + 0.2)  # behind its trailing corner, pushing along +x
_CARRY = (0.0, BOX_SIZE[1] / 2 + 0.25)  # behind it (farther from the camera), holding it
#: The person's feet relative to the box centre: (time s, dx, dy).
_PERSON_KEYS = np.array(
    [
        (0.0, *_PUSH),
        (3.6, *_PUSH),
        (4.1, *_CARRY),
        (9.2, *_CARRY),
        (10.0, *_PUSH),
    ]
)


def _keyed(keys: NDArray[np.float64], t: float) -> NDArray[np.float64]:
    """Values at time ``t`` (periodic) from ``(time, values...)`` rows, smoothstep between rows."""
    tm = float(t) % PERIOD
    times = keys[:, 0]
    i = int(np.clip(np.searchsorted(times, tm, side="right") - 1, 0, len(keys) - 2))
    t0, t1 = times[i], times[i + 1]
    x = np.clip((tm - t0) / max(t1 - t0, 1e-9), 0.0, 1.0)
    s = x * x * (3.0 - 2.0 * x)
    return keys[i, 1:] + s * (keys[i + 1, 1:] - keys[i, 1:])


def box_pose(t: float) -> tuple[NDArray[np.float64], float]:
    """(centre xyz, yaw in degrees) of the box at time ``t``."""
    x, y, zb, yaw = _keyed(_BOX_KEYS, t)
    return np.array([x, y, zb + BOX_SIZE[2] / 2]), float(yaw)


def carried_box(t: float) -> Box:
    """The box at time ``t``: cardboard with a poster on the side facing the camera."""
    c, yaw = box_pose(t)
    half = np.array(BOX_SIZE) / 2
    return _box(
        "carried_box",
        tuple(c - half),
        tuple(c + half),
        _faces("cardboard", top="cardboard", front="poster"),
        yaw_deg=yaw,
        label=LABEL_MOVER,
        ppm=300.0,
    )


def carrier_position(t: float) -> NDArray[np.float64]:
    """The person's feet (world xy) at time ``t``."""
    c, _ = box_pose(t)
    return c[:2] + _keyed(_PERSON_KEYS, t)


class CarrierTrack:
    """The person's track for :class:`semslam.synth.people.People`: position, heading and
    distance walked (for the gait) at any time; standing (no gait) when nearly still."""

    SAMPLES = 4000  # per period, for the walked distance
    STILL_SPEED = 0.15  # m/s

    def __init__(self) -> None:
        ts = np.linspace(0.0, PERIOD, self.SAMPLES + 1)
        pos = np.array([carrier_position(t) for t in ts])
        self._ts = ts
        self._walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])

    def velocity(self, t: float) -> NDArray[np.float64]:
        dt = 1e-3
        return (carrier_position(t + dt) - carrier_position(t - dt)) / (2 * dt)

    def is_idle(self, t: float) -> bool:
        return bool(np.linalg.norm(self.velocity(t)) < self.STILL_SPEED)

    def state(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """(position xy, unit heading xy, distance walked) at time ``t``."""
        vel = self.velocity(t)
        speed = float(np.linalg.norm(vel))
        heading = vel / speed if speed > 1e-6 else np.array([0.0, -1.0])
        cycles, tm = divmod(float(t), PERIOD)
        walked = cycles * self._walked[-1] + float(np.interp(tm, self._ts, self._walked))
        return carrier_position(t), heading, walked
