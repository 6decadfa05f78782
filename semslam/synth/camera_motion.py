"""Camera trajectories like the TUM fr3 ones (static, xyz, rpy, halfsphere) plus a loop.

Every trajectory is a smooth (C2) function of time built from sinusoids of a warped time
that starts at rest, so it starts at rest and the finite-difference speed is bounded;
trackers then see realistic frame-to-frame motion. Poses are camera-to-world (``T_wc``)
with the camera x right, y down, z forward and the world z axis up.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.geometry.se3 import look_at, make_pose, so3_exp

#: Where the camera stands at rest and what it looks at (a desk against the back wall,
#: about 3.3 m away), like the tripod/handheld view in fr3 walking/sitting.
BASE_EYE = np.array([3.0, 1.45, 1.40])
BASE_TARGET = np.array([3.0, 4.75, 0.95])

#: Upper bounds the tests check (the loop is scaled to respect them).
MAX_SPEED = 0.6  # m/s
MAX_ANGULAR_SPEED = np.deg2rad(45.0)  # rad/s

#: ``fast_turns``: every FAST_TURN_PERIOD_S the camera snaps FAST_TURN_DEG to one side in
#: FAST_TURN_S and back half a period later, a handheld glance: raised-cosine steps whose
#: peak rate is deg * pi / (2 s) = 202 deg/s (issue 13's "up to 200 deg/s").
FAST_TURN_DEG = 35.0
FAST_TURN_S = 0.27
FAST_TURN_PERIOD_S = 4.0


def _warp(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """Warped time whose rate rises smoothly from 0 to 1 over the first 1.5 s (or quarter).

    Sinusoids of warped time start at rest yet never move faster than their steady-state
    peak (an amplitude ramp instead would add speed while it rises).
    """
    rise = max(min(1.5, duration / 4.0), 1e-3)
    x = np.clip(t / rise, 0.0, 1.0)
    head = rise * x**4 * (x * (x - 3.0) + 2.5)  # integral of the smootherstep
    return np.where(t < rise, head, t - rise / 2.0)


def base_pose() -> NDArray[np.float64]:
    """The rest pose every motion starts from."""
    return look_at(BASE_EYE, BASE_TARGET)


def camera_trajectory(
    motion: str, times: NDArray[np.float64], duration: float, seed: int = 0
) -> NDArray[np.float64]:
    """Poses ``(N, 4, 4)`` (T_wc) at ``times`` (seconds from the first frame).

    ``seed`` picks the path of the seeded motions (:data:`SEEDED_MOTIONS`); the others
    ignore it, so their renders stay what they were.
    """
    t = np.asarray(times, dtype=np.float64)
    if motion in SEEDED_MOTIONS:
        return SEEDED_MOTIONS[motion](t, duration, seed)
    fn = {
        "static": _static,
        "xyz": _xyz,
        "rpy": _rpy,
        "halfsphere": _halfsphere,
        "loop": _loop,
        "room_loop": _room_loop,
        "room_revisit": _room_revisit,
        "fast_turns": _fast_turns,
        "jump_back": _jump_back,
    }[motion]
    return fn(t, duration)


def _offset_poses(
    t: NDArray[np.float64], trans_cam: NDArray[np.float64], rotvec_cam: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Base pose moved by camera-frame translations and rotation vectors per time."""
    t0 = base_pose()
    poses = np.empty((len(t), 4, 4))
    for i in range(len(t)):
        r = t0[:3, :3] @ so3_exp(rotvec_cam[i])
        c = t0[:3, 3] + t0[:3, :3] @ trans_cam[i]
        poses[i] = make_pose(r, c)
    return poses


def _static(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """Tripod: sub-millimetre tremor so that the images are not bit-identical."""
    tr = np.stack(
        [
            0.00030 * np.sin(2 * np.pi * 1.3 * t),
            0.00020 * np.sin(2 * np.pi * 0.9 * t + 1.0),
            0.00025 * np.sin(2 * np.pi * 0.7 * t + 2.0),
        ],
        axis=1,
    )
    rv = np.deg2rad(0.02) * np.stack(
        [
            np.sin(2 * np.pi * 1.1 * t),
            np.sin(2 * np.pi * 0.8 * t + 0.5),
            np.sin(2 * np.pi * 0.6 * t + 1.5),
        ],
        axis=1,
    )
    return _offset_poses(t, tr, rv)


def _xyz(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """Translation along the camera axes (about +-0.3 m sideways), orientation kept."""
    t = _warp(t, duration)
    tr = np.stack(
        [
            0.30 * np.sin(2 * np.pi * t / 7.0),  # right
            0.15 * np.sin(2 * np.pi * t / 5.0),  # down
            0.20 * np.sin(2 * np.pi * t / 9.0),  # forward
        ],
        axis=1,
    )
    rv = np.deg2rad(1.0) * np.stack(
        [np.sin(2 * np.pi * t / 6.0), np.sin(2 * np.pi * t / 8.0), np.zeros_like(t)], axis=1
    )
    return _offset_poses(t, tr, rv)


def _turn_steps(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """0 -> 1 -> 0 per FAST_TURN_PERIOD_S: raised-cosine steps of FAST_TURN_S at a quarter
    and three quarters of each period (C1; the rate peaks mid-step)."""
    phase = np.mod(t, FAST_TURN_PERIOD_S)

    def step(start: float) -> NDArray[np.float64]:
        x = np.clip((phase - start) / FAST_TURN_S, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * x)

    return step(0.25 * FAST_TURN_PERIOD_S) - step(0.75 * FAST_TURN_PERIOD_S)


def _fast_turns(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """The xyz motion plus fast glances (yaw, with some pitch) up to ~200 deg/s: the
    hard-imaging sequences' motion, where motion blur and rolling shutter are strongest."""
    base = _xyz(t, duration)
    steps = _turn_steps(np.asarray(t, np.float64))
    sign = np.where(np.mod(np.floor(np.asarray(t) / FAST_TURN_PERIOD_S), 2) == 0, 1.0, -1.0)
    rv = np.deg2rad(FAST_TURN_DEG) * steps[:, None] * sign[:, None] * np.array([0.25, 1.0, 0.0])
    out = base.copy()
    for i in range(len(out)):
        out[i, :3, :3] = base[i, :3, :3] @ so3_exp(rv[i])
    return out


def _rpy(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """Rotation about the camera axes (pitch +-12, yaw +-18, roll +-15 degrees)."""
    t = _warp(t, duration)
    rv = np.deg2rad(
        np.stack(
            [
                12.0 * np.sin(2 * np.pi * t / 6.0),  # pitch (about x)
                18.0 * np.sin(2 * np.pi * t / 8.0),  # yaw (about y)
                15.0 * np.sin(2 * np.pi * t / 7.0),  # roll (about z)
            ],
            axis=1,
        )
    )
    tr = 0.02 * np.stack(
        [np.sin(2 * np.pi * t / 5.0), np.sin(2 * np.pi * t / 4.0), np.sin(2 * np.pi * t / 6.0)],
        axis=1,
    )
    return _offset_poses(t, tr, rv)


def _halfsphere(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """On a half sphere of 1 m diameter (the half facing the scene), looking at a point
    1.6 m ahead of the rest position, so that the view turns by up to ~20 degrees."""
    t = _warp(t, duration)
    radius = 0.5
    t0 = base_pose()
    right, fwd = t0[:3, 0], t0[:3, 2]
    up = np.array([0.0, 0.0, 1.0])
    centre = BASE_EYE + radius * fwd
    az = np.deg2rad(55.0) * np.sin(2 * np.pi * t / 9.0)
    el = np.deg2rad(35.0) * (0.5 - 0.5 * np.cos(2 * np.pi * t / 6.5))
    poses = np.empty((len(t), 4, 4))
    for i in range(len(t)):
        ce = np.cos(el[i])
        d = ce * (np.sin(az[i]) * right - np.cos(az[i]) * fwd) + np.sin(el[i]) * up
        eye = centre + radius * d
        poses[i] = look_at(eye, BASE_EYE + 1.6 * fwd)
    return poses


def loop_scale(duration: float) -> float:
    """Size factor of the loop so that its peak speed stays under ~0.45 m/s."""
    a, b = 1.0, 0.45
    perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))  # Ramanujan
    # s(t) = 2*pi*(x - sin(2*pi*x)/(2*pi)) peaks at twice the mean speed.
    return float(min(1.0, 0.45 * duration / (2.0 * perimeter)))


def _loop(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """A closed horizontal ellipse (up to 2 m x 0.9 m) that ends exactly at the start pose."""
    k = loop_scale(duration)
    x = np.clip(t / max(duration - 1e-9, 1e-9), 0.0, 1.0)
    # Phase from 0 to 2*pi with zero speed and acceleration at both ends.
    s = 2 * np.pi * (x - np.sin(2 * np.pi * x) / (2 * np.pi))
    t0 = base_pose()
    right = t0[:3, 0]
    fwd_h = np.array([t0[0, 2], t0[1, 2], 0.0])
    fwd_h /= np.linalg.norm(fwd_h)
    up = np.array([0.0, 0.0, 1.0])
    poses = np.empty((len(t), 4, 4))
    for i in range(len(t)):
        eye = (
            BASE_EYE
            + k * 1.0 * (np.cos(s[i]) - 1.0) * right
            + k * 0.45 * np.sin(s[i]) * fwd_h
            + k * 0.08 * np.sin(2 * s[i]) * up
        )
        target = BASE_TARGET + k * 0.9 * np.sin(s[i]) * right + 0.15 * k * (np.cos(s[i]) - 1.0) * up
        poses[i] = look_at(eye, target)
    return poses


#: Centre of the room_loop circle (the middle of the 6 x 5 m room, eye height 1.4 m).
ROOM_LOOP_CENTER = np.array([3.0, 2.4, 1.4])
ROOM_LOOP_TURNS = 1.25


def _room_loop(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """1.25 turns on a 0.5 m circle in the middle of the room, looking outward at the walls.

    Unlike ``loop`` (which keeps the desk in view), the start is out of view for most of
    the way, so coming back to it is a real loop closure: tracking cannot rejoin the first
    keyframes through its local map and drift has accumulated by then. The last quarter
    turn revisits the start area, as a loop detector needs several keyframes there.
    """
    x = np.clip(t / max(duration - 1e-9, 1e-9), 0.0, 1.0)
    s = ROOM_LOOP_TURNS * 2 * np.pi * (x - np.sin(2 * np.pi * x) / (2 * np.pi))
    return _outward_on_circle(s)


def _outward_on_circle(s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Poses on room_loop's 0.5 m circle turned by ``s`` radians from the start, looking
    outward (and a little down) at the walls; ``s = 0`` is the rest pose's heading."""
    base_dir = BASE_TARGET - BASE_EYE
    yaw0 = np.arctan2(base_dir[1], base_dir[0])
    poses = np.empty((len(s), 4, 4))
    for i in range(len(s)):
        yaw = yaw0 + s[i]
        d = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        eye = ROOM_LOOP_CENTER + 0.5 * d - 0.5 * np.array([np.cos(yaw0), np.sin(yaw0), 0.0])
        poses[i] = look_at(eye, eye + 2.0 * d + np.array([0.0, 0.0, -0.35]))
    return poses


#: ``room_revisit``: one turn of room_loop's circle every ROOM_REVISIT_PERIOD_S, for ever.
ROOM_REVISIT_PERIOD_S = 30.0


def _room_revisit(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """room_loop's circle turned round and round at a steady 12 deg/s after a smooth start:
    after the first turn every view is one seen before, the room the long-run benchmark
    revisits (``benchmarks/long_run.py``: the map must stop growing). The poses of a frame
    do not depend on the sequence's length (beyond 6 s), so a short render is the start of
    a long one."""
    s = 2 * np.pi * _warp(np.asarray(t, np.float64), max(duration, 6.0)) / ROOM_REVISIT_PERIOD_S
    return _outward_on_circle(s)


#: ``jump_back``: the xyz sway at the rest pose; at JUMP_AT_S the view cuts JUMP_YAW_DEG to the
#: side (an unmapped wall: no overlap with a ~60 deg field of view), stays there, turns back
#: between JUMP_RETURN_S (a raised-cosine turn, peak ~56 deg/s) and then stays at the start.
JUMP_AT_S = 1.5
JUMP_RETURN_S = (3.5, 6.0)
JUMP_YAW_DEG = 90.0


def _jump_back(t: NDArray[np.float64], duration: float) -> NDArray[np.float64]:
    """The xyz motion, yawed about the world vertical through the camera by 0 before
    JUMP_AT_S, JUMP_YAW_DEG until JUMP_RETURN_S, then smoothly back to 0: a cut into an
    unmapped part of the room (tracking is lost, a new map starts) and a return to the
    first part (the maps can merge)."""
    t = np.asarray(t, np.float64)
    base = _xyz(t, duration)
    a, b = JUMP_RETURN_S
    x = np.clip((t - a) / (b - a), 0.0, 1.0)
    yaw = np.deg2rad(JUMP_YAW_DEG) * np.where(t < JUMP_AT_S, 0.0, 0.5 + 0.5 * np.cos(np.pi * x))
    out = base.copy()
    for i in range(len(out)):
        out[i, :3, :3] = so3_exp(np.array([0.0, 0.0, yaw[i]])) @ base[i, :3, :3]
    return out


# Issue 38's held-out family: seeded motions, a different path for every seed (each draws
# its parameters from ``default_rng([seed, 41 + k])``, so one motion's draws never shift
# another's). All start at rest through _warp.


def _rotate_cam(poses: NDArray[np.float64], rotvec_cam: NDArray[np.float64]) -> NDArray[np.float64]:
    """``poses`` turned by camera-frame rotation vectors (one per pose)."""
    out = poses.copy()
    for i in range(len(out)):
        out[i, :3, :3] = poses[i, :3, :3] @ so3_exp(rotvec_cam[i])
    return out


def _sines(w: NDArray[np.float64], rng: np.random.Generator, amps: NDArray[np.float64],
           periods: tuple[float, float]) -> NDArray[np.float64]:
    """``(N, len(amps))``: per column a sinusoid of warped time ``w`` with a seeded period
    in ``periods`` and seeded phase, shifted to be 0 at ``w = 0`` (every path starts at
    its base)."""
    p = rng.uniform(*periods, len(amps))
    ph = rng.uniform(0, 2 * np.pi, len(amps))
    return amps * (np.sin(2 * np.pi * w[:, None] / p + ph) - np.sin(ph))


#: ``room_path``: a walk round the room like TUM fr1_room, turning to look at every wall.
#: The eye wanders within ROOM_PATH_BOX (inside the camera zone of every layout); the
#: heading turns at a seeded steady ~ROOM_PATH_TURN_DEG_S (+-40 %) plus a sway.
ROOM_PATH_CENTRE = np.array([3.0, 1.7, 1.45])
ROOM_PATH_HALF = np.array([0.95, 0.32, 0.12])
ROOM_PATH_TURN_DEG_S = 22.0


def _room_path(t: NDArray[np.float64], duration: float, seed: int) -> NDArray[np.float64]:
    """Walking round the room (~1-2 m) while turning to look at every wall, 15-30 deg/s."""
    rng = np.random.default_rng([seed, 41])
    w = _warp(t, duration)
    eye = ROOM_PATH_CENTRE + _sines(w, rng, ROOM_PATH_HALF * rng.uniform(0.7, 1.0, 3), (9.0, 14.0))
    base_dir = BASE_TARGET - BASE_EYE
    yaw0 = np.arctan2(base_dir[1], base_dir[0])
    turn = np.deg2rad(ROOM_PATH_TURN_DEG_S * rng.uniform(0.75, 1.3)) * rng.choice([-1.0, 1.0])
    sway = _sines(w, rng, np.deg2rad(np.array([12.0, 8.0, 3.0])), (5.0, 8.0))
    yaw = yaw0 + turn * w + sway[:, 0]
    pitch = np.deg2rad(-8.0) + sway[:, 1]
    poses = np.empty((len(t), 4, 4))
    for i in range(len(t)):
        d = np.array([np.cos(yaw[i]) * np.cos(pitch[i]), np.sin(yaw[i]) * np.cos(pitch[i]),
                      np.sin(pitch[i])])
        poses[i] = look_at(eye[i], eye[i] + d)
    return _rotate_cam(poses, np.stack([np.zeros_like(t), np.zeros_like(t), sway[:, 2]], axis=1))


#: ``shake``: hand-held tremor on a slow path: a physiological band (SHAKE_LOW_HZ, a few mm
#: and a few tenths of a degree) and a fine one (SHAKE_HIGH_HZ, ~1 mm, ~0.1 deg).
SHAKE_LOW_HZ = (1.0, 3.0)
SHAKE_HIGH_HZ = (8.0, 12.0)


def _shake(t: NDArray[np.float64], duration: float, seed: int) -> NDArray[np.float64]:
    """A slow seeded drift (~0.15 m, a few degrees) plus hand tremor in two bands."""
    rng = np.random.default_rng([seed, 42])
    w = _warp(t, duration)
    tr = _sines(w, rng, np.array([0.15, 0.06, 0.10]), (6.0, 10.0))
    rv = _sines(w, rng, np.deg2rad(np.array([3.0, 5.0, 2.0])), (5.0, 9.0))
    for band, mm, deg in ((SHAKE_LOW_HZ, 3.0, 0.3), (SHAKE_HIGH_HZ, 0.8, 0.08)):
        periods = (1.0 / band[1], 1.0 / band[0])
        tr = tr + _sines(w, rng, np.full(3, mm * 1e-3) * rng.uniform(0.6, 1.4, 3), periods)
        rv = rv + _sines(w, rng, np.deg2rad(np.full(3, deg)) * rng.uniform(0.6, 1.4, 3), periods)
    return _offset_poses(t, tr, rv)


#: ``fast_rotations``: swings on all three axes at once (median ~40 deg/s) plus seeded
#: flicks, out and back, about random axes, every FLICK_EVERY_S; the fastest peak near
#: FLICK_PEAK_DEG_S (a raised-cosine step of ``a`` degrees in ``s`` seconds peaks at
#: ``a * pi / (2 s)``).
FAST_ROT_AMPS_DEG = (10.0, 17.0, 9.0)  # pitch, yaw, roll
FAST_ROT_PERIODS_S = (2.2, 4.0)
FLICK_EVERY_S = (1.6, 3.2)
FLICK_PEAK_DEG_S = (80.0, 175.0)
FLICK_DEG = (18.0, 32.0)


def _raised_cosine(t: NDArray[np.float64], start: float, span: float) -> NDArray[np.float64]:
    """0 before ``start``, 1 after ``start + span``, a half cosine between."""
    x = np.clip((t - start) / span, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _flicks(t: NDArray[np.float64], duration: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """``(N, 3)`` rotation vectors of the flicks: each a raised-cosine step out to a random
    axis and angle, held for 0.3-0.8 s, then back at the same speed."""
    rv = np.zeros((len(t), 3))
    start = 1.5 + rng.uniform(0.0, 1.0)
    first = True
    while start < duration:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        deg = rng.uniform(*FLICK_DEG)
        peak = FLICK_PEAK_DEG_S[1] if first else rng.uniform(*FLICK_PEAK_DEG_S)
        first = False  # the first flick is the fastest, so every sequence has one
        s = deg * np.pi / (2 * peak)
        back = start + s + rng.uniform(0.3, 0.8)
        out = _raised_cosine(t, start, s) - _raised_cosine(t, back, s)
        rv += np.deg2rad(deg) * out[:, None] * axis
        start = back + s + rng.uniform(*FLICK_EVERY_S)
    return rv


def _fast_rotations(t: NDArray[np.float64], duration: float, seed: int) -> NDArray[np.float64]:
    """A walking sway with rotations on all axes at once and fast seeded flicks."""
    rng = np.random.default_rng([seed, 43])
    w = _warp(t, duration)
    tr = _sines(w, rng, np.array([0.20, 0.08, 0.15]), (5.0, 8.0))
    rv = _sines(w, rng, np.deg2rad(np.array(FAST_ROT_AMPS_DEG)), FAST_ROT_PERIODS_S)
    rv = rv + _sines(w, rng, np.deg2rad(np.array(FAST_ROT_AMPS_DEG)) / 3, (1.1, 1.7))
    poses = _offset_poses(t, tr, rv)
    return _rotate_cam(poses, _flicks(t, duration, rng))


SEEDED_MOTIONS = {"room_path": _room_path, "shake": _shake, "fast_rotations": _fast_rotations}
