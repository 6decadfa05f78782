"""Something over the lens (issue 38): a hand or a flat card a few centimetres away.

Closer than a Kinect's ~0.5 m minimum range, it gives no depth where it covers, and it is
far out of focus: a soft-edged, strongly blurred shape covering 50-100 % of the image that
moves while the camera keeps moving. Pure functions of (seed, time since it came, size), so
every frame is deterministic.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

OCCLUDER_KINDS = ("hand", "object")
#: Where the blurred cover is at least this opaque the depth camera sees only it (nothing).
DEPTH_ALPHA = 0.1
#: Defocus blur, as a share of the image width (a hand ~5 cm from the lens).
DEFOCUS_SHARE = 0.05
#: Skin tones (RGB, lit): from light to dark, one picked per seed.
SKIN_TONES = ((224, 172, 140), (198, 140, 105), (160, 110, 80), (112, 76, 56))


def _grid(h: int, w: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Pixel centres in units of the image height, origin in the middle (u right, v down)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return (xx - w / 2) / h, (yy - h / 2) / h


def _ellipse(u: NDArray[np.float32], v: NDArray[np.float32], c: tuple[float, float], a: float,
             b: float, angle: float) -> NDArray[np.bool_]:
    """Inside an ellipse centred at ``c`` with semi-axes ``a`` (along ``angle``) and ``b``."""
    ca, sa = np.cos(angle), np.sin(angle)
    du, dv = u - c[0], v - c[1]
    x, y = du * ca + dv * sa, -du * sa + dv * ca
    return (x / a) ** 2 + (y / b) ** 2 <= 1.0


def _drift(rng: np.random.Generator, t: float) -> tuple[float, float, float]:
    """A slow seeded wander of the cover: (du, dv, angle) at ``t`` seconds after it came."""
    p = rng.uniform(0.8, 1.6, 3)
    ph = rng.uniform(0, 2 * np.pi, 3)
    s = np.sin(2 * np.pi * t / p + ph)
    return float(0.12 * s[0]), float(0.08 * s[1]), float(0.25 * s[2])


def _hand_mask(rng: np.random.Generator, t: float, h: int, w: int) -> NDArray[np.float32]:
    """A palm over most of the image with four fingers and a thumb, drifting and turning."""
    u, v = _grid(h, w)
    du, dv, ang = _drift(rng, t)
    base = rng.uniform(-0.4, 0.4)  # which way the fingers point
    size = rng.uniform(0.95, 1.2)
    c = (du, 0.1 + dv)
    mask = _ellipse(u, v, c, 0.62 * size, 0.48 * size, base + ang)
    for k in range(4):  # fingers fan out from the palm's top edge
        a = base + ang - np.pi / 2 + (k - 1.5) * 0.28
        r = 0.45 * size
        fc = (c[0] + r * np.cos(a), c[1] + r * np.sin(a))
        mask |= _ellipse(u, v, fc, 0.38 * size, 0.09 * size, a)
    a = base + ang + 0.35  # the thumb, low on one side
    mask |= _ellipse(u, v, (c[0] + 0.55 * size * np.cos(a), c[1] + 0.3 * size), 0.3 * size,
                     0.1 * size, a)
    return mask.astype(np.float32)


def _card_mask(rng: np.random.Generator, t: float, h: int, w: int) -> NDArray[np.float32]:
    """A tilted rectangle (a book, a card) held over most of the image."""
    u, v = _grid(h, w)
    du, dv, ang = _drift(rng, t)
    a, b = rng.uniform(0.55, 0.75), rng.uniform(0.4, 0.55)
    angle = rng.uniform(-0.3, 0.3) + 0.5 * ang
    ca, sa = np.cos(angle), np.sin(angle)
    x = (u - du) * ca + (v - dv) * sa
    y = -(u - du) * sa + (v - dv) * ca
    return ((np.abs(x) <= a) & (np.abs(y) <= b)).astype(np.float32)


def _hand_colour(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    """Skin lit from one side: a seeded tone with a brightness gradient across the hand."""
    tone = np.array(SKIN_TONES[int(rng.integers(0, len(SKIN_TONES)))], np.float32)
    u, v = _grid(h, w)
    d = rng.uniform(0, 2 * np.pi)
    shade = 0.55 + 0.25 * (np.cos(d) * u + np.sin(d) * v) + rng.uniform(-0.1, 0.1)
    return tone * np.clip(shade, 0.2, 1.0)[..., None]


def _card_colour(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    """A printed card: a seeded colour with stripes and blocks of print (texture that moves
    with the camera, not with the room)."""
    u, v = _grid(h, w)
    paper = rng.uniform(90, 230, 3).astype(np.float32)
    ink = rng.uniform(10, 120, 3).astype(np.float32)
    f = rng.uniform(6, 14)
    stripes = (np.sin(2 * np.pi * f * (u + 0.3 * v)) > 0.4).astype(np.float32)
    blocks = (np.floor(u * f / 2) + np.floor(v * f / 2)) % 3 == 0
    print_ = np.clip(stripes + blocks, 0, 1)[..., None]
    return paper * (1 - print_) + ink * print_


def occluder_layer(kind: str, seed: int, t: float, h: int, w: int
                   ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """(alpha ``(H, W)`` in [0, 1], colour ``(H, W, 3)``) of the cover ``t`` seconds after
    it came over the lens. The shape is seeded per sequence (not per frame) and moves with
    ``t``; the defocus blur softens its edges."""
    rng = np.random.default_rng([seed, 47])
    mask = (_hand_mask if kind == "hand" else _card_mask)(rng, t, h, w)
    colour = (_hand_colour if kind == "hand" else _card_colour)(rng, h, w)
    sigma = DEFOCUS_SHARE * w * (1.0 if kind == "hand" else 0.6)
    alpha = cv2.GaussianBlur(mask, (0, 0), sigma)
    colour = cv2.GaussianBlur(colour, (0, 0), sigma)
    return alpha, colour


def cover_rgb(rgb8: NDArray[np.uint8], alpha: NDArray[np.float32], colour: NDArray[np.float32]
              ) -> NDArray[np.uint8]:
    """The scene image with the cover blended over it (before optics and sensor noise)."""
    a = alpha[..., None]
    return np.clip(rgb8.astype(np.float32) * (1 - a) + colour * a + 0.5, 0, 255).astype(np.uint8)


def cover_depth(depth: NDArray[np.uint16], alpha: NDArray[np.float32]) -> NDArray[np.uint16]:
    """The depth with nothing where the cover is (too close for the depth camera)."""
    return np.where(alpha >= DEPTH_ALPHA, 0, depth).astype(np.uint16)
