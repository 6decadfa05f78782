"""Texture atlas: every box face gets its own texels, with lighting baked in.

All faces live in one image so that a whole frame is textured with one ``cv2.remap`` per
mip level. Lighting (ceiling lights, contact shadows under objects) depends only on the
world point, so it is baked into the texels once per scene instead of per frame; this also
keeps a static point's colour identical in every frame, as a tracker expects.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.synth import textures
from semslam.synth.scene import LIGHTS, Box

PAD = 8  # texels of replicated border around each face (enough for mip level 2)
ATLAS_WIDTH = 4096
LEVELS = 3
#: With photo textures, this share of faces shows a photograph (blended over its procedural
#: texture, which keeps some of the office's look), chosen per face by its own seeded stream.
PHOTO_SHARE = 0.6
PHOTO_STREAM = 7  # the photo choice's stream: the procedural textures' streams stay as they were
#: Ceiling lights: (position, relative intensity) per light.
Lights = tuple[tuple[NDArray[np.float64], float], ...]


@dataclass
class TextureAtlas:
    """Mip levels of the packed texture and, per box, how local points map to texels.

    ``tables[i]`` is ``(6, 2, 4)``: atlas x and y (level-0 pixel coordinates, pixel centres
    at integers) of box ``i``'s face ``f`` = ``table[f, k, :3] @ p_local + table[f, k, 3]``.
    ``ppm[i]`` holds texels per metre per face, for choosing the mip level.
    """

    levels: list[NDArray[np.uint8]]
    tables: list[NDArray[np.float32]]
    ppm: list[NDArray[np.float32]]


def _face_rng(seed: int, box: Box, f: int) -> np.random.Generator:
    """An independent stream per (seed, box, face): adding a box leaves others unchanged."""
    return np.random.default_rng([seed, zlib.crc32(box.name.encode()), f])


def _shading(
    box: Box, f: int, wpx: int, hpx: int, w: float, h: float, others: list[Box], lights: Lights = LIGHTS
) -> NDArray[np.float32]:
    """Per-texel light factor of face ``f``: Lambert from ceiling lights, wall-base darkening
    and soft contact shadows of objects standing on an upward face."""
    step = 8
    gw, gh = max(2, wpx // step + 1), max(2, hpx // step + 1)
    a = (np.arange(gw) + 0.5) * (w / gw)
    b = (np.arange(gh) + 0.5) * (h / gh)
    aa, bb = np.meshgrid(a, b)
    pts = box.face_point(f, aa, bb)  # (gh, gw, 3)
    n = box.world_normal(f)
    light = np.full((gh, gw), 0.52)
    for pos, inten in lights:
        d = pos - pts
        dist = np.linalg.norm(d, axis=-1)
        cos = np.clip((d @ n) / np.maximum(dist, 1e-6), 0.0, 1.0)
        light += 0.95 * inten * cos / (1.0 + 0.18 * dist**2)
    if abs(n[2]) < 0.5:  # vertical faces: darker near the floor
        light *= 1.0 - 0.18 * np.exp(-pts[..., 2] / 0.25)
    if n[2] > 0.9:  # upward faces: contact shadows of boxes resting above
        fz = float(pts[0, 0, 2])
        occl = np.ones((gh, gw))
        for o in others:
            c = o.corners()
            bottom = c[:, 2].min()
            gap = bottom - fz
            if o is box or o.inside or gap < -0.02 or gap > 1.2:
                continue
            x0, y0 = c[:, :2].min(0)
            x1, y1 = c[:, :2].max(0)
            inside = (
                (pts[..., 0] > x0) & (pts[..., 0] < x1) & (pts[..., 1] > y0) & (pts[..., 1] < y1)
            )
            if not inside.any():
                continue
            sigma_m = 0.03 + 0.2 * max(gap, 0.0)
            sigma = max(0.5, sigma_m / (w / gw))
            soft = cv2.GaussianBlur(inside.astype(np.float32), (0, 0), sigma)
            occl *= 1.0 - 0.5 * np.exp(-max(gap, 0.0) / 0.35) * soft
        light *= occl
    light *= 1.05
    return cv2.resize(light.astype(np.float32), (wpx, hpx), interpolation=cv2.INTER_LINEAR)


def _photo_face(tex: NDArray[np.uint8], seed: int, box: Box, f: int, ppm: float,
                photos: tuple[NDArray[np.uint8], ...]) -> NDArray[np.uint8]:
    """``tex``, or with probability :data:`PHOTO_SHARE` a photo blended over it (70-100 %)."""
    rng = np.random.default_rng([seed, zlib.crc32(box.name.encode()), f, PHOTO_STREAM])
    if rng.random() >= PHOTO_SHARE:
        return tex
    h, w = tex.shape[:2]
    alpha = rng.uniform(0.7, 1.0)
    img = textures.photo(rng, w, h, ppm, photos).astype(np.float32)
    return np.clip(alpha * img + (1 - alpha) * tex.astype(np.float32) + 0.5, 0, 255).astype(np.uint8)


def build_texture_atlas(
    boxes: list[Box], seed: int, casters: list[Box] | None = None, lights: Lights = LIGHTS,
    photo_textures: str | None = None,
) -> TextureAtlas:
    """Generate, light and pack the textures of all faces of ``boxes``; contact shadows
    are baked in from ``casters`` (default: all of ``boxes``), light from ``lights``
    (default: layout 0's). ``photo_textures``: a folder of photographs, laid on a seeded
    share of the faces (``textures.photo``); None (default) keeps the procedural ones."""
    others = boxes if casters is None else casters
    photos = textures.load_photos(photo_textures) if photo_textures else None
    items = []  # (box index, face, texture)
    for i, box in enumerate(boxes):
        for f in range(6):
            _, _, _, w, h = box.face_frame(f)
            wpx, hpx = max(2, round(w * box.ppm)), max(2, round(h * box.ppm))
            tex = textures.generate(box.faces[f], _face_rng(seed, box, f), wpx, hpx, box.ppm)
            if photos:
                tex = _photo_face(tex, seed, box, f, box.ppm, photos)
            lit = tex.astype(np.float32) * _shading(box, f, wpx, hpx, w, h, others, lights)[..., None]
            items.append((i, f, np.clip(lit + 0.5, 0, 255).astype(np.uint8), w, h))
    # shelf packing, tallest first
    order = sorted(range(len(items)), key=lambda k: -items[k][2].shape[0])
    x = y = row_h = 0
    places: dict[int, tuple[int, int]] = {}
    for k in order:
        th, tw = items[k][2].shape[:2]
        bw, bh = tw + 2 * PAD, th + 2 * PAD
        if bw > ATLAS_WIDTH:
            raise ValueError(f"texture too wide for the atlas: {bw}")
        if x + bw > ATLAS_WIDTH:
            x, y, row_h = 0, y + row_h, 0
        places[k] = (x, y)
        x += bw
        row_h = max(row_h, bh)
    height = ((y + row_h + 3) // 4) * 4
    atlas = np.zeros((height, ATLAS_WIDTH, 3), np.uint8)
    tables = [np.zeros((6, 2, 4), np.float32) for _ in boxes]
    ppm = [np.zeros(6, np.float32) for _ in boxes]
    for k, (i, f, tex, w, h) in enumerate(items):
        px, py = places[k]
        th, tw = tex.shape[:2]
        atlas[py : py + th + 2 * PAD, px : px + tw + 2 * PAD] = cv2.copyMakeBorder(
            tex, PAD, PAD, PAD, PAD, cv2.BORDER_REPLICATE
        )
        _, right, up, _, _ = boxes[i].face_frame(f)
        sx, sy = tw / w, th / h
        tables[i][f, 0, :3] = right * sx
        tables[i][f, 0, 3] = px + PAD + w / 2 * sx - 0.5
        tables[i][f, 1, :3] = -up * sy
        tables[i][f, 1, 3] = py + PAD + h / 2 * sy - 0.5
        ppm[i][f] = np.sqrt(sx * sy)
    levels = [atlas]
    for _ in range(LEVELS - 1):
        levels.append(cv2.pyrDown(levels[-1]))
    return TextureAtlas(levels=levels, tables=tables, ppm=ppm)
