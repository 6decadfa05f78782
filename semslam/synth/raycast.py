"""Vectorised ray casting of boxes and billboards into z-buffers, and atlas sampling.

Rays are parametrised by z-depth: pixel (u, v) has direction ``d = ((u-cx)/fx, (v-cy)/fy, 1)``
in the camera frame, so the hit parameter ``t`` *is* the depth image value. Each
direction component in a box frame is affine in (x', y'), so it costs one broadcast add
per box; work is limited to the box's projected bounding rectangle.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.synth.scene import Box

F32 = NDArray[np.float32]
NEAR = 0.05  # metres; closer geometry is not drawn


@dataclass
class Camera:
    """Intrinsics and per-pixel normalised ray coordinates for one image size."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        self.xs = ((np.arange(self.width) - self.cx) / self.fx).astype(np.float32)
        self.ys = ((np.arange(self.height) - self.cy) / self.fy).astype(np.float32)
        self.ray_norm = np.sqrt(self.xs[None, :] ** 2 + self.ys[:, None] ** 2 + 1.0).astype(
            np.float32
        )

    @property
    def f(self) -> float:
        return 0.5 * (self.fx + self.fy)

    def bbox(
        self, pts_world: NDArray[np.float64], pose: NDArray[np.float64]
    ) -> tuple[int, int, int, int] | None:
        """Pixel rectangle (r0, r1, c0, c1) covering the projection of points, None if all
        are behind the camera; the whole image if some are behind (conservative)."""
        pc = (pts_world - pose[:3, 3]) @ pose[:3, :3]
        z = pc[:, 2]
        if np.all(z < NEAR):
            return None
        if np.any(z < NEAR):
            return 0, self.height, 0, self.width
        u = self.fx * pc[:, 0] / z + self.cx
        v = self.fy * pc[:, 1] / z + self.cy
        c0 = max(0, int(np.floor(u.min())) - 1)
        c1 = min(self.width, int(np.ceil(u.max())) + 2)
        r0 = max(0, int(np.floor(v.min())) - 1)
        r1 = min(self.height, int(np.ceil(v.max())) + 2)
        if c1 <= c0 or r1 <= r0:
            return None
        return r0, r1, c0, c1


class Buffers:
    """Per-pixel results of casting: depth, atlas coordinates, texel footprint, label."""

    def __init__(self, h: int, w: int) -> None:
        self.z = np.full((h, w), np.inf, np.float32)
        self.mapx = np.zeros((h, w), np.float32)
        self.mapy = np.zeros((h, w), np.float32)
        self.foot = np.ones((h, w), np.float32)  # texels per pixel
        self.cos = np.ones((h, w), np.float32)  # |cos| of incidence, for depth dropout
        self.label = np.zeros((h, w), np.uint8)

    def copy(self) -> Buffers:
        """An independent copy (to go on casting into one while keeping the other)."""
        out = Buffers.__new__(Buffers)
        for name in ("z", "mapx", "mapy", "foot", "cos", "label"):
            setattr(out, name, getattr(self, name).copy())
        return out


def _lut(values: NDArray[np.float32]) -> NDArray[np.float32]:
    """A 256-entry float32 table for ``cv2.LUT`` (much faster than ``np.take``)."""
    lut = np.zeros(256, np.float32)
    lut[: len(values)] = values
    return lut


def _lut8(values: tuple[int, ...]) -> NDArray[np.uint8]:
    """A 256-entry uint8 table for ``cv2.LUT`` (face index -> label id)."""
    lut = np.zeros(256, np.uint8)
    lut[: len(values)] = values
    return lut


def cast_box(
    buf: Buffers, cam: Camera, pose: NDArray[np.float64], box: Box, table: F32, ppm: F32
) -> None:
    """Ray-cast one box (slab method) and keep the nearer hits in ``buf``.

    Works on whole arrays of the box's screen rectangle (``np.copyto(where=...)``) rather
    than gathering hit pixels, which is faster for the large boxes (room, partition).
    """
    rect = (0, cam.height, 0, cam.width) if box.inside else cam.bbox(box.corners(), pose)
    if rect is None:
        return
    r0, r1, c0, c1 = rect
    m = (box.rot.T @ pose[:3, :3]).astype(np.float32)
    o = (box.rot.T @ (pose[:3, 3] - box.center)).astype(np.float32)
    half = box.half.astype(np.float32)
    xs, ys = cam.xs[c0:c1], cam.ys[r0:r1]
    d, tks = [], []
    t = tfar = None
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for k in range(3):
            dk = (m[k, 1] * ys + m[k, 2])[:, None] + (m[k, 0] * xs)[None, :]
            inv = np.float32(1.0) / dk
            t1 = (-half[k] - o[k]) * inv
            t2 = (half[k] - o[k]) * inv
            if box.inside:  # leave the room through the farther slab plane
                tk = np.maximum(t1, t2)
                t = tk if t is None else np.minimum(t, tk)
            else:  # enter through the nearer one
                tk = np.minimum(t1, t2)
                tf = np.maximum(t1, t2)
                t = tk if t is None else np.maximum(t, tk)
                tfar = tf if tfar is None else np.minimum(tfar, tf)
            d.append(dk)
            tks.append(tk)
        zsub = buf.z[r0:r1, c0:c1]
        hit = (t > NEAR) & (t < zsub)
        if tfar is not None:
            hit &= t <= tfar
    if not hit.any():
        return
    # which slab gave t: the face axis; face index = 2 * axis + (0 for +, 1 for -)
    is2 = tks[2] == t
    is1 = (tks[1] == t) & ~is2
    is0 = ~(is1 | is2)
    dax = np.where(is2, d[2], np.where(is1, d[1], d[0]))
    # entering (outside) through the - face when moving along +; leaving the room through +
    neg = dax < 0 if box.inside else dax > 0
    face = (is1.view(np.uint8) << 1) + (is2.view(np.uint8) << 2) + neg.view(np.uint8)
    with np.errstate(invalid="ignore"):  # t is inf where nothing is hit; masked below
        p = [o[k] + t * d[k] for k in range(3)]
    # texture coordinates: horizontal from y on x-faces else x; vertical from y on z-faces else z
    pa = np.where(is0, p[1], p[0])
    pb = np.where(is2, p[1], p[2])
    tb = table.astype(np.float32)
    sa = tb[np.arange(6), 0, np.array([1, 1, 0, 0, 0, 0])]
    sb = tb[np.arange(6), 1, np.array([2, 2, 2, 2, 1, 1])]
    ax = cv2.LUT(face, _lut(sa)) * pa + cv2.LUT(face, _lut(tb[:, 0, 3]))
    ay = cv2.LUT(face, _lut(sb)) * pb + cv2.LUT(face, _lut(tb[:, 1, 3]))
    nrm = cam.ray_norm[r0:r1, c0:c1]
    cos = np.abs(dax) / nrm
    foot = (
        cv2.LUT(face, _lut(ppm.astype(np.float32) / np.float32(cam.f)))
        * (t * nrm)
        / np.sqrt(np.maximum(cos, np.float32(0.05)))
    )
    np.copyto(zsub, t, where=hit)
    np.copyto(buf.mapx[r0:r1, c0:c1], ax, where=hit)
    np.copyto(buf.mapy[r0:r1, c0:c1], ay, where=hit)
    np.copyto(buf.foot[r0:r1, c0:c1], foot, where=hit)
    np.copyto(buf.cos[r0:r1, c0:c1], cos, where=hit)
    if box.classes:  # a static box: the class of the face hit
        labels = cv2.LUT(face, _lut8(box.classes))
        np.copyto(buf.label[r0:r1, c0:c1], labels, where=hit)
    elif box.label or not box.inside:
        np.copyto(buf.label[r0:r1, c0:c1], np.uint8(box.label), where=hit)


def sample_atlas(levels: list[NDArray[np.uint8]], buf: Buffers) -> NDArray[np.uint8]:
    """Trilinear (mip-mapped) texture lookup of the whole frame: ``(H, W, 3)`` uint8.

    The level of detail is log2 of the texel footprint; levels 0-1 and 1-2 are blended
    with ``cv2.blendLinear`` so that far and grazing surfaces do not alias (aliasing would
    make ORB corners flicker from frame to frame).
    """
    lod = np.log2(np.maximum(buf.foot, np.float32(1e-6)))
    needed = 1 + int(np.ceil(np.clip(float(lod.max()), 0.0, len(levels) - 1.0)))
    samples = []
    for lv, img in enumerate(levels[:needed]):
        s = np.float32(0.5**lv)
        mx = (buf.mapx + np.float32(0.5)) * s - np.float32(0.5) if lv else buf.mapx
        my = (buf.mapy + np.float32(0.5)) * s - np.float32(0.5) if lv else buf.mapy
        samples.append(cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    out = samples[0]
    for lv in range(1, needed):
        f = np.clip(lod - np.float32(lv - 1), 0.0, 1.0).astype(np.float32)
        out = cv2.blendLinear(out, samples[lv], np.float32(1.0) - f, f)
    return out


@dataclass
class Billboard:
    """An upright textured rectangle facing the camera (a person).

    ``foot`` is the world point under the middle of the sprite's bottom edge; the sprite
    is ``width`` x ``height`` metres. ``rgba`` levels (uint8) and ``bulge`` levels (metres
    the body surface stands out towards the camera) share texel coordinates.
    """

    foot: NDArray[np.float64]
    width: float
    height: float
    rgba: list[NDArray[np.uint8]]
    bulge: list[F32]
    label: int


def _billboard_frame(
    bb: Billboard, cam_pos: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """(normal towards the camera, right axis, the 4 corners) of a billboard seen from
    ``cam_pos``; None when the camera stands right above its foot."""
    up = np.array([0.0, 0.0, 1.0])
    n = cam_pos - bb.foot
    n[2] = 0.0
    dist_h = np.linalg.norm(n)
    if dist_h < 1e-3:
        return None
    n /= dist_h
    right = np.cross(up, n)
    corners = np.array(
        [bb.foot + sa * bb.width / 2 * right + z * up for sa in (-1, 1) for z in (0.0, bb.height)]
    )
    return n, right, corners


def billboard_aabb(
    bb: Billboard, cam: Camera, pose: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """World axis-aligned box holding every surface point :func:`cast_billboard` can draw
    for ``bb`` seen from ``pose``: the sprite's rectangle and the same moved towards the
    camera by the largest bulge (along a ray, hence the factor of the most oblique ray)."""
    frame = _billboard_frame(bb, pose[:3, 3])
    if frame is None:
        return None
    n, _, corners = frame
    nc2 = abs(float((pose[:3, :3].T @ n)[2]))
    reach = float(max(np.max(b) for b in bb.bulge)) * nc2 * float(cam.ray_norm.max())
    towards = pose[:3, 3] - corners
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    pts = np.vstack([corners, corners + reach * towards])
    return pts.min(axis=0), pts.max(axis=0)


def cast_billboard(
    buf: Buffers, rgb: NDArray[np.uint8], cam: Camera, pose: NDArray[np.float64], bb: Billboard,
    facing: NDArray[np.float64] | None = None,
) -> None:
    """Draw a billboard over ``rgb`` with alpha, depth test against and update ``buf``.

    The billboard turns to face ``facing`` (default: the camera's centre); a stereo rig's right
    camera passes the left one's centre so that both see the same plane (the same scene)."""
    c = pose[:3, 3]
    up = np.array([0.0, 0.0, 1.0])
    frame = _billboard_frame(bb, c if facing is None else facing)
    if frame is None:
        return
    n, right, corners = frame
    rect = cam.bbox(corners, pose)
    if rect is None:
        return
    r0, r1, c0, c1 = rect
    rw = pose[:3, :3]
    nc, rc, uc = rw.T @ n, rw.T @ right, rw.T @ up
    xs, ys = cam.xs[c0:c1], cam.ys[r0:r1]

    def lin(v: NDArray[np.float64]) -> F32:
        return (np.float32(v[1]) * ys + np.float32(v[2]))[:, None] + (np.float32(v[0]) * xs)[
            None, :
        ]

    with np.errstate(divide="ignore", invalid="ignore"):
        den = lin(nc)
        t = np.float32(n @ (bb.foot - c)) / den
        a = np.float32(right @ (c - bb.foot)) + t * lin(rc) + np.float32(bb.width / 2)
        z = np.float32(up @ (c - bb.foot)) + t * lin(uc)
    # choose the sprite resolution from the texel footprint at the billboard's distance
    h0 = bb.rgba[0].shape[0]
    tpm = h0 / bb.height
    dist = float(np.linalg.norm(bb.foot + up * bb.height / 2 - c))
    lv = int(np.clip(np.floor(np.log2(max(tpm * dist / cam.f, 1e-6) + 1e-9)), 0, len(bb.rgba) - 1))
    s = 0.5**lv
    mx = (a * np.float32(tpm) + 0.5) * s - 0.5
    my = ((np.float32(bb.height) - z) * np.float32(tpm) + 0.5) * s - 0.5
    mx = np.where(t > NEAR, mx, -10).astype(np.float32)
    smp = cv2.remap(
        bb.rgba[lv],
        mx,
        my.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    alpha = smp[..., 3].astype(np.float32) / 255.0
    if not np.any(alpha > 0.02):
        return
    bulge = cv2.remap(
        bb.bulge[lv],
        mx,
        my.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    tsurf = t - bulge * np.float32(abs(nc[2]))
    zsub = buf.z[r0:r1, c0:c1]
    vis = (alpha > 0.02) & (tsurf < zsub) & (t > NEAR)
    al = np.where(vis, alpha, 0.0)[..., None]
    sub = rgb[r0:r1, c0:c1]
    mixed = sub.astype(np.float32) * (1.0 - al) + smp[..., :3].astype(np.float32) * al
    sub[...] = (mixed + np.float32(0.5)).astype(np.uint8)
    solid = vis & (alpha >= 0.5)
    zsub[solid] = tsurf[solid]
    buf.label[r0:r1, c0:c1][solid] = bb.label
    buf.cos[r0:r1, c0:c1][solid] = 1.0
