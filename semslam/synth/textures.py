"""Procedural surface textures for the synthetic office, deterministic by a seed.

ORB needs many distinct, non-repeating corners, so surfaces are covered with random
structure as in a real office: posters and notes with text, book spines, wood grain,
speckled linoleum, cardboard with labels. Nothing is loaded from disk, except with photo
textures (:func:`photo`, renders for training: a folder of real photographs). Every generator
has the signature ``gen(rng, width_px, height_px, ppm) -> uint8 RGB (H, W, 3)`` where
``ppm`` is texels per metre, so decorations get physical sizes.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

Image = NDArray[np.uint8]
Rng = np.random.Generator

WORDS = tuple(
    "MEETING ROBOT SLAM VISION LAB OFFICE PROJECT REPORT DEADLINE KINECT DEPTH CAMERA "
    "FREIBURG MUNICH TUM DATA SENSOR PLAN AGENDA NOTES BUDGET TEAM RESEARCH SEMINAR "
    "ROOM 2.14 EXIT FIRE PRINTER COFFEE KITCHEN LIBRARY THESIS DRAFT MAP POSE GRAPH "
    "LOOP CLOSURE BUNDLE ADJUST ORB FEATURE TRACK FRAME KEY POINT CLOUD MESH VOXEL Q1 "
    "Q2 Q3 Q4 2012 JULY MONDAY FRIDAY TODO DONE URGENT CALL EMAIL MAIL BOX PARCEL "
    "FRAGILE THIS SIDE UP HANDLE WITH CARE BOOK ATLAS PHYSICS MATH ALGEBRA OPTICS".split()
)

FONTS = (
    cv2.FONT_HERSHEY_SIMPLEX,
    cv2.FONT_HERSHEY_DUPLEX,
    cv2.FONT_HERSHEY_COMPLEX,
    cv2.FONT_HERSHEY_TRIPLEX,
    cv2.FONT_HERSHEY_PLAIN,
)


# --------------------------------------------------------------------------- helpers


def fbm(
    rng: Rng, h: int, w: int, cells: tuple[float, ...] = (4, 16, 64), gain: float = 0.55
) -> NDArray[np.float32]:
    """Multi-scale smooth noise, roughly zero mean and unit std (octaves of cell size px)."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for c in cells:
        gh, gw = max(2, int(h / c) + 2), max(2, int(w / c) + 2)
        g = rng.standard_normal((gh, gw)).astype(np.float32)
        up = cv2.resize(g, (int(gw * c), int(gh * c)), interpolation=cv2.INTER_CUBIC)
        out += (
            amp * up[:h, :w]
            if up.shape[0] >= h and up.shape[1] >= w
            else amp * cv2.resize(g, (w, h))
        )
        total += amp * amp
        amp *= gain
    return out / np.sqrt(total)


def _color(rng: Rng, lo: int = 0, hi: int = 256) -> tuple[int, int, int]:
    c = rng.integers(lo, hi, 3)
    return (int(c[0]), int(c[1]), int(c[2]))


def _vivid(rng: Rng) -> tuple[int, int, int]:
    """A saturated colour (random hue), as on posters and book covers."""
    hsv = np.uint8([[[rng.integers(0, 180), rng.integers(120, 256), rng.integers(110, 250)]]])
    c = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return (int(c[0]), int(c[1]), int(c[2]))


def _contrast(c: tuple[int, int, int]) -> tuple[int, int, int]:
    return (20, 20, 25) if sum(c) > 380 else (240, 240, 235)


def _words(rng: Rng, n: int) -> str:
    return " ".join(rng.choice(WORDS, n))


def put_text(
    img: Image,
    rng: Rng,
    text: str,
    org: tuple[int, int],
    height_px: float,
    color: tuple[int, int, int],
    font: int | None = None,
) -> int:
    """Draw text whose capital height is about ``height_px``; returns the text width."""
    font = int(rng.choice(FONTS)) if font is None else font
    (_, th), _ = cv2.getTextSize("H", font, 1.0, 1)
    scale = max(height_px / max(th, 1), 0.2)
    thick = max(1, int(round(scale * 1.4)))
    cv2.putText(img, text, org, font, scale, color, thick, cv2.LINE_AA)
    (tw, _), _ = cv2.getTextSize(text, font, scale, thick)
    return tw


def text_lines(
    img: Image, rng: Rng, x0: int, y0: int, x1: int, y1: int, line_h: float, color
) -> None:
    """Fill a box with lines of small text (a paragraph)."""
    y = y0 + line_h
    font = int(rng.choice(FONTS[:2]))
    while y < y1:
        put_text(
            img, rng, _words(rng, int(rng.integers(2, 7))), (x0, int(y)), line_h * 0.6, color, font
        )
        y += line_h * rng.uniform(1.3, 1.8)


def _sub(img: Image, x: int, y: int, w: int, h: int) -> Image | None:
    """A view of ``img`` at (x, y, w, h) clipped to the image, or None if empty."""
    hh, ww = img.shape[:2]
    x0, y0, x1, y1 = max(0, x), max(0, y), min(ww, x + w), min(hh, y + h)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return img[y0:y1, x0:x1]


def _paste(dst: Image, src: Image, x: int, y: int) -> None:
    h, w = src.shape[:2]
    view = _sub(dst, x, y, w, h)
    if view is None:
        return
    sx, sy = max(0, -x), max(0, -y)
    view[...] = src[sy : sy + view.shape[0], sx : sx + view.shape[1]]


def _rotated_paste(dst: Image, src: Image, cx: int, cy: int, angle: float) -> None:
    """Paste ``src`` rotated by ``angle`` degrees around its centre at (cx, cy)."""
    h, w = src.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), angle, 1.0)
    cos, sin = abs(m[0, 0]), abs(m[0, 1])
    nw, nh = int(h * sin + w * cos) + 2, int(h * cos + w * sin) + 2
    m[0, 2] += nw / 2 - w / 2
    m[1, 2] += nh / 2 - h / 2
    rot = cv2.warpAffine(src, m, (nw, nh), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))
    mask = cv2.warpAffine(np.full((h, w), 255, np.uint8), m, (nw, nh), flags=cv2.INTER_LINEAR)
    x0, y0 = cx - nw // 2, cy - nh // 2
    view = _sub(dst, x0, y0, nw, nh)
    if view is None:
        return
    sx, sy = max(0, -x0), max(0, -y0)
    r = rot[sy : sy + view.shape[0], sx : sx + view.shape[1]].astype(np.float32)
    a = mask[sy : sy + view.shape[0], sx : sx + view.shape[1]].astype(np.float32)[..., None] / 255.0
    view[...] = (r * a + view.astype(np.float32) * (1 - a)).astype(np.uint8)


def shade_noise(
    img: Image, rng: Rng, amount: float, cells: tuple[float, ...] = (3, 12, 48)
) -> Image:
    """Multiply by (1 + amount * noise): dirt, paper grain, paint unevenness."""
    n = fbm(rng, img.shape[0], img.shape[1], cells)
    out = img.astype(np.float32) * (1.0 + amount * n)[..., None]
    return np.clip(out, 0, 255).astype(np.uint8)


def flat(color: tuple[int, int, int], w: int, h: int) -> Image:
    img = np.empty((h, w, 3), np.uint8)
    img[...] = color
    return img


# --------------------------------------------------------------------------- small items


def poster(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """A poster: coloured background, a title, shapes, a picture block and paragraphs."""
    bg = _color(rng, 150, 256) if rng.random() < 0.6 else _vivid(rng)
    img = flat(bg, w, h)
    fg = _contrast(bg)
    m = max(2, int(0.03 * ppm))
    title_h = max(4, int(rng.uniform(0.03, 0.06) * ppm))
    put_text(img, rng, _words(rng, int(rng.integers(1, 3))), (m, m + title_h), title_h, fg)
    # picture block of blobs
    py0 = m + int(title_h * 1.8)
    ph = int((h - py0) * rng.uniform(0.3, 0.55))
    pic = img[py0 : py0 + ph, m : w - m]
    if pic.size:
        pic[...] = _color(rng)
        for _ in range(int(rng.integers(5, 14))):
            c = _vivid(rng)
            cx, cy = int(rng.integers(0, pic.shape[1])), int(rng.integers(0, pic.shape[0]))
            r = int(rng.integers(2, max(3, min(pic.shape[:2]) // 2)))
            kind = rng.integers(0, 3)
            if kind == 0:
                cv2.circle(pic, (cx, cy), r, c, -1, cv2.LINE_AA)
            elif kind == 1:
                cv2.rectangle(pic, (cx - r, cy - r // 2), (cx + r, cy + r), c, -1)
            else:
                pts = rng.integers(0, [pic.shape[1], pic.shape[0]], (3, 2)).astype(np.int32)
                cv2.fillPoly(pic, [pts], c, cv2.LINE_AA)
    line_h = max(4, int(0.018 * ppm))
    text_lines(img, rng, m, py0 + ph + m, w - m, h - m, line_h, fg)
    cv2.rectangle(
        img, (0, 0), (w - 1, h - 1), (max(bg[0] - 60, 0), max(bg[1] - 60, 0), max(bg[2] - 60, 0)), 1
    )
    return img


def picture(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """A framed landscape-like picture (sky gradient, hills, sun, trees)."""
    img = np.zeros((h, w, 3), np.uint8)
    sky0, sky1 = (
        np.array(_color(rng, 120, 256), np.float32),
        np.array(_color(rng, 60, 220), np.float32),
    )
    a = np.linspace(0, 1, h, dtype=np.float32)[:, None, None]
    img[...] = (sky0 * (1 - a) + sky1 * a).astype(np.uint8)
    for k in range(int(rng.integers(2, 5))):
        base = h * (0.45 + 0.12 * k)
        xs = np.linspace(0, w, 12)
        ys = base + rng.normal(0, h * 0.06, 12)
        pts = np.concatenate([np.stack([xs, ys], 1), [[w, h], [0, h]]]).astype(np.int32)
        cv2.fillPoly(img, [pts], _color(rng, 20, 200), cv2.LINE_AA)
    cv2.circle(
        img,
        (int(rng.uniform(0.1, 0.9) * w), int(h * 0.2)),
        max(2, int(h * 0.08)),
        _color(rng, 180, 256),
        -1,
        cv2.LINE_AA,
    )
    for _ in range(int(rng.integers(2, 8))):
        x, y = int(rng.integers(0, w)), int(rng.uniform(0.5, 0.9) * h)
        cv2.line(img, (x, y), (x, y - int(h * 0.1)), (60, 40, 20), max(1, w // 80))
        cv2.circle(
            img, (x, y - int(h * 0.12)), max(2, int(h * 0.05)), _color(rng, 0, 140), -1, cv2.LINE_AA
        )
    fw = max(2, int(0.025 * ppm))
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), _color(rng, 0, 120), fw)
    return shade_noise(img, rng, 0.05)


def sticky_note(rng: Rng, w: int, h: int, ppm: float) -> Image:
    col = [(250, 240, 120), (250, 180, 200), (160, 230, 250), (180, 250, 160), (250, 200, 120)]
    bg = col[int(rng.integers(0, len(col)))]
    img = flat(bg, w, h)
    text_lines(img, rng, 2, 2, w - 2, h - 2, max(5, int(0.012 * ppm)), (30, 30, 120))
    return img


def paper(rng: Rng, w: int, h: int, ppm: float) -> Image:
    img = flat(_color(rng, 225, 256), w, h)
    m = max(2, int(0.015 * ppm))
    put_text(img, rng, _words(rng, 2), (m, m + int(0.02 * ppm)), max(4, 0.02 * ppm), (20, 20, 20))
    text_lines(
        img, rng, m, m + int(0.04 * ppm), w - m, h - m, max(4, int(0.01 * ppm)), (40, 40, 40)
    )
    if rng.random() < 0.5:  # a table or chart
        x0, y0 = m, int(h * rng.uniform(0.4, 0.6))
        for _ in range(int(rng.integers(3, 9))):
            bw = int(rng.integers(3, max(4, w // 10)))
            bh = int(rng.integers(3, max(4, h // 5)))
            cv2.rectangle(img, (x0, y0 - bh), (x0 + bw, y0), _vivid(rng), -1)
            x0 += bw + 2
    return img


def calendar(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Month grid with numbers: regular, but the numbers and marks make it unique."""
    img = flat((245, 245, 240), w, h)
    ph = int(h * 0.45)
    img[:ph] = picture(rng, w, ph, ppm)
    rows, cols = 5, 7
    cw, ch = w / cols, (h - ph) / rows
    start = int(rng.integers(0, 7))
    for i in range(rows * cols):
        r, c = divmod(i, cols)
        x, y = int(c * cw), int(ph + r * ch)
        cv2.rectangle(img, (x, y), (int(x + cw), int(y + ch)), (150, 150, 150), 1)
        day = i - start + 1
        if 1 <= day <= 31:
            put_text(
                img,
                rng,
                str(day),
                (x + 2, y + int(ch * 0.5)),
                ch * 0.3,
                (200, 30, 30) if c == 6 else (30, 30, 30),
                cv2.FONT_HERSHEY_SIMPLEX,
            )
            if rng.random() < 0.15:
                cv2.circle(
                    img,
                    (int(x + cw / 2), int(y + ch / 2)),
                    int(min(cw, ch) * 0.4),
                    (220, 40, 40),
                    1,
                    cv2.LINE_AA,
                )
    return img


def whiteboard(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Whiteboard with marker scribbles, diagrams and text."""
    img = flat((238, 240, 242), w, h)
    markers = [(30, 30, 160), (20, 20, 20), (180, 30, 30), (30, 130, 40)]
    for _ in range(int(rng.integers(6, 14))):
        c = markers[int(rng.integers(0, len(markers)))]
        x, y = int(rng.integers(0, w - 10)), int(rng.integers(10, h))
        kind = rng.integers(0, 4)
        if kind == 0:
            put_text(
                img,
                rng,
                _words(rng, int(rng.integers(1, 4))),
                (x, y),
                rng.uniform(0.02, 0.05) * ppm,
                c,
            )
        elif kind == 1:
            s = int(rng.uniform(0.05, 0.15) * ppm)
            cv2.rectangle(img, (x, y - s), (x + 2 * s, y), c, 2, cv2.LINE_AA)
            put_text(img, rng, str(rng.choice(WORDS)), (x + 3, y - s // 3), s * 0.3, c)
        elif kind == 2:
            pts = np.cumsum(rng.normal(0, 0.04 * ppm, (8, 2)), 0) + [x, y]
            cv2.polylines(img, [pts.astype(np.int32)], False, c, 2, cv2.LINE_AA)
        else:
            cv2.arrowedLine(
                img,
                (x, y),
                (x + int(rng.normal(0, 0.2 * ppm)), y + int(rng.normal(0, 0.1 * ppm))),
                c,
                2,
                cv2.LINE_AA,
            )
    fw = max(2, int(0.02 * ppm))
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (170, 170, 175), fw)
    return img


def notice_board(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Cork board with pinned notes, photos and papers at random angles."""
    img = np.empty((h, w, 3), np.uint8)
    img[...] = (185, 140, 90)
    img = shade_noise(img, rng, 0.18, (1.5, 4, 16))
    for _ in range(int(w * h / (0.12 * ppm) ** 2 * 0.7) + 2):
        nw, nh = int(rng.uniform(0.07, 0.22) * ppm), int(rng.uniform(0.07, 0.28) * ppm)
        gen = [sticky_note, paper, picture, poster][int(rng.integers(0, 4))]
        item = gen(rng, max(nw, 8), max(nh, 8), ppm)
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        _rotated_paste(img, item, cx, cy, float(rng.normal(0, 8)))
        cv2.circle(
            img, (cx, cy - nh // 2 + 4), max(2, int(0.006 * ppm)), _vivid(rng), -1, cv2.LINE_AA
        )
    fw = max(2, int(0.025 * ppm))
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (110, 80, 50), fw)
    return img


def clock(rng: Rng, w: int, h: int, ppm: float) -> Image:
    img = flat((238, 238, 235), w, h)
    c, r = (w // 2, h // 2), min(w, h) // 2 - 2
    cv2.circle(img, c, r, (30, 30, 30), max(2, r // 12), cv2.LINE_AA)
    for k in range(12):
        a = k * np.pi / 6
        p0 = (int(c[0] + 0.8 * r * np.sin(a)), int(c[1] - 0.8 * r * np.cos(a)))
        p1 = (int(c[0] + 0.92 * r * np.sin(a)), int(c[1] - 0.92 * r * np.cos(a)))
        cv2.line(img, p0, p1, (20, 20, 20), max(1, r // 25), cv2.LINE_AA)
    for length, width in ((0.5, 5), (0.75, 3)):
        a = rng.uniform(0, 2 * np.pi)
        cv2.line(
            img,
            c,
            (int(c[0] + length * r * np.sin(a)), int(c[1] - length * r * np.cos(a))),
            (10, 10, 10),
            max(1, r // (width * 4)),
            cv2.LINE_AA,
        )
    return img


def outlet(rng: Rng, w: int, h: int, ppm: float) -> Image:
    img = flat((235, 235, 230), w, h)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (180, 180, 175), 1)
    cv2.circle(img, (w // 2, h // 2), max(2, min(w, h) // 3), (200, 200, 195), -1)
    for dx in (-1, 1):
        cv2.circle(img, (w // 2 + dx * max(1, w // 8), h // 2), max(1, w // 16), (40, 40, 40), -1)
    return img


# --------------------------------------------------------------------------- large surfaces


def _scatter(
    img: Image,
    rng: Rng,
    ppm: float,
    items: list[tuple[Callable[..., Image], tuple[float, float], tuple[float, float], float]],
    band: tuple[float, float],
    coverage: float,
    max_tries: int = 400,
) -> None:
    """Place rectangles (generator, width range m, height range m, weight) without overlap.

    ``band`` is the vertical range in metres from the top of the surface.
    """
    h, w = img.shape[:2]
    occupied = np.zeros((h, w), bool)
    weights = np.array([it[3] for it in items], float)
    weights /= weights.sum()
    target = coverage * w * (min(h, band[1] * ppm) - band[0] * ppm)
    placed = 0.0
    for _ in range(max_tries):
        if placed >= target:
            break
        gen, wr, hr, _wt = items[int(rng.choice(len(items), p=weights))]
        iw, ih = int(rng.uniform(*wr) * ppm), int(rng.uniform(*hr) * ppm)
        if iw < 6 or ih < 6 or iw >= w or ih >= h:
            continue
        y_lo, y_hi = int(band[0] * ppm), int(min(h, band[1] * ppm)) - ih
        if y_hi <= y_lo:
            continue
        x, y = int(rng.integers(0, w - iw)), int(rng.integers(y_lo, y_hi))
        m = max(2, int(0.03 * ppm))
        if occupied[max(0, y - m) : y + ih + m, max(0, x - m) : x + iw + m].any():
            continue
        img[y : y + ih, x : x + iw] = gen(rng, iw, ih, ppm)
        occupied[y : y + ih, x : x + iw] = True
        placed += iw * ih


WALL_ITEMS = [
    (poster, (0.35, 0.75), (0.45, 1.0), 3.0),
    (picture, (0.3, 0.8), (0.25, 0.6), 2.0),
    (notice_board, (0.6, 1.3), (0.5, 0.9), 2.0),
    (calendar, (0.25, 0.35), (0.35, 0.5), 1.0),
    (whiteboard, (0.9, 1.6), (0.7, 1.0), 1.0),
    (clock, (0.25, 0.32), (0.25, 0.32), 0.5),
    (paper, (0.21, 0.3), (0.28, 0.4), 1.5),
]


def wall(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Painted wall with posters, pictures, boards, papers; skirting board at the floor."""
    base = np.array(_color(rng, 200, 236), np.float32)
    base = base * 0.4 + np.array([225, 222, 212], np.float32) * 0.6
    img = flat(tuple(int(c) for c in base), w, h)
    img = shade_noise(img, rng, 0.035, (2, 8, 40, 160))
    _scatter(img, rng, ppm, WALL_ITEMS, band=(0.3, 2.1), coverage=0.55)
    _scatter(
        img,
        rng,
        ppm,
        [(paper, (0.21, 0.3), (0.28, 0.4), 1.0), (sticky_note, (0.07, 0.1), (0.07, 0.1), 1.0)],
        band=(0.6, 1.9),
        coverage=0.06,
    )
    for _ in range(int(w / ppm * 0.6)):  # outlets near the floor
        ow, oh = int(0.08 * ppm), int(0.08 * ppm)
        x = int(rng.integers(0, max(1, w - ow)))
        y = h - int(rng.uniform(0.25, 0.35) * ppm)
        if ow > 4:
            img[y : y + oh, x : x + ow] = outlet(rng, ow, oh, ppm)
    sk = max(2, int(0.08 * ppm))
    img[h - sk :] = shade_noise(flat(_color(rng, 60, 120), w, sk), rng, 0.1)
    cv2.line(img, (0, h - sk), (w, h - sk), (40, 40, 40), 1)
    # scuffs, nail holes and pencil marks: small features between the items
    for _ in range(int(w * h / ppm**2 * 6)):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        g = int(rng.integers(60, 170))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), int(rng.integers(1, 3)), (g, g, g - 5), -1)
        else:
            q = (x + int(rng.normal(0, 0.02 * ppm)), y + int(rng.normal(0, 0.02 * ppm)))
            cv2.line(img, (x, y), q, (g, g, g), 1, cv2.LINE_AA)
    return img


def floor(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Speckled grey linoleum with scuffs, tape lines and a rug: corners for ORB everywhere."""
    img = flat((142, 140, 134), w, h)
    img = shade_noise(img, rng, 0.10, (2, 6, 24, 96, 300))
    # terrazzo-like chips: fine ones for texture, coarse high-contrast ones for corners
    for count, rmin, rmax in ((600, 1, 3), (120, 2, 6)):
        n_spk = int(w * h / ppm**2 * count)
        xs, ys = rng.integers(0, w, n_spk), rng.integers(0, h, n_spk)
        rs = rng.integers(rmin, rmax, n_spk)
        dark = rng.random(n_spk) < 0.6
        shades = np.where(dark, rng.integers(25, 90, n_spk), rng.integers(185, 245, n_spk))
        for x, y, r, sh in zip(xs, ys, rs, shades):
            cv2.circle(
                img, (int(x), int(y)), int(r), (int(sh), int(sh) - 3, max(int(sh) - 8, 0)), -1
            )
    for _ in range(int(w * h / ppm**2 * 3)):  # scuff marks
        p = rng.integers(0, [w, h])
        q = p + rng.normal(0, 0.08 * ppm, 2)
        cv2.line(
            img,
            tuple(int(v) for v in p),
            tuple(int(v) for v in q),
            _color(rng, 40, 90),
            int(rng.integers(1, 4)),
            cv2.LINE_AA,
        )
    # a rug
    rw, rh = int(rng.uniform(1.4, 2.0) * ppm), int(rng.uniform(0.9, 1.3) * ppm)
    rx, ry = int(w * 0.5 - rw / 2 + rng.normal(0, 0.3 * ppm)), int(h * 0.42 - rh / 2)
    rug = shade_noise(flat(_vivid(rng), rw, rh), rng, 0.25, (1.5, 4, 12))
    for _ in range(int(rng.integers(25, 50))):
        c = _vivid(rng)
        cx, cy = int(rng.integers(0, rw)), int(rng.integers(0, rh))
        s = int(rng.uniform(0.03, 0.15) * ppm)
        if rng.random() < 0.5:
            cv2.circle(rug, (cx, cy), s, c, -1, cv2.LINE_AA)
        else:
            pts = (rng.normal(0, s, (int(rng.integers(3, 6)), 2)) + [cx, cy]).astype(np.int32)
            cv2.fillPoly(rug, [pts], c, cv2.LINE_AA)
    bw = max(2, int(0.06 * ppm))
    cv2.rectangle(rug, (0, 0), (rw - 1, rh - 1), _color(rng, 20, 120), bw)
    _paste(img, rug, rx, ry)
    # tape lines (TUM floors have them)
    for _ in range(2):
        tw = max(2, int(0.05 * ppm))
        c = (220, 190, 40) if rng.random() < 0.5 else (230, 230, 230)
        if rng.random() < 0.5:
            y = int(rng.integers(0, h))
            cv2.line(img, (0, y), (w, y + int(rng.normal(0, 0.05 * ppm))), c, tw)
        else:
            x = int(rng.integers(0, w))
            cv2.line(img, (x, 0), (x + int(rng.normal(0, 0.05 * ppm)), h), c, tw)
    return img


def ceiling(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Acoustic ceiling tiles with random perforation, grid rails and light panels."""
    img = flat((228, 228, 224), w, h)
    img = shade_noise(img, rng, 0.04, (2, 8, 32))
    n = int(w * h / ppm**2 * 500)
    xs, ys = rng.integers(0, w, n), rng.integers(0, h, n)
    img[ys, xs] = (
        (img[ys, xs].astype(np.int32) - rng.integers(30, 90, (n, 1))).clip(0, 255).astype(np.uint8)
    )
    step = 0.6 * ppm
    for k in range(int(w / step) + 1):
        cv2.line(
            img, (int(k * step), 0), (int(k * step), h), (175, 175, 170), max(1, int(0.02 * ppm))
        )
    for k in range(int(h / step) + 1):
        cv2.line(
            img, (0, int(k * step)), (w, int(k * step)), (175, 175, 170), max(1, int(0.02 * ppm))
        )
    return img


def wood(rng: Rng, w: int, h: int, ppm: float, vertical: bool = False) -> Image:
    """Wood grain: warped sinusoidal rings with knots, in a random warm colour."""
    hh, ww = (w, h) if vertical else (h, w)
    y = np.arange(hh, dtype=np.float32)[:, None]
    warp = fbm(rng, hh, ww, (8, 40, 160)) * 6.0
    freq = rng.uniform(0.15, 0.35) * 250.0 / max(ppm, 1)
    rings = np.sin((y + warp * 4.0 + fbm(rng, hh, ww, (2, 6)) * 0.8) * freq * 2 * np.pi / 6.0)
    t = 0.5 + 0.5 * rings
    c0 = np.array(_color(rng, 150, 230), np.float32) * [1.0, 0.8, 0.55]
    c1 = c0 * rng.uniform(0.55, 0.75)
    img = (c0 * (1 - t[..., None]) + c1 * t[..., None]).astype(np.uint8)
    img = np.ascontiguousarray(img.transpose(1, 0, 2)) if vertical else img
    for _ in range(int(w * h / ppm**2 * 4) + 1):
        cv2.ellipse(
            img,
            (int(rng.integers(0, w)), int(rng.integers(0, h))),
            (int(rng.integers(2, 8)), int(rng.integers(2, 5))),
            float(rng.uniform(0, 180)),
            0,
            360,
            (int(c1[0] * 0.7), int(c1[1] * 0.7), int(c1[2] * 0.7)),
            -1,
            cv2.LINE_AA,
        )
    return img


def desk_top(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Laminate desk top with papers, notes, a mouse pad, pens, a coffee ring."""
    img = flat((214, 205, 186), w, h)
    img = shade_noise(img, rng, 0.05, (2, 10, 50))
    for _ in range(int(w * h / ppm**2 * 12) + 2):
        gen = [paper, sticky_note, paper, poster][int(rng.integers(0, 4))]
        pw, ph = int(rng.uniform(0.08, 0.3) * ppm), int(rng.uniform(0.08, 0.3) * ppm)
        if pw < 8 or ph < 8:
            continue
        _rotated_paste(
            img,
            gen(rng, pw, ph, ppm),
            int(rng.integers(0, w)),
            int(rng.integers(0, h)),
            float(rng.uniform(-30, 30)),
        )
    for _ in range(int(rng.integers(2, 6))):
        p = rng.integers(0, [w, h])
        q = p + rng.normal(0, 0.08 * ppm, 2)
        cv2.line(
            img,
            tuple(int(v) for v in p),
            tuple(int(v) for v in q),
            _vivid(rng),
            max(2, int(0.008 * ppm)),
            cv2.LINE_AA,
        )
    cv2.circle(
        img,
        (int(rng.integers(0, w)), int(rng.integers(0, h))),
        max(3, int(0.035 * ppm)),
        (150, 120, 90),
        max(1, int(0.005 * ppm)),
        cv2.LINE_AA,
    )
    return img


def books(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Shelves full of book spines with vertical titles, some lying flat, some gaps."""
    img = wood(rng, w, h, ppm)
    shelf_h = 0.38 * ppm
    board = max(2, int(0.025 * ppm))
    y = 0.0
    while y < h:
        y0, y1 = int(y) + board, int(y + shelf_h)
        x = int(rng.integers(0, max(1, int(0.05 * ppm))))
        while x < w:
            bw = int(rng.uniform(0.018, 0.06) * ppm)
            bh = int(rng.uniform(0.6, 0.95) * (y1 - y0))
            if rng.random() < 0.07:  # gap
                x += int(rng.uniform(0.05, 0.15) * ppm)
                continue
            if bw < 2 or bh < 4:
                x += 3
                continue
            c = _vivid(rng) if rng.random() < 0.7 else _color(rng, 20, 240)
            spine = flat(c, bh, bw)  # drawn horizontally, then rotated
            put_text(
                spine,
                rng,
                str(rng.choice(WORDS)),
                (int(bh * 0.1), int(bw * 0.7)),
                bw * 0.45,
                _contrast(c),
            )
            if rng.random() < 0.6:
                cv2.line(
                    spine, (int(bh * 0.8), 0), (int(bh * 0.8), bw), _contrast(c), max(1, bw // 6)
                )
            spine = cv2.rotate(spine, cv2.ROTATE_90_COUNTERCLOCKWISE)
            _paste(img, spine, x, y1 - bh)
            x += bw + int(rng.integers(0, 2))
        cv2.rectangle(img, (0, int(y)), (w, int(y) + board), (90, 60, 35), -1)
        y += shelf_h
    return img


def cardboard(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Brown cardboard with tape, printed logos, labels, arrows and barcodes."""
    base = np.array([176, 138, 92], np.float32) * rng.uniform(0.85, 1.1)
    img = flat(tuple(int(c) for c in base.clip(0, 255)), w, h)
    img = shade_noise(img, rng, 0.08, (1.5, 6, 30))
    if rng.random() < 0.7:
        tw = max(2, int(0.05 * ppm))
        cv2.rectangle(img, (w // 2 - tw // 2, 0), (w // 2 + tw // 2, h), (190, 160, 110), -1)
    for _ in range(int(w * h / ppm**2 * 40) + 2):
        kind = rng.integers(0, 4)
        x, y = int(rng.integers(0, max(1, w - 8))), int(rng.integers(8, max(9, h)))
        if kind == 0:
            put_text(
                img,
                rng,
                _words(rng, int(rng.integers(1, 3))),
                (x, y),
                rng.uniform(0.015, 0.04) * ppm,
                (40, 30, 25),
            )
        elif kind == 1:
            lw, lh = int(rng.uniform(0.06, 0.12) * ppm), int(rng.uniform(0.04, 0.08) * ppm)
            if lw > 6 and lh > 6:
                _paste(img, paper(rng, lw, lh, ppm), x, y - lh)
        elif kind == 2:  # barcode
            bx = x
            for _k in range(int(rng.integers(15, 30))):
                bw = int(rng.integers(1, 4))
                if rng.random() < 0.55:
                    cv2.rectangle(
                        img, (bx, y - int(0.03 * ppm)), (bx + bw - 1, y), (20, 20, 20), -1
                    )
                bx += bw
        else:
            s = int(rng.uniform(0.02, 0.05) * ppm)
            cv2.arrowedLine(
                img,
                (x, y),
                (x, y - 2 * s),
                (30, 30, 30),
                max(1, s // 5),
                cv2.LINE_AA,
                tipLength=0.4,
            )
    return img


def metal(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Painted metal (filing cabinet) with drawer fronts, handles, labels and stickers."""
    c = _color(rng, 120, 210)
    img = flat(c, w, h)
    img = shade_noise(img, rng, 0.03, (1, 40))
    nd = max(1, int(h / (0.3 * ppm)))
    for k in range(nd):
        y0, y1 = int(k * h / nd), int((k + 1) * h / nd)
        cv2.rectangle(
            img,
            (2, y0 + 2),
            (w - 3, y1 - 3),
            (int(c[0] * 0.6), int(c[1] * 0.6), int(c[2] * 0.6)),
            1,
        )
        hw, hh = int(0.12 * ppm), max(2, int(0.02 * ppm))
        cv2.rectangle(
            img,
            (w // 2 - hw // 2, y0 + int(0.05 * ppm)),
            (w // 2 + hw // 2, y0 + int(0.05 * ppm) + hh),
            (60, 60, 60),
            -1,
        )
        lw, lh = int(0.08 * ppm), int(0.04 * ppm)
        if lw > 6 and lh > 6:
            _paste(img, paper(rng, lw, lh, ppm), w // 2 - lw // 2, y0 + int(0.1 * ppm))
    for _ in range(int(rng.integers(1, 5))):
        sw = int(rng.uniform(0.04, 0.12) * ppm)
        if sw > 6:
            _paste(
                img,
                poster(rng, sw, sw, ppm),
                int(rng.integers(0, max(1, w - sw))),
                int(rng.integers(0, max(1, h - sw))),
            )
    return img


def screen(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Monitor front: bezel and a desktop with windows, text and icons."""
    img = flat((25, 25, 28), w, h)
    b = max(2, int(0.02 * ppm))
    desk = img[b : h - b, b : w - b]
    desk[...] = _color(rng, 20, 140)
    dh, dw = desk.shape[:2]
    for _ in range(int(rng.integers(2, 5))):
        ww_, wh_ = int(dw * rng.uniform(0.3, 0.7)), int(dh * rng.uniform(0.3, 0.7))
        x, y = int(rng.integers(0, max(1, dw - ww_))), int(rng.integers(0, max(1, dh - wh_)))
        win = desk[y : y + wh_, x : x + ww_]
        win[...] = (245, 245, 245)
        win[: max(3, wh_ // 10)] = _vivid(rng)
        text_lines(
            win,
            rng,
            3,
            max(3, wh_ // 10) + 2,
            ww_ - 3,
            wh_ - 3,
            max(4, int(0.012 * ppm)),
            (30, 30, 30),
        )
    for k in range(int(rng.integers(3, 8))):
        s = max(3, int(0.02 * ppm))
        cv2.rectangle(desk, (4, 4 + k * 2 * s), (4 + s, 4 + k * 2 * s + s), _vivid(rng), -1)
    return img


def keyboard(rng: Rng, w: int, h: int, ppm: float) -> Image:
    img = flat((45, 45, 48), w, h)
    rows = 5
    kh = h / rows
    for r in range(rows):
        x = rng.uniform(1, 4)
        while x < w - 3:
            kw = kh * (1.0 if rng.random() < 0.85 else rng.uniform(1.4, 2.5))
            cv2.rectangle(
                img,
                (int(x), int(r * kh + 1)),
                (int(x + kw - 2), int((r + 1) * kh - 1)),
                (70, 70, 74),
                -1,
            )
            put_text(
                img,
                rng,
                chr(int(rng.integers(65, 91))),
                (int(x + 2), int((r + 0.7) * kh)),
                kh * 0.3,
                (200, 200, 200),
                cv2.FONT_HERSHEY_SIMPLEX,
            )
            x += kw
    return img


def fabric(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Upholstery: a muted colour with coarse weave noise and lint."""
    c = np.array(_vivid(rng), np.float32) * 0.45 + 35
    img = flat(tuple(int(v) for v in c), w, h)
    img = shade_noise(img, rng, 0.25, (1, 3, 10))
    for _ in range(int(w * h / ppm**2 * 20) + 1):
        cv2.circle(
            img,
            (int(rng.integers(0, w)), int(rng.integers(0, h))),
            int(rng.integers(1, 3)),
            _color(rng, 0, 120),
            -1,
        )
    return img


def painted(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """A plain painted panel with a few stickers (furniture sides, partition boards)."""
    img = flat(_color(rng, 150, 235), w, h)
    img = shade_noise(img, rng, 0.05, (2, 10, 40))
    _scatter(
        img,
        rng,
        ppm,
        [
            (sticky_note, (0.07, 0.1), (0.07, 0.1), 1.0),
            (paper, (0.1, 0.25), (0.1, 0.3), 1.0),
            (poster, (0.2, 0.5), (0.25, 0.6), 1.0),
        ],
        band=(0.0, h / ppm),
        coverage=0.25,
        max_tries=60,
    )
    return img


def partition(rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Chipboard partition (as in fr3 scenes) covered with posters and notes."""
    img = np.empty((h, w, 3), np.uint8)
    img[...] = (196, 160, 110)
    img = shade_noise(img, rng, 0.12, (1.5, 3, 8, 30))
    _scatter(
        img,
        rng,
        ppm,
        [
            WALL_ITEMS[0],
            WALL_ITEMS[1],
            WALL_ITEMS[3],
            WALL_ITEMS[6],
            (sticky_note, (0.07, 0.1), (0.07, 0.1), 1.0),
        ],
        band=(0.05, h / ppm - 0.05),
        coverage=0.45,
    )
    return img


def metal_plain(rng: Rng, w: int, h: int, ppm: float) -> Image:
    img = flat(_color(rng, 40, 110), w, h)
    return shade_noise(img, rng, 0.06, (1, 5))


GENERATORS: dict[str, Callable[[Rng, int, int, float], Image]] = {
    "wall": wall,
    "floor": floor,
    "ceiling": ceiling,
    "wood": wood,
    "desk_top": desk_top,
    "books": books,
    "cardboard": cardboard,
    "metal": metal,
    "metal_plain": metal_plain,
    "screen": screen,
    "keyboard": keyboard,
    "fabric": fabric,
    "painted": painted,
    "partition": partition,
    "poster": poster,
    "paper": paper,
    "whiteboard": whiteboard,
    "notice_board": notice_board,
    "picture": picture,
}


def generate(kind: str, rng: Rng, w: int, h: int, ppm: float) -> Image:
    """Texture of ``kind`` (a key of :data:`GENERATORS`) of ``w`` x ``h`` texels."""
    img = GENERATORS[kind](rng, max(w, 2), max(h, 2), ppm)
    assert img.shape == (max(h, 2), max(w, 2), 3), (kind, img.shape, w, h)
    return img


# --------------------------------------------------------------------------- photo textures
# Real photographs as surface textures, for renders that look more like camera images than the
# procedural generators above do (issue 40, item 4: SDFCNN trained on renders only does not
# generalise to real frames). Training-time only: the photos come from packages of the
# ``train`` extra and Debian's opencv-doc; a default render never reads them.

#: opencv-doc's natural photographs (examples/data; drawings, logos, charts and calibration
#: boards left out).
OPENCV_DOC_DIR = Path("/usr/share/doc/opencv-doc/examples/data")
OPENCV_DOC_PHOTOS = ("aero1.jpg", "aero3.jpg", "aloeL.jpg", "apple.jpg", "baboon.jpg", "basketball1.png",
                     "board.jpg", "box_in_scene.png", "building.jpg", "butterfly.jpg", "fruits.jpg", "home.jpg",
                     "leuvenA.jpg", "messi5.jpg", "orange.jpg", "rubberwhale1.png", "smarties.png",
                     "squirrel_cls.jpg", "starry_night.jpg", "stuff.jpg", "graf1.png", "ela_original.jpg",
                     "licenseplate_motion.jpg", "text_defocus.jpg")
#: scikit-image's bundled photographs (``skimage.data``; the ones it ships without a download).
SKIMAGE_PHOTOS = ("astronaut", "brick", "camera", "cat", "chelsea", "coffee", "coins", "grass", "gravel",
                  "rocket", "page", "immunohistochemistry", "hubble_deep_field")
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg")


def collect_photos(dest: Path) -> list[Path]:
    """Write the real photographs of the installed sources into ``dest`` as PNG (RGB) and return
    the paths: opencv-doc's, scikit-image's and scikit-learn's sample images, whichever are
    installed (``pip install semslam[train]``, ``apt-get install opencv-doc``)."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    found: dict[str, NDArray[np.uint8]] = {}
    for name in OPENCV_DOC_PHOTOS:
        bgr = cv2.imread(str(OPENCV_DOC_DIR / name), cv2.IMREAD_COLOR)
        if bgr is not None:
            found[f"opencv_{Path(name).stem}"] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    try:
        from skimage import data as skdata

        for name in SKIMAGE_PHOTOS:
            img = np.asarray(getattr(skdata, name)())
            found[f"skimage_{name}"] = np.repeat(img[..., None], 3, 2) if img.ndim == 2 else img[..., :3]
    except ImportError:
        pass
    try:
        from sklearn.datasets import load_sample_images

        sk = load_sample_images()
        for fname, img in zip(sk.filenames, sk.images):
            found[f"sklearn_{Path(fname).stem}"] = np.asarray(img)[..., :3]
    except ImportError:
        pass
    out = []
    for name, img in sorted(found.items()):
        path = dest / f"{name}.png"
        cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(img.astype(np.uint8)), cv2.COLOR_RGB2BGR))
        out.append(path)
    return out


@functools.lru_cache(maxsize=2)
def load_photos(folder: str) -> tuple[Image, ...]:
    """The photos in ``folder`` (RGB, sorted by file name, so a seed picks the same ones)."""
    paths = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)
    photos = []
    for p in paths:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is not None:
            photos.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    if not photos:
        raise FileNotFoundError(f"no photos ({'/'.join(PHOTO_SUFFIXES)}) in {folder}")
    return tuple(photos)


def photo(rng: Rng, w: int, h: int, ppm: float, photos: tuple[Image, ...]) -> Image:
    """One of ``photos`` laid on a ``w`` x ``h`` face: printed 0.3-2 m across (a real size, so
    its detail shrinks with distance as a real surface's does), mirror-tiled over larger faces
    from a random offset, randomly flipped, and given a random colour cast."""
    src = photos[int(rng.integers(0, len(photos)))]
    if rng.random() < 0.5:
        src = src[:, ::-1]
    if rng.random() < 0.3:
        src = np.ascontiguousarray(np.rot90(src))
    across = rng.uniform(0.3, 2.0) * ppm  # texels the photo's width spans
    scale = across / src.shape[1]
    pw, ph = max(2, round(src.shape[1] * scale)), max(2, round(src.shape[0] * scale))
    img = cv2.resize(np.ascontiguousarray(src), (pw, ph), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    ox, oy = int(rng.integers(0, pw)), int(rng.integers(0, ph))
    reps_y, reps_x = (h + oy) // ph + 2, (w + ox) // pw + 2
    tile = np.concatenate([img, img[::-1]], 0)  # mirrored tiling: no seams
    tile = np.concatenate([tile, tile[:, ::-1]], 1)
    big = np.tile(tile, ((reps_y + 1) // 2 + 1, (reps_x + 1) // 2 + 1, 1))
    out = big[oy : oy + h, ox : ox + w].astype(np.float32)
    gains = rng.uniform(0.8, 1.2, 3) * rng.uniform(0.7, 1.1)
    return np.clip(out * gains, 0, 255).astype(np.uint8)


if __name__ == "__main__":  # python -m semslam.synth.textures DIR: a photo folder for --photo-textures
    import sys

    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m semslam.synth.textures DIR")
    written = collect_photos(Path(sys.argv[1]))
    print(f"{len(written)} photos in {sys.argv[1]}")
