"""Forward warping of static background from source views into a target view (DDL-SLAM
III-E): back-project each source's observed static pixels with their depth, move them into
the target camera, project them, and keep per target pixel the nearest surface (a z-buffer).

Pure functions of arrays. Images are the raw (possibly distorted) camera images, as the
snapshots carry them: back-projection undistorts the source pixels with the camera's own
``undistort_points`` and projection re-applies the target's distortion (OpenCV's
``projectPoints``), so fr1/fr2's distorted images warp correctly.

Only source points that can land on the target's dynamic pixels are projected: points are
grouped by image tile with a 3D box per tile, and a tile is skipped when its box projects
away from the dynamic pixels (``DynamicCover``). ``warp_static`` runs the per-point work in
a compiled kernel (``splat_kernel``); ``warp_static_numpy`` is the numpy reference. With 15
sources at 640x480 (a loaded 2-core machine, CPU time): a person on 13 % of the image 34 ms
(numpy 75 ms), two people on 39 % 87 ms (numpy 156 ms).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.reconstruction import splat_kernel

BoolImage = NDArray[np.bool_]

#: Points closer than this to the target camera are not projected (behind or on the lens).
MIN_Z_M = 0.05
#: Side of the image tiles source points are grouped by for culling (pixels).
TILE_PX = 16
#: Cell of the coarse grid of the target's dynamic pixels tiles are culled against (pixels).
COVER_CELL_PX = 4
#: The depth-consistency tolerance grows by this share of the depth (Kinect noise grows with it).
REL_TOLERANCE = 0.02


def tolerance(depth: NDArray[np.floating], depth_tolerance_m: float) -> NDArray[np.floating]:
    """Depth difference (metres) still counted as the same surface at ``depth``."""
    return depth_tolerance_m + REL_TOLERANCE * depth


@dataclass(frozen=True)
class SourcePoints:
    """The observed static pixels of one source view, back-projected once into its camera
    frame, so a pose correction only replaces ``T_wc`` (``dataclasses.replace``).

    Points are grouped by ``TILE_PX`` x ``TILE_PX`` image tiles, each with its 3D bounding
    box, so a warp projects only the tiles whose box can land on the target's dynamic
    pixels (``tile_rows``) instead of every point.
    """

    T_wc: NDArray[np.float64]
    camera: PinholeCamera
    shape: tuple[int, int]
    #: Flat pixel index (v * width + u) of every point in the source image.
    flat: NDArray[np.int32]
    pts_c: NDArray[np.float32]
    rgb: NDArray[np.uint8]
    labels: NDArray[np.uint8] | None
    confidence: NDArray[np.float32] | None
    #: Points of non-empty tile k are rows tile_ptr[k]:tile_ptr[k + 1]; their box tile_lo..tile_hi.
    tile_ptr: NDArray[np.int64]
    tile_lo: NDArray[np.float32]
    tile_hi: NDArray[np.float32]
    #: The least observed static depth of each 3x3 window, -inf where the window holds none
    #: (no evidence): what ``seen_through`` compares with.
    nearest_static: NDArray[np.float32]

    def __len__(self) -> int:
        return len(self.flat)

    def static_depth(self) -> NDArray[np.float32]:
        """The source's observed static depth as an image (0 elsewhere)."""
        img = np.zeros(self.shape[0] * self.shape[1], np.float32)
        img[self.flat] = self.pts_c[:, 2]
        return img.reshape(self.shape)

def seen_through(camera: PinholeCamera, T_wc: NDArray[np.float64], depth: NDArray[np.float32],
                 candidates: BoolImage, sources: Sequence[SourcePoints], depth_tolerance_m: float) -> BoolImage:
    """Candidate pixels (with ``depth``) whose 3D point some source saw through: it projects
    into the source in front of the source's observed static depth, the least of a 3x3 window
    (so a point beside a source's depth edge is not condemned), by more than the tolerance.
    A static surface stops every ray that reaches it, so only a transient point - a mover
    some keyframe did not mask - can lie where another keyframe saw farther."""
    h, w = candidates.shape
    flat = np.flatnonzero(candidates & valid_depth(depth))
    out = np.zeros(h * w, bool)
    if not len(flat):
        return out.reshape(h, w)
    z = depth.ravel()[flat].astype(np.float32)
    rays = pixel_rays(camera, h, w)[flat]
    pts_c = np.stack([rays[:, 0] * z, rays[:, 1] * z, z], axis=1)
    pts_w = (pts_c @ T_wc[:3, :3].T + T_wc[:3, 3]).astype(np.float32)
    for src in sources:
        sh, sw = src.shape
        rows, u, v, zz = project_to_image(src.camera, pts_w, sh, sw, invert(src.T_wc))
        near = src.nearest_static.ravel()[
            (v + np.float32(0.5)).astype(np.int64) * sw + (u + np.float32(0.5)).astype(np.int64)]
        out[flat[rows[near > zz + tolerance(zz, depth_tolerance_m)]]] = True  # -inf: nothing seen there
    return out.reshape(h, w)


@lru_cache(maxsize=8)
def pixel_rays(camera: PinholeCamera, height: int, width: int) -> NDArray[np.float32]:
    """Undistorted normalised coordinates ``(x/z, y/z)`` of every raw pixel, ``(H*W, 2)``;
    cached because undistorting a whole image is the slow part of back-projection."""
    v, u = np.mgrid[0:height, 0:width]
    xy = camera.undistort_points(np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64))
    rays = np.empty_like(xy, dtype=np.float32)
    rays[:, 0] = (xy[:, 0] - camera.cx) / camera.fx
    rays[:, 1] = (xy[:, 1] - camera.cy) / camera.fy
    rays.setflags(write=False)
    return rays


@lru_cache(maxsize=4)
def tile_index(height: int, width: int) -> NDArray[np.int16] | NDArray[np.int32]:
    """The ``TILE_PX`` tile of every pixel, row-major; 16-bit where the count allows (numpy's
    stable sort of 16-bit ints is a radix sort)."""
    v, u = np.mgrid[0:height, 0:width]
    tiles_x = -(-width // TILE_PX)
    tile = (v // TILE_PX * tiles_x + u // TILE_PX).ravel()
    tile = tile.astype(np.int16 if tiles_x * -(-height // TILE_PX) < 2**15 else np.int32)
    tile.setflags(write=False)
    return tile


def valid_depth(depth: NDArray[np.floating]) -> BoolImage:
    """Pixels with a measured depth (0 and NaN mean none)."""
    return np.isfinite(depth) & (depth > 0)


def make_source(T_wc: NDArray[np.float64], rgb: NDArray[np.uint8], depth: NDArray[np.float32],
                static: BoolImage, camera: PinholeCamera, labels: NDArray[np.uint8] | None = None,
                confidence: NDArray[np.float32] | None = None) -> SourcePoints:
    """Back-project a view's ``static`` pixels that have depth (its observed static background)."""
    h, w = depth.shape
    flat = np.flatnonzero(static & valid_depth(depth)).astype(np.int32)
    tile = tile_index(h, w)[flat]
    order = np.argsort(tile, kind="stable")
    flat, tile = flat[order], tile[order]
    z = depth.ravel()[flat].astype(np.float32)
    rays = pixel_rays(camera, h, w)[flat]
    pts = np.empty((len(flat), 3), np.float32)
    pts[:, 0] = rays[:, 0] * z
    pts[:, 1] = rays[:, 1] * z
    pts[:, 2] = z
    starts = np.flatnonzero(np.diff(tile.astype(np.int32), prepend=-1))
    lo = np.minimum.reduceat(pts, starts, axis=0) if len(pts) else np.zeros((0, 3), np.float32)
    hi = np.maximum.reduceat(pts, starts, axis=0) if len(pts) else np.zeros((0, 3), np.float32)
    nearest = np.full(h * w, np.inf, np.float32)
    nearest[flat] = z
    nearest = cv2.erode(nearest.reshape(h, w), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    nearest[np.isinf(nearest)] = -np.inf
    return SourcePoints(
        T_wc=np.array(T_wc, np.float64), camera=camera, shape=(h, w), flat=flat, pts_c=pts, nearest_static=nearest,
        rgb=rgb.reshape(-1, 3)[flat], labels=None if labels is None else labels.ravel()[flat],
        confidence=None if confidence is None else confidence.ravel()[flat].astype(np.float32),
        tile_ptr=np.append(starts, len(flat)).astype(np.int64), tile_lo=lo, tile_hi=hi)


@dataclass(frozen=True)
class DynamicCover:
    """Where a target's dynamic pixels are, coarsely, in undistorted normalised coordinates: a
    grid of ``COVER_CELL_PX`` cells holding dynamic pixels, grown by one cell (rounding to a
    pixel, the 2x2 splat), with a summed-area table so a rectangle is tested in O(1)."""

    box: tuple[float, float, float, float]  # x0, x1, y0, y1 of the grid
    cell: tuple[float, float]
    sat: NDArray[np.int32]  # (ny + 1, nx + 1), zero first row and column

    @classmethod
    def of(cls, camera: PinholeCamera, mask: BoolImage) -> DynamicCover:
        h, w = mask.shape
        rays = pixel_rays(camera, h, w)[np.flatnonzero(mask)]
        cx, cy = COVER_CELL_PX / camera.fx, COVER_CELL_PX / camera.fy
        x0, y0 = float(rays[:, 0].min()) - 1.5 * cx, float(rays[:, 1].min()) - 1.5 * cy
        nx = int((rays[:, 0].max() - x0) / cx) + 3
        ny = int((rays[:, 1].max() - y0) / cy) + 3
        grid = np.zeros((ny, nx), np.uint8)
        grid[((rays[:, 1] - y0) / cy).astype(np.intp), ((rays[:, 0] - x0) / cx).astype(np.intp)] = 1
        grid = cv2.dilate(grid, np.ones((3, 3), np.uint8))
        sat = np.zeros((ny + 1, nx + 1), np.int32)
        sat[1:, 1:] = grid.cumsum(0, dtype=np.int32).cumsum(1, dtype=np.int32)
        return cls(box=(x0, x0 + nx * cx, y0, y0 + ny * cy), cell=(cx, cy), sat=sat)

    def meets(self, x_lo: NDArray[np.floating], x_hi: NDArray[np.floating], y_lo: NDArray[np.floating],
              y_hi: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Whether each rectangle holds a covered cell."""
        ny, nx = self.sat.shape[0] - 1, self.sat.shape[1] - 1
        x0, _, y0, _ = self.box
        with np.errstate(invalid="ignore"):
            i0 = np.clip(np.floor((x_lo - x0) / self.cell[0]), 0, nx).astype(np.intp)
            i1 = np.clip(np.floor((x_hi - x0) / self.cell[0]) + 1, 0, nx).astype(np.intp)
            j0 = np.clip(np.floor((y_lo - y0) / self.cell[1]), 0, ny).astype(np.intp)
            j1 = np.clip(np.floor((y_hi - y0) / self.cell[1]) + 1, 0, ny).astype(np.intp)
        s = self.sat
        return (s[j1, i1] - s[j0, i1] - s[j1, i0] + s[j0, i0]) > 0


def tiles_towards(src: SourcePoints, T_ts: NDArray[np.float64], cover: DynamicCover) -> NDArray[np.int64]:
    """The tiles of ``src`` whose projection into a target camera (``T_ts``: source to target
    frame) can meet the target's dynamic pixels (``cover``). Conservative: a box wholly in
    front of the camera projects inside its corners' projections (a convex set); one that is
    not is kept."""
    if len(src.tile_lo) == 0:
        return np.zeros(0, np.int64)
    lh = (src.tile_lo, src.tile_hi)
    corners = np.stack([np.stack([lh[i][:, 0], lh[j][:, 1], lh[k][:, 2]], axis=1)
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)], axis=1)  # (K, 8, 3)
    q = corners @ T_ts[:3, :3].T.astype(np.float32) + T_ts[:3, 3].astype(np.float32)
    z = q[..., 2]
    front = (z > MIN_Z_M).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[..., 0] / z, q[..., 1] / z
    keep = ~front | cover.meets(x.min(axis=1), x.max(axis=1), y.min(axis=1), y.max(axis=1))
    return np.flatnonzero(keep).astype(np.int64)


def tile_rows(src: SourcePoints, tiles: NDArray[np.int64]) -> NDArray[np.intp]:
    """The rows of ``src``'s points in ``tiles``."""
    keep = np.zeros(len(src.tile_lo), bool)
    keep[tiles] = True
    return np.flatnonzero(np.repeat(keep, np.diff(src.tile_ptr)))


def project_to_image(camera: PinholeCamera, pts_c: NDArray[np.float32], height: int, width: int,
                     T_cs: NDArray[np.float64] | None = None
                     ) -> tuple[NDArray[np.intp], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Raw (distorted) pixel positions of points that land inside the image.

    ``pts_c`` are in the camera frame, or in another frame that ``T_cs`` maps into it (one
    3x4 product with K folded in). Returns (rows of ``pts_c`` kept, u, v, z); points with
    z < ``MIN_Z_M`` are dropped. Inside means u in [-0.5, width - 0.5), so ``u + 0.5``
    truncates to the nearest pixel.
    """
    M = camera.K @ (np.eye(4)[:3] if T_cs is None else np.asarray(T_cs, np.float64)[:3])
    q = pts_c @ M[:, :3].T.astype(np.float32)
    q += M[:, 3].astype(np.float32)
    z = q[:, 2]  # K's last row is (0, 0, 1): the third coordinate is the depth
    with np.errstate(divide="ignore", invalid="ignore"):
        u = q[:, 0] / z
        v = q[:, 1] / z
    # Distortion moves pixels by a few percent at most; cull with a margin, then distort only
    # the survivors (OpenCV's polynomial folds back far outside the field of view).
    mu, mv = (0.15 * width, 0.15 * height) if camera.is_distorted else (0.0, 0.0)
    rows = np.flatnonzero((z > MIN_Z_M) & (u >= -0.5 - mu) & (u < width - 0.5 + mu)
                          & (v >= -0.5 - mv) & (v < height - 0.5 + mv))
    u, v, z = u[rows], v[rows], z[rows]
    if camera.is_distorted and len(rows):
        p = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=1)
        uv, _ = cv2.projectPoints(p.astype(np.float64).reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                  camera.K, camera.dist_coeffs)
        uv = uv.reshape(-1, 2).astype(np.float32)
        inside = (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)
        rows, u, v, z = rows[inside], uv[inside, 0], uv[inside, 1], z[inside]
    return rows, u, v, z


@dataclass
class WarpResult:
    """What the sources say about the target's dynamic pixels: the nearest consistent static
    surface where ``filled``; ``seen`` = some source pixel landed there before the
    depth-consistency test."""

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    labels: NDArray[np.uint8] | None
    confidence: NDArray[np.float32] | None
    filled: BoolImage
    seen: BoolImage


class _Candidates(NamedTuple):
    """Source points that landed on target pixels ``idx`` at depth ``z``, with their data."""

    idx: NDArray[np.int64]
    z: NDArray[np.float32]
    rgb: NDArray[np.uint8]
    labels: NDArray[np.uint8] | None
    confidence: NDArray[np.float32] | None


def _footprint(u: NDArray[np.float32], v: NDArray[np.float32], height: int, width: int, splat: str
               ) -> Iterator[tuple[NDArray[np.int64], NDArray[np.intp] | None]]:
    """Flat target pixels a projection covers: (pixel index, which of the points; None = all).
    ``point``: the nearest pixel (u, v lie in [-0.5, size - 0.5), so + 0.5 truncates to it);
    ``quad``: the 2x2 pixels around it."""
    if splat == "point":
        yield (v + np.float32(0.5)).astype(np.int64) * width + (u + np.float32(0.5)).astype(np.int64), None
    elif splat == "quad":
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
            ui, vi = u0 + du, v0 + dv
            sel = np.flatnonzero((ui >= 0) & (ui < width) & (vi >= 0) & (vi < height))
            yield vi[sel] * width + ui[sel], sel
    else:
        raise ValueError(f"unknown splat footprint {splat!r} (point, quad)")


def warp_static_numpy(camera: PinholeCamera, T_wc: NDArray[np.float64], depth: NDArray[np.float32] | None,
                      dynamic: BoolImage, sources: Sequence[SourcePoints], depth_tolerance_m: float,
                      splat: str = "point", fill_cracks: bool = True, average: bool = True) -> WarpResult:
    """``warp_static`` in numpy, the reference the compiled kernel is tested against (the
    same candidates; pixel rounding may differ where float32 and float64 disagree)."""
    h, w = dynamic.shape
    n_pix = h * w
    dyn_flat = dynamic.ravel()
    obs = None
    if depth is not None:
        obs = np.where(valid_depth(depth), depth, np.float32(0)).astype(np.float32).ravel()
    T_cw = invert(T_wc)
    has_labels = any(s.labels is not None for s in sources)
    has_conf = any(s.confidence is not None for s in sources)
    seen = np.zeros(n_pix, bool)
    parts: list[_Candidates] = []
    if dyn_flat.any():
        cover = DynamicCover.of(camera, dynamic)
        for src in sources:
            T_ts = T_cw @ src.T_wc
            near = tile_rows(src, tiles_towards(src, T_ts, cover))
            rows, u, v, z = project_to_image(camera, src.pts_c[near], h, w, T_ts)
            rows = near[rows]
            for idx, sel in _footprint(u, v, h, w, splat):
                r, zz = (rows, z) if sel is None else (rows[sel], z[sel])
                on_dyn = np.flatnonzero(dyn_flat[idx])
                idx, r, zz = idx[on_dyn], r[on_dyn], zz[on_dyn]
                seen[idx] = True
                if obs is not None:
                    o = obs[idx]
                    ok = np.flatnonzero((o <= 0) | (zz >= o - tolerance(o, depth_tolerance_m)))
                    idx, r, zz = idx[ok], r[ok], zz[ok]
                lab = conf = None
                if has_labels:
                    lab = src.labels[r] if src.labels is not None else np.zeros(len(r), np.uint8)
                if has_conf:
                    conf = src.confidence[r] if src.confidence is not None else np.full(len(r), np.nan, np.float32)
                parts.append(_Candidates(idx, zz, src.rgb[r], lab, conf))
    return _zbuffer(parts, dynamic, obs, depth_tolerance_m, seen, has_labels, has_conf, fill_cracks,
                    average)


def warp_static(camera: PinholeCamera, T_wc: NDArray[np.float64], depth: NDArray[np.float32] | None,
                dynamic: BoolImage, sources: Sequence[SourcePoints], depth_tolerance_m: float,
                splat: str = "point", fill_cracks: bool = True, average: bool = True) -> WarpResult:
    """Fill the target's ``dynamic`` pixels with the nearest static surface the sources saw.

    A candidate that lies in front of what the target itself observes there (its ``depth``,
    the moving object's) by more than the tolerance is rejected before the z-buffer: a static
    surface cannot be in front of a visible person, and such a point (a mislabelled source
    pixel, a pose error) must not hide the true background behind it. ``splat``: ``point``
    rounds each projection to its nearest pixel, ``quad`` covers the 2x2 pixels around it;
    ``fill_cracks`` closes one-pixel gaps between two samples of one surface (see
    ``close_cracks``). ``average``: the candidates of the nearest surface (within the
    tolerance of the nearest candidate) are averaged; the nearest alone would be the most
    negative of several noisy samples, a bias towards the camera that grows with the number
    of sources (synthetic sequence with Kinect-like noise, 13 mm median error per
    observation: nearest 13 -> 30 mm as the history fills, average 3-5 mm).
    """
    if splat not in ("point", "quad"):
        raise ValueError(f"unknown splat footprint {splat!r} (point, quad)")
    h, w = dynamic.shape
    n_pix = h * w
    at = np.flatnonzero(dynamic)  # the buffers below hold the dynamic pixels only
    slot = np.full(n_pix, -1, np.int32)
    slot[at] = np.arange(len(at), dtype=np.int32)
    obs = None
    if depth is not None:
        obs = np.where(valid_depth(depth), depth, np.float32(0)).astype(np.float32).ravel()
    obs_at = np.zeros(len(at), np.float32) if obs is None else obs[at]
    zbuf_at = np.full(len(at), np.inf, np.float32)
    seen_at = np.zeros(len(at), bool)
    win = np.full(len(at), -1, np.int64)
    acc = np.zeros((len(at) if average else 0, 5), np.float32)
    if len(at) and sources:
        cover = DynamicCover.of(camera, dynamic)
        box = np.asarray(cover.box, np.float64)
        T_cw = invert(T_wc)
        todo = []
        for src in sources:
            T_ts = T_cw @ src.T_wc
            todo.append((src, tiles_towards(src, T_ts, cover), np.ascontiguousarray(T_ts)))
        intr = np.array([camera.fx, camera.fy, camera.cx, camera.cy], np.float64)
        listed = []
        for i, (src, tiles, T_ts) in enumerate(todo):
            room = int((src.tile_ptr[tiles + 1] - src.tile_ptr[tiles]).sum()) * (4 if splat == "quad" else 1)
            cand = (np.empty(room, np.int32), np.empty(room, np.float32), np.empty(room, np.int32))
            n = splat_kernel.splat_source(
                src.pts_c, src.tile_ptr, tiles, T_ts, intr, camera.dist_coeffs, box, h, w, splat == "quad", MIN_Z_M,
                slot, obs_at, depth_tolerance_m, REL_TOLERANCE, i, zbuf_at, seen_at, win, *cand)
            listed.append((src, [c[:n] for c in cand]))
        if average:
            for src, cand in listed:
                splat_kernel.accumulate(*cand, src.rgb, zbuf_at, depth_tolerance_m, REL_TOLERANCE, acc)
    has_labels = any(s.labels is not None for s in sources)
    has_conf = any(s.confidence is not None for s in sources)
    zbuf = np.full(n_pix, np.inf, np.float32)
    rgb = np.zeros((n_pix, 3), np.uint8)
    labels = np.zeros(n_pix, np.uint8) if has_labels else None
    conf = np.full(n_pix, np.nan, np.float32) if has_conf else None
    seen = np.zeros(n_pix, bool)
    seen[at] = seen_at
    hit = np.flatnonzero(win >= 0)
    src_of, row_of = win[hit] >> splat_kernel.ROW_BITS, win[hit] & ((1 << splat_kernel.ROW_BITS) - 1)
    for i, src in enumerate(sources):
        mine = src_of == i
        pix, rows = at[hit[mine]], row_of[mine]
        rgb[pix] = src.rgb[rows]
        if labels is not None and src.labels is not None:
            labels[pix] = src.labels[rows]
        if conf is not None and src.confidence is not None:
            conf[pix] = src.confidence[rows]
    zbuf[at] = zbuf_at
    if average and len(hit):
        a = acc[hit]  # count >= 1: the nearest candidate is within the tolerance of itself
        zbuf[at[hit]] = a[:, 1] / a[:, 0]
        rgb[at[hit]] = np.rint(a[:, 2:] / a[:, :1]).astype(np.uint8)
    return _finish(zbuf, rgb, labels, conf, seen, dynamic, obs, depth_tolerance_m, fill_cracks)


def _zbuffer(parts: list[_Candidates], dynamic: BoolImage, obs: NDArray[np.float32] | None, depth_tolerance_m: float,
             seen: BoolImage, has_labels: bool, has_conf: bool, fill_cracks: bool, average: bool) -> WarpResult:
    """Keep per pixel the nearest surface: the candidates within the tolerance of the nearest
    one, averaged (depth, colour) when ``average``; labels from the nearest candidate."""
    h, w = dynamic.shape
    n_pix = h * w
    zbuf = np.full(n_pix, np.inf, np.float32)
    rgb = np.zeros((n_pix, 3), np.uint8)
    labels = np.zeros(n_pix, np.uint8) if has_labels else None
    conf = np.full(n_pix, np.nan, np.float32) if has_conf else None
    if parts:
        idx = np.concatenate([p.idx for p in parts])
        z = np.concatenate([p.z for p in parts])
        colours = np.concatenate([p.rgb for p in parts])
        np.minimum.at(zbuf, idx, z)
        nearest = zbuf[idx]
        win = np.flatnonzero(z == nearest)  # ties have the same depth; any of them will do
        rgb[idx[win]] = colours[win]
        if labels is not None:
            labels[idx[win]] = np.concatenate([p.labels for p in parts])[win]
        if conf is not None:
            conf[idx[win]] = np.concatenate([p.confidence for p in parts])[win]
        if average:
            same = np.flatnonzero(z <= nearest + tolerance(nearest, depth_tolerance_m))
            at = idx[same]
            count = np.bincount(at, minlength=n_pix)
            many = np.flatnonzero(count > 1)
            n = count[many]
            zbuf[many] = (np.bincount(at, weights=z[same], minlength=n_pix)[many] / n).astype(np.float32)
            for c in range(3):
                total = np.bincount(at, weights=colours[same, c], minlength=n_pix)[many]
                rgb[many, c] = np.rint(total / n).astype(np.uint8)
    return _finish(zbuf, rgb, labels, conf, seen, dynamic, obs, depth_tolerance_m, fill_cracks)


def _finish(zbuf: NDArray[np.float32], rgb: NDArray[np.uint8], labels: NDArray[np.uint8] | None,
            conf: NDArray[np.float32] | None, seen: NDArray[np.bool_], dynamic: BoolImage,
            obs: NDArray[np.float32] | None, depth_tolerance_m: float, fill_cracks: bool) -> WarpResult:
    """Flat z-buffer -> images, then the one-pixel cracks closed."""
    h, w = dynamic.shape
    filled = np.isfinite(zbuf).reshape(h, w)
    depth = np.where(filled, zbuf.reshape(h, w), np.float32(0)).astype(np.float32)
    rgb = rgb.reshape(h, w, 3)
    labels = None if labels is None else labels.reshape(h, w)
    conf = None if conf is None else conf.reshape(h, w)
    if fill_cracks:
        close_cracks(depth, rgb, labels, conf, filled, dynamic, None if obs is None else obs.reshape(h, w),
                     depth_tolerance_m)
    return WarpResult(rgb=rgb, depth=depth, labels=labels, confidence=conf, filled=filled, seen=seen.reshape(h, w))


# Opposite neighbour pairs (dv, du): a crack pixel lies between the two samples of a pair.
_PAIRS = ((0, 1), (1, 0), (1, 1), (1, -1))


def close_cracks(depth: NDArray[np.float32], rgb: NDArray[np.uint8], labels: NDArray[np.uint8] | None,
                 confidence: NDArray[np.float32] | None, filled: BoolImage, dynamic: BoolImage,
                 observed: NDArray[np.float32] | None, depth_tolerance_m: float) -> int:
    """Close one-pixel cracks of forward splatting, in place; returns how many were closed.

    A dynamic pixel is a crack when two opposite neighbours (left/right, up/down or a
    diagonal) hold samples of one surface (depths within the tolerance) and the pixel itself
    is empty or farther than that surface (background seen through a gap of a nearer
    surface). It gets the pair's mean depth and colour; the nearest qualifying pair wins.
    Requiring an opposite pair interpolates between samples and never grows a surface past
    its edge. Only dynamic pixels are visited (gathers through a padded flat image).
    """
    h, w = depth.shape
    wp = w + 2
    pad_d = np.pad(np.where(filled, depth, np.float32(0)), 1).ravel()
    cand_v, cand_u = np.nonzero(dynamic)
    p = (cand_v + 1) * wp + cand_u + 1
    best = np.full(len(p), np.inf, np.float32)
    best_off = np.zeros(len(p), np.int64)
    for dv, du in _PAIRS:
        off = dv * wp + du
        a, b = pad_d[p + off], pad_d[p - off]
        mean = np.float32(0.5) * (a + b)
        ok = (a > 0) & (b > 0) & (np.abs(a - b) <= tolerance(mean, depth_tolerance_m)) & (mean < best)
        best[ok] = mean[ok]
        best_off[ok] = off
    here = pad_d[p]
    crack = np.isfinite(best) & ((here <= 0) | (here > best + tolerance(best, depth_tolerance_m)))
    if observed is not None:
        o = observed[cand_v, cand_u]
        crack &= (o <= 0) | (best >= o - tolerance(o, depth_tolerance_m))
    p, off, cv, cu = p[crack], best_off[crack], cand_v[crack], cand_u[crack]
    # Back from padded flat indices to image rows/columns of the two samples.
    (av, au), (bv, bu) = np.divmod(p + off, wp), np.divmod(p - off, wp)
    av, au, bv, bu = av - 1, au - 1, bv - 1, bu - 1
    depth[cv, cu] = best[crack]
    mean_rgb = (rgb[av, au].astype(np.uint16) + rgb[bv, bu] + 1) // 2
    rgb[cv, cu] = mean_rgb.astype(np.uint8)
    if labels is not None:
        labels[cv, cu] = labels[av, au]
    if confidence is not None:
        confidence[cv, cu] = confidence[av, au]
    filled[cv, cu] = True
    return int(crack.sum())


def warm_up() -> None:
    """Compile the splat kernel (or load it from numba's disk cache) on a tiny input, so the
    first keyframe does not pay for it (seconds cold, ~0.2 s from the cache)."""
    cam = PinholeCamera(fx=2.0, fy=2.0, cx=1.5, cy=1.5, width=4, height=4)
    depth = np.ones((4, 4), np.float32)
    everywhere = np.ones((4, 4), bool)
    src = make_source(np.eye(4), np.zeros((4, 4, 3), np.uint8), depth, everywhere, cam)
    warp_static(cam, np.eye(4), depth, everywhere, [src], 0.03)
