"""Hard imaging for synthetic sequences (issue 13): motion blur, rolling shutter,
auto-exposure swings and a depth-colour time offset, all deterministic per (config, frame).

A frame's RGB is integrated from sub-frame renders at times around its timestamp: row ``r``
is exposed over ``[c_r - E/2, c_r + E/2]`` with ``c_r = t + (r / (H - 1) - 1/2) R`` (exposure
``E``, readout ``R``: the middle row is captured at the frame's timestamp, whose pose the
ground truth holds). Sub-frames are ``SUB_FRAME_S`` apart; each row averages the ones in its
exposure window (the nearest one when ``E`` is 0: a pure rolling shutter). Pure functions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Sub-frame renders are spaced so that the image moves about MAX_STEP_PX between two
#: (finer than the blur itself, so no discrete copies show), at least MIN_SUB_FRAME_S apart
#: and at most MAX_SUB_FRAMES per frame: at 200 deg/s (~1900 px/s at 640x480) about 1 ms.
MAX_STEP_PX = 2.0
MIN_SUB_FRAME_S = 0.001
MAX_SUB_FRAMES = 33
#: The depth-colour offset of a frame is drawn in [DELAY_MIN_SHARE, 1] x depth_delay_ms.
DELAY_MIN_SHARE = 0.35


def sub_frame_offsets(exposure_s: float, readout_s: float, image_speed_px_s: float = 1e4) -> NDArray[np.float64]:
    """Times (relative to the frame's timestamp) of the sub-frames a frame is built from, for
    an image moving at up to ``image_speed_px_s``; an odd count, so one is the timestamp."""
    span = exposure_s + readout_s
    if span <= 0:
        return np.zeros(1)
    step = max(MIN_SUB_FRAME_S, MAX_STEP_PX / max(image_speed_px_s, 1e-6))
    k = int(min(MAX_SUB_FRAMES, np.ceil(span / step) + 1))
    k = max(3, k + 1 - k % 2)  # odd, and the window's ends are rendered
    return np.linspace(-span / 2, span / 2, k)


def row_weights(offsets: NDArray[np.float64], height: int, exposure_s: float, readout_s: float) -> NDArray[np.float32]:
    """``(K, H)`` weights of each sub-frame in each row, summing to 1 per row."""
    centre = (np.arange(height) / max(height - 1, 1) - 0.5) * readout_s  # capture time of each row
    dist = np.abs(offsets[:, None] - centre[None, :])
    w = (dist <= exposure_s / 2 + 1e-9).astype(np.float64)
    empty = w.sum(0) == 0  # no sub-frame inside a (short) window: the nearest one
    w[np.argmin(dist[:, empty], axis=0), np.flatnonzero(empty)] = 1.0
    return (w / w.sum(0, keepdims=True)).astype(np.float32)


def blend_rows(images: list[NDArray[np.uint8]], weights: NDArray[np.float32]) -> NDArray[np.uint8]:
    """The rows of ``images`` (K of them, H x W x 3) mixed with ``row_weights``."""
    out = np.zeros(images[0].shape, np.float32)
    for img, w in zip(images, weights):
        rows = np.flatnonzero(w)
        out[rows] += img[rows].astype(np.float32) * w[rows, None, None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def exposure_gain(seed: int, t: float, swing: float) -> float:
    """Auto-exposure gain at time ``t``: ``1 + swing * s(t)`` with ``s`` a smooth seeded mix
    of two slow sinusoids (periods 2.5-6 s) that reaches +-1."""
    if swing <= 0:
        return 1.0
    rng = np.random.default_rng([seed, 23])
    p1, p2 = rng.uniform(2.5, 4.0), rng.uniform(4.0, 6.0)
    f1, f2 = rng.uniform(0, 2 * np.pi, 2)
    s = 0.6 * np.sin(2 * np.pi * t / p1 + f1) + 0.4 * np.sin(2 * np.pi * t / p2 + f2)
    return float(1.0 + swing * s)


def white_balance_gains(seed: int, t: float, swing: float) -> NDArray[np.float32]:
    """Per-channel (R, G, B) gains at time ``t``: auto white balance hunting, each channel
    ``1 + swing * s_c(t)`` with its own smooth seeded mix of slow sinusoids (periods 2-7 s)."""
    if swing <= 0:
        return np.ones(3, np.float32)
    rng = np.random.default_rng([seed, 31])
    p1, p2 = rng.uniform(2.0, 4.0, 3), rng.uniform(4.0, 7.0, 3)
    f1, f2 = rng.uniform(0, 2 * np.pi, 3), rng.uniform(0, 2 * np.pi, 3)
    s = 0.6 * np.sin(2 * np.pi * t / p1 + f1) + 0.4 * np.sin(2 * np.pi * t / p2 + f2)
    return (1.0 + swing * s).astype(np.float32)


def depth_delay_s(seed: int, frame: int, max_delay_s: float) -> float:
    """How long after the RGB image frame ``frame``'s depth is captured."""
    if max_delay_s <= 0:
        return 0.0
    return float(np.random.default_rng([seed, frame, 29]).uniform(DELAY_MIN_SHARE, 1.0) * max_delay_s)
