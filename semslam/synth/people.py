"""People for the synthetic sequences: sprites cut out of real photos, walking paths, gait.

A person segmenter must recognise the people, so, when the TUM photos in
``shared/data/images_people`` are available, the person of ``fr3_walking_person.png`` is
cut out at run time with GrabCut (initialised from a hand-drawn outline) and completed
with lower legs that swing with the gait. Nothing derived from the photos is stored; the
cut-out is cached in memory. Without the photos a procedural figure (head, torso, arms,
legs) is drawn instead and a warning is issued.

People are rendered as upright billboards facing the camera, standing on the floor, with
a body-shaped depth bulge, bobbing and swaying while they walk.
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.synth.box_carry import CarrierTrack
from semslam.synth.raycast import Billboard
from semslam.synth.scene import LABEL_PERSON

PEOPLE_ENV = "SEMSLAM_PEOPLE_DIR"
PHOTO = "fr3_walking_person.png"

# Hand-drawn GrabCut initialisation for fr3_walking_person.png (pixel coordinates):
# probable-foreground outline and definitely-foreground strokes.
_OUTLINE = [
    (150, 46),
    (200, 58),
    (206, 138),
    (218, 150),
    (230, 212),
    (213, 236),
    (216, 290),
    (230, 330),
    (258, 372),
    (258, 402),
    (242, 404),
    (242, 480),
    (80, 480),
    (82, 382),
    (66, 300),
    (56, 180),
    (66, 142),
    (104, 134),
    (108, 58),
]
_BACKGROUND = [  # desk seen between the torso and the hand
    [(215, 357), (221, 357), (222, 370), (215, 370)],
]
_SURE = [
    [(92, 172), (192, 172), (198, 330), (100, 362)],  # torso
    [(102, 402), (218, 402), (220, 479), (102, 479)],  # trousers
]

#: Gait phases precomputed per sprite (the walk cycle is quantised to this many poses).
GAIT_STEPS = 24
STRIDE = 1.4  # metres per gait cycle (two steps)


@dataclass
class UpperBody:
    """A person from the head down to the knees, RGBA, plus where the two legs attach.

    ``knee_y`` is the last row; ``legs`` gives the (x_left, x_right) extent of each leg at
    that row; ``shin_px`` is how long the lower legs (with shoes) must be, in pixels.
    """

    rgba: NDArray[np.uint8]
    legs: tuple[tuple[int, int], tuple[int, int]]
    shin_px: int
    trouser_band: NDArray[np.uint8]  # RGB rows just above the knees, to texture the shins
    source: str


def default_people_dir() -> Path:
    """``$SEMSLAM_PEOPLE_DIR`` or ``<repo>/../shared/data/images_people``."""
    env = os.environ.get(PEOPLE_ENV)
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    return repo.parent / "shared" / "data" / "images_people"


def cutout_photo(path: Path) -> UpperBody:
    """GrabCut the walking person out of the fr3 photo (RGB result, cropped)."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None or bgr.shape[:2] != (480, 640):
        raise OSError(f"cannot read a 640x480 image from {path}")
    x0, y0, x1, y1 = 30, 30, 290, 480
    sub = np.ascontiguousarray(bgr[y0:y1, x0:x1])
    mask = np.full(sub.shape[:2], cv2.GC_BGD, np.uint8)
    off = np.array([x0, y0])
    cv2.fillPoly(mask, [np.array(_OUTLINE) - off], cv2.GC_PR_FGD)
    for poly in _SURE:
        cv2.fillPoly(mask, [np.array(poly) - off], cv2.GC_FGD)
    for poly in _BACKGROUND:
        cv2.fillPoly(mask, [np.array(poly) - off], cv2.GC_BGD)
    cv2.ellipse(mask, (152 - x0, 98 - y0), (20, 26), 0, 0, 360, cv2.GC_FGD, -1)
    cv2.line(mask, (205 - x0, 240 - y0), (232 - x0, 352 - y0), cv2.GC_FGD, 8)  # forearm
    cv2.ellipse(mask, (238 - x0, 380 - y0), (8, 13), 0, 0, 360, cv2.GC_FGD, -1)  # hand
    cv2.setRNGSeed(0)  # GrabCut's GMM init uses OpenCV's RNG: keep it deterministic
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.grabCut(sub, mask, None, bgd, fgd, 4, cv2.GC_INIT_WITH_MASK)
    m = np.where((mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD), 255, 0).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m)
    if n < 2:
        raise OSError(f"GrabCut found no person in {path}")
    m = np.where(lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])), 255, 0).astype(np.uint8)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)))
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
    # fill holes: everything not reachable from the border is foreground
    inv = cv2.bitwise_not(m)
    ff = inv.copy()
    cv2.floodFill(ff, None, (0, 0), 0)
    m = cv2.bitwise_or(m, ff)
    alpha = cv2.GaussianBlur(m, (0, 0), 0.8)
    ys, xs = np.nonzero(m)
    top, left, right = ys.min(), xs.min(), xs.max() + 1
    rgb = cv2.cvtColor(sub, cv2.COLOR_BGR2RGB)
    rgba = np.dstack([rgb, alpha])[top:, left:right].copy()
    last = m[-1, left:right] > 0
    cols = np.nonzero(last)[0]
    lo, hi = int(cols.min()), int(cols.max()) + 1
    mid = (lo + hi) // 2
    band = rgb[-60:, left + lo : left + hi].copy()
    h = rgba.shape[0]
    # the wrist (y=360) is at ~52 % of the height from the top: photo covers ~0.72 H
    shin = round(h / 0.72 * 0.28)
    return UpperBody(rgba, ((lo, mid), (mid, hi)), shin, band, str(path.name))


def _procedural_upper(rng: np.random.Generator) -> UpperBody:
    """A drawn person (head to knees) for when the photos are unavailable."""
    h, w = 425, 220
    img = np.zeros((h, w, 4), np.uint8)
    skin = (205, 160, 130, 255)
    hair = tuple(int(c) for c in rng.integers(20, 90, 3)) + (255,)
    shirt = (52, 52, 56, 255)  # dark grey: _recolour puts a pattern on it
    pants = tuple(int(c) for c in rng.integers(30, 120, 3)) + (255,)
    cx = w // 2
    cv2.fillPoly(
        img,
        [np.array([(cx - 80, 120), (cx + 80, 120), (cx + 68, 330), (cx - 68, 330)])],
        shirt,
        cv2.LINE_AA,
    )
    cv2.rectangle(img, (cx - 14, 80), (cx + 14, 125), skin, -1)
    cv2.ellipse(img, (cx, 55), (34, 44), 0, 0, 360, skin, -1, cv2.LINE_AA)
    cv2.ellipse(img, (cx, 40), (36, 32), 0, 180, 360, hair, -1, cv2.LINE_AA)
    for s in (-1, 1):  # arms
        cv2.line(img, (cx + s * 78, 130), (cx + s * 92, 250), shirt, 30, cv2.LINE_AA)
        cv2.line(img, (cx + s * 92, 240), (cx + s * 96, 340), skin, 22, cv2.LINE_AA)
        cv2.circle(img, (cx + s * 96, 350), 15, skin, -1, cv2.LINE_AA)
    cv2.fillPoly(
        img,
        [np.array([(cx - 68, 325), (cx + 68, 325), (cx + 64, h), (cx - 64, h)])],
        pants,
        cv2.LINE_AA,
    )
    cv2.line(img, (cx, 360), (cx, h), tuple(int(c * 0.7) for c in pants[:3]) + (255,), 3)
    for s in (-1, 1):  # face: ears, eyes, brows; then nose and mouth
        cv2.ellipse(img, (cx + s * 34, 58), (6, 11), 0, 0, 360, skin, -1, cv2.LINE_AA)
        cv2.ellipse(
            img, (cx + s * 13, 52), (6, 3), 0, 0, 360, (245, 245, 240, 255), -1, cv2.LINE_AA
        )
        cv2.circle(img, (cx + s * 13, 52), 2, (40, 30, 25, 255), -1, cv2.LINE_AA)
        cv2.line(img, (cx + s * 6, 43), (cx + s * 20, 42), hair, 3, cv2.LINE_AA)
    cv2.line(img, (cx, 55), (cx - 3, 68), (170, 120, 95, 255), 2, cv2.LINE_AA)
    cv2.ellipse(img, (cx, 80), (10, 4), 0, 0, 180, (150, 70, 70, 255), 2, cv2.LINE_AA)
    # round shading (bodies are cylinders) and fabric noise
    xs = (np.arange(w) - cx) / (w / 2)
    shade = (1.0 - 0.35 * xs**2)[None, :, None]
    noise = rng.normal(0, 6, (h, w, 1))
    img[..., :3] = np.clip(img[..., :3] * shade + noise, 0, 255).astype(np.uint8)
    band = img[-60:, cx - 64 : cx + 64, :3].copy()
    return UpperBody(img, ((cx - 64, cx), (cx, cx + 64)), 165, band, "procedural")


@functools.lru_cache(maxsize=4)
def load_upper_body(people_dir: str | None) -> UpperBody:
    """The photo cut-out if available (cached), else the procedural figure with a warning."""
    d = Path(people_dir) if people_dir else default_people_dir()
    path = d / PHOTO
    if path.is_file():
        try:
            return cutout_photo(path)
        except OSError as exc:
            warnings.warn(f"synth: {exc}; using procedural people", stacklevel=2)
    else:
        warnings.warn(
            f"synth: {path} not found; using procedural people (set {PEOPLE_ENV} or --people-dir)",
            stacklevel=2,
        )
    return _procedural_upper(np.random.default_rng(0))


# --------------------------------------------------------------------------- variants


TROUSERS = [None, (50, 60, 110), (60, 55, 50), (110, 100, 80)]
SHIRT_KINDS = ("print", "plaid", "stripes", "print", "plaid", "stripes")


def _shirt_pattern(
    kind: str, h: int, w: int, rng: np.random.Generator, variant: int
) -> NDArray[np.float32]:
    """What a shirt looks like flat: plaid, stripes or a big print on a plain colour.

    People in the fr3 walking sequences wear such shirts; their texture gives ORB corners
    on the people, which is what makes dynamic objects harmful to a naive tracker.
    """

    def col(lo: int, hi: int) -> NDArray[np.float32]:
        return rng.integers(lo, hi, 3).astype(np.float32)

    if kind == "plaid":
        img = np.empty((h, w, 3), np.float32)
        img[...] = col(60, 200) * np.array([1.0, 0.7, 0.6], np.float32)[rng.permutation(3)]
        for axis in (0, 1):
            pos = 0
            size = h if axis == 0 else w
            while pos < size:
                bw = int(rng.integers(4, 14))
                c, a = col(10, 240), rng.uniform(0.45, 0.8)
                sl = (
                    (slice(pos, pos + bw), slice(None))
                    if axis == 0
                    else (slice(None), slice(pos, pos + bw))
                )
                img[sl] = img[sl] * (1 - a) + c * a
                pos += bw + int(rng.integers(6, 22))
        return img
    if kind == "stripes":
        img = np.empty((h, w, 3), np.float32)
        c0, c1 = col(150, 245), col(20, 140)
        img[...] = c0
        pos = 0
        while pos < h:
            bw = int(rng.integers(5, 16))
            img[pos : pos + bw] = c1 if rng.random() < 0.8 else col(20, 240)
            pos += bw + int(rng.integers(5, 16))
        return img
    base = np.zeros(3, np.float32) if variant == 0 else col(20, 160)
    img = np.empty((h, w, 3), np.uint8)
    img[...] = base.astype(np.uint8)
    cx, cy = w // 2, int(h * 0.35)
    ink = tuple(int(v) for v in col(150, 255))
    cv2.circle(img, (cx, cy), max(6, w // 6), ink, max(2, w // 40), cv2.LINE_AA)
    for _ in range(int(rng.integers(3, 7))):
        pts = (rng.normal(0, w / 8, (3, 2)) + [cx, cy]).astype(np.int32)
        cv2.fillPoly(img, [pts], tuple(int(v) for v in col(60, 255)), cv2.LINE_AA)
    word = str(rng.choice(["TUM", "ROBOTICS", "FREIBURG", "LAB", "2012", "KINECT"]))
    scale = w / 260.0
    (tw, th), _ = cv2.getTextSize(word, cv2.FONT_HERSHEY_DUPLEX, scale, 2)
    cv2.putText(
        img,
        word,
        (cx - tw // 2, cy + max(6, w // 6) + th + 8),
        cv2.FONT_HERSHEY_DUPLEX,
        scale,
        ink,
        2,
        cv2.LINE_AA,
    )
    return img.astype(np.float32)


def _recolour(
    ub: UpperBody, variant: int, seed: int
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Shirt pattern and trouser colour per person so that several people look different.

    The photo's shading (wrinkles, folds) is kept by modulating the pattern with the
    original luminance relative to its median over the shirt.
    """
    rng = np.random.default_rng([seed, variant, 41])
    rgba = ub.rgba.copy()
    band = ub.trouser_band.copy()
    trousers = TROUSERS[(variant // 2 + variant) % len(TROUSERS)] if variant else None
    rgb = rgba[..., :3].astype(np.float32)
    lum = rgb.mean(-1)
    h, w = rgba.shape[:2]
    rows = np.arange(h)[:, None]
    sat = rgb.max(-1) - rgb.min(-1)
    torso = (rows > 0.2 * h) & (rows < 0.78 * h) & (lum < 75) & (sat < 40) & (rgba[..., 3] > 0)
    if torso.sum() > 100:
        ys, xs = np.nonzero(torso)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        pattern = np.zeros((h, w, 3), np.float32)
        pattern[y0:y1, x0:x1] = _shirt_pattern(
            SHIRT_KINDS[variant % len(SHIRT_KINDS)], y1 - y0, x1 - x0, rng, variant
        )
        smooth = cv2.GaussianBlur(lum, (0, 0), 1.5)  # the photo's noise must not be amplified
        shade = np.clip(smooth / max(float(np.median(smooth[torso])), 1.0), 0.45, 1.5)
        rgb[torso] = np.clip(pattern[torso] * shade[torso, None] * 0.9, 0, 255)
    if trousers is not None:
        legs = (rows >= 0.8 * h) & (rgba[..., 3] > 0)
        gain = np.array(trousers, np.float32) / 90.0
        rgb[legs] = np.clip(lum[legs, None] * gain, 0, 255)
        bl = band.astype(np.float32).mean(-1)
        band = np.clip(bl[..., None] * gain, 0, 255).astype(np.uint8)
    rgba[..., :3] = rgb.astype(np.uint8)
    return rgba, band


def _shin(
    band: NDArray[np.uint8], top_w: int, length: int, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """A tapered lower leg of ``length`` px, textured by mirror-tiling the trouser band,
    ending in a shoe; RGBA."""
    bh = band.shape[0]
    reps = length // bh + 2
    tiles = [band if k % 2 == 0 else band[::-1] for k in range(reps)]
    tex = np.concatenate(tiles, 0)[:length]
    tex = cv2.resize(tex, (top_w, length), interpolation=cv2.INTER_LINEAR)
    shoe_h = max(4, int(length * 0.14))
    leg_len = length - shoe_h
    bottom_w = max(4, int(top_w * 0.62))
    src = np.float32([[0, 0], [top_w, 0], [top_w, leg_len], [0, leg_len]])
    inset = (top_w - bottom_w) / 2
    dst = np.float32([[0, 0], [top_w, 0], [top_w - inset, leg_len], [inset, leg_len]])
    warp = cv2.getPerspectiveTransform(src, dst)
    rgb = cv2.warpPerspective(tex[:leg_len], warp, (top_w, length), borderMode=cv2.BORDER_REPLICATE)
    alpha = np.zeros((length, top_w), np.uint8)
    cv2.fillPoly(alpha, [dst.astype(np.int32)], 255, cv2.LINE_AA)
    shoe_col = tuple(int(c) for c in rng.integers(15, 60, 3))
    cx = top_w // 2
    cv2.ellipse(
        rgb,
        (cx + int(0.1 * top_w), length - shoe_h // 2 - 1),
        (int(bottom_w * 0.75), shoe_h // 2),
        0,
        0,
        360,
        shoe_col,
        -1,
        cv2.LINE_AA,
    )
    cv2.ellipse(
        alpha,
        (cx + int(0.1 * top_w), length - shoe_h // 2 - 1),
        (int(bottom_w * 0.75), shoe_h // 2),
        0,
        0,
        360,
        255,
        -1,
        cv2.LINE_AA,
    )
    return np.dstack([rgb, alpha])


def _over(dst: NDArray[np.float32], src: NDArray[np.uint8], x: int, y: int) -> None:
    """Alpha-composite an RGBA uint8 image onto a float RGBA canvas at (x, y)."""
    h, w = src.shape[:2]
    H, W = dst.shape[:2]
    xa, ya, xb, yb = max(0, x), max(0, y), min(W, x + w), min(H, y + h)
    if xb <= xa or yb <= ya:
        return
    s = src[ya - y : yb - y, xa - x : xb - x].astype(np.float32)
    a = s[..., 3:4] / 255.0
    d = dst[ya:yb, xa:xb]
    d[..., :3] = s[..., :3] * a + d[..., :3] * (1 - a)
    d[..., 3:4] = 255.0 * a + d[..., 3:4] * (1 - a)


@dataclass
class Sprite:
    """One walking pose of one person: image pyramid, depth bulge and its size in metres."""

    rgba: list[NDArray[np.uint8]]
    bulge: list[NDArray[np.float32]]
    width_m: float
    height_m: float


class PersonLook:
    """A person's appearance: a recoloured cut-out with gait poses rendered on demand."""

    def __init__(self, ub: UpperBody, variant: int, height_m: float, seed: int) -> None:
        self.ub = ub
        self.rgba, self.band = _recolour(ub, variant, seed)
        self.height_m = height_m
        rng = np.random.default_rng([seed, variant, 77])
        (l0, l1), (r0, r1) = ub.legs
        self.shins = [
            _shin(self.band[:, : l1 - l0], l1 - l0, ub.shin_px, rng),
            _shin(self.band[:, l1 - l0 :], r1 - r0, ub.shin_px, rng),
        ]
        self.margin = int(ub.shin_px * 0.5) + 4
        self._cache: dict[tuple[int, int, bool], Sprite] = {}

    def sprite(self, phase: float, swing: float, flip: bool) -> Sprite:
        """The pose at gait ``phase`` (radians) with legs swinging ``swing`` (0..1) across."""
        k = round(float(phase) / (2 * np.pi) * GAIT_STEPS) % GAIT_STEPS
        s = round(float(np.clip(swing, 0, 1)) * 3)
        key = (k, s, flip)
        if key not in self._cache:
            self._cache[key] = self._compose(2 * np.pi * k / GAIT_STEPS, s / 3.0, flip)
        return self._cache[key]

    def _compose(self, phase: float, swing: float, flip: bool) -> Sprite:
        ub = self.ub
        uh, uw = self.rgba.shape[:2]
        H = uh + ub.shin_px
        W = uw + 2 * self.margin
        knee_y = uh - 2
        amp = np.deg2rad(24.0) * swing
        # legs first (the one swinging back behind), each rotated about its knee into a
        # small region of the canvas; then the upper body on top
        canvas = np.zeros((H, W, 4), np.float32)
        order = [0, 1] if np.sin(phase) > 0 else [1, 0]
        for leg in order:
            shin = self.shins[leg]
            ang = np.rad2deg(amp * np.sin(phase) * (1 if leg == 0 else -1))
            lh, lw = shin.shape[:2]
            reach = int(np.ceil(lh * np.sin(np.deg2rad(abs(ang))) + lw * 0.5)) + 2
            x_attach = self.margin + ub.legs[leg][0]  # left edge of the leg at the knee
            x0, y0 = x_attach + lw // 2 - (lw // 2 + reach), knee_y - reach
            rw, rh = lw + 2 * reach, lh + 2 * reach
            rot = cv2.getRotationMatrix2D((lw / 2, 0.0), ang, 1.0)
            rot[0, 2] += x_attach - x0
            rot[1, 2] += knee_y - y0
            region = cv2.warpAffine(
                shin,
                rot,
                (rw, rh),
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0,
            )
            _over(canvas, region, x0, y0)
        band = max(0, knee_y - int(self.margin))  # rows above which no leg reaches
        canvas[:band, self.margin : self.margin + uw] = self.rgba[:band]
        _over(canvas, self.rgba[band:], self.margin, band)
        img = (canvas + np.float32(0.5)).astype(np.uint8)
        if flip:
            img = np.ascontiguousarray(img[:, ::-1])
        mask = (img[..., 3] > 127).astype(np.uint8)
        dt = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
        body_px = 0.14 * H  # about half a torso width
        bulge = (0.13 * np.sqrt(np.clip(dt / body_px, 0, 1))).astype(np.float32)
        bulge = cv2.GaussianBlur(bulge, (0, 0), 2.0)
        rgba, bul = [img], [bulge]
        for _ in range(2):
            rgba.append(cv2.pyrDown(rgba[-1]))
            bul.append(cv2.pyrDown(bul[-1]))
        return Sprite(rgba, bul, self.height_m * W / H, self.height_m)


# --------------------------------------------------------------------------- motion


@dataclass
class PersonTrack:
    """Where a person is: a closed walking loop at constant speed, or standing idle."""

    points: NDArray[np.float64]  # (N, 2) closed polyline on the floor
    speed: float
    start: float  # arc length at t = 0
    idle: bool = False

    def __post_init__(self) -> None:
        seg = np.diff(np.vstack([self.points, self.points[:1]]), axis=0)
        self.cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
        self.length = float(self.cum[-1])

    def is_idle(self, t: float) -> bool:
        """Standing (no gait, bob or sway) at time ``t``."""
        return self.idle

    def state(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """(position xy, unit heading xy, distance walked) at time ``t``."""
        if self.idle:
            sway = np.array(
                [0.03 * np.sin(2 * np.pi * t / 3.1), 0.02 * np.sin(2 * np.pi * t / 4.3)]
            )
            return self.points[0] + sway, np.array([0.0, -1.0]), 0.0
        walked = self.speed * t
        s = (self.start + walked) % self.length
        i = int(np.searchsorted(self.cum, s, side="right") - 1)
        i = min(i, len(self.points) - 1)
        p0, p1 = self.points[i], self.points[(i + 1) % len(self.points)]
        seg = self.cum[i + 1] - self.cum[i]
        u = (s - self.cum[i]) / max(seg, 1e-9)
        heading = (p1 - p0) / max(seg, 1e-9)
        return p0 + u * (p1 - p0), heading, walked


def _ellipse(
    cx: float, cy: float, rx: float, ry: float, reverse: bool, n: int = 256
) -> NDArray[np.float64]:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    if reverse:
        a = -a
    return np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], 1)


def make_tracks(n: int, mode: str, seed: int) -> list[PersonTrack]:
    """Paths in the free floor area in front of the desks (x 0.6..5.4, y 2.5..3.95).

    Person 0 starts in the middle of the view walking across it so that even short
    sequences show a person; the others enter from the sides or the back.
    """
    rng = np.random.default_rng([seed, 991])
    tracks = []
    if mode == "idle":
        spots = [
            (2.35, 3.8),
            (3.8, 3.75),
            (1.3, 3.5),
            (4.7, 3.6),
            (3.0, 3.9),
            (1.9, 3.4),
            (4.2, 3.3),
            (2.8, 3.5),
        ]
        return [
            PersonTrack(np.array([spots[i % len(spots)]]), 0.0, 0.0, idle=True) for i in range(n)
        ]
    templates = [
        (3.0, 3.22, 2.15, 0.66, False),
        (3.05, 3.35, 1.75, 0.5, True),
        (3.0, 3.7, 2.3, 0.18, False),
        (2.8, 3.1, 1.9, 0.55, True),
    ]
    for i in range(n):
        cx, cy, rx, ry, rev = templates[i % len(templates)]
        if i >= len(templates):
            cx += rng.uniform(-0.2, 0.2)
            cy += rng.uniform(-0.1, 0.1)
        pts = _ellipse(cx, cy, rx, ry, rev)
        speed = float(rng.uniform(0.85, 1.15))
        track = PersonTrack(pts, speed, 0.0)
        # start arc length: person 0 near the view centre on the far side; others spread
        if i == 0:
            target = np.array([2.3, cy + ry])
        else:
            target = np.array([cx + (rx if i % 2 else -rx), cy])
        k = int(np.argmin(np.linalg.norm(pts - target, axis=1)))
        track.start = float(track.cum[k] + rng.uniform(-0.3, 0.3) * (i > 0))
        tracks.append(track)
    return tracks


class People:
    """All people of a sequence: appearance and track per person, billboards per frame."""

    def __init__(
        self, n: int, mode: str, seed: int, people_dir: str | None, carrier: bool = False
    ) -> None:
        """``n`` people walking (or idle), plus, with ``carrier``, the person who pushes and
        carries the box of :mod:`semslam.synth.box_carry` (the others are unchanged by it)."""
        self.source = "none"
        self.looks: list[PersonLook] = []
        self.tracks: list[PersonTrack | CarrierTrack] = []
        self.tracks += make_tracks(n, mode, seed) if n else []
        if n or carrier:
            ub = load_upper_body(people_dir)
            self.source = ub.source
            rng = np.random.default_rng([seed, 313])
            for i in range(n):
                self.looks.append(PersonLook(ub, i, float(rng.uniform(1.68, 1.86)), seed))
            if carrier:
                self.looks.append(PersonLook(ub, n, float(rng.uniform(1.68, 1.86)), seed))
                self.tracks.append(CarrierTrack())

    def billboards(self, t: float, cam_pos: NDArray[np.float64]) -> list[Billboard]:
        """Billboards at time ``t``, sorted far to near for correct alpha blending."""
        out = []
        for look, track in zip(self.looks, self.tracks):
            pos, heading, walked = track.state(t)
            phase = 2 * np.pi * walked / STRIDE
            view = pos - cam_pos[:2]
            view /= max(np.linalg.norm(view), 1e-9)
            right = np.array([view[1], -view[0]])  # viewer's right on the floor
            lateral = float(heading @ right)
            idle = track.is_idle(t)
            flip = lateral < 0 if not idle else False
            sp = look.sprite(phase, 0.0 if idle else abs(lateral), flip)
            # walking: bob twice per cycle, sway sideways once per cycle
            bob = 0.0 if idle else 0.012 * (np.cos(2 * phase) - 1.0)
            side = np.array([-heading[1], heading[0]])
            sway = (0.0 if idle else 0.025 * np.sin(phase)) * side
            foot = np.array([pos[0] + sway[0], pos[1] + sway[1], bob])
            out.append(Billboard(foot, sp.width_m, sp.height_m, sp.rgba, sp.bulge, LABEL_PERSON))
        out.sort(key=lambda b: -np.linalg.norm(b.foot[:2] - cam_pos[:2]))
        return out
