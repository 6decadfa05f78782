"""DDL-SLAM's background inpainting (III-E): each keyframe's dynamic pixels are filled with
the static background the last ``cfg.keyframes`` keyframes observed, warped into it
(``forward_warp``). What no keyframe saw stays unknown, or, with ``cfg.hole_fill_px`` > 0,
small holes are filled by image inpainting (the "more elaborate inpainting" the paper leaves
to future work) and marked synthesised, so maps and users can tell observed from invented.

The history keeps each keyframe's *observed* static pixels only, never its filled ones:
filled pixels add no observation, they copy older keyframes' data with the poses known at
that time. Feeding them back would carry a wrong fill (a pose error, a mislabelled source
pixel) forward from keyframe to keyframe, keep data alive beyond the 15-keyframe window, and
stay misplaced after a loop closure corrects the poses of the keyframes they came from.

A mover the masks missed in one keyframe is "static" there and would be pasted into later
keyframes' backgrounds (the z-buffer only asks that a fill lie behind what the target sees).
With ``cfg.reject_seen_through`` a filled point that another remembered keyframe saw through
(``forward_warp.seen_through``) stays unknown: background stops rays, a transient does not.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from semslam.config import InpaintingConfig
from semslam.core.protocols import KeyframeSnapshot
from semslam.core.types import LabelMap
from semslam.errors import DataError
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.reconstruction.forward_warp import (
    BoolImage,
    SourcePoints,
    make_source,
    pixel_rays,
    project_to_image,
    seen_through,
    tolerance,
    valid_depth,
    warm_up,
    warp_static,
)

#: TUM depth PNG units per metre.
TUM_DEPTH_SCALE = 5000.0
#: Values of the mask PNG ``write_inpainted`` writes.
MASK_OBSERVED, MASK_FILLED, MASK_SYNTHESIZED, MASK_UNKNOWN = 0, 1, 2, 3


@dataclass
class InpaintResult:
    """One image after inpainting. ``dynamic`` is what stays unknown (the maps exclude it),
    as in ``KeyframeSnapshot``; ``seen`` = dynamic pixels some source pixel landed on."""

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None
    labels: LabelMap | None
    filled: BoolImage
    synthesized: BoolImage
    dynamic: BoolImage
    seen: BoolImage


# ---------------------------------------------------------------------------- second stage
def small_holes(holes: BoolImage, max_radius_px: int) -> BoolImage:
    """The connected holes (8-connected) whose inscribed radius, the largest distance from a
    hole pixel to the nearest non-hole pixel (distance transform), is at most
    ``max_radius_px``: a strip w pixels wide has radius ceil(w / 2), so r = 2 fills strips up
    to 3 px, r = 3 up to 5 px. Larger holes are left whole, not nibbled at their rims."""
    if max_radius_px <= 0 or not holes.any():
        return np.zeros_like(holes)
    mask = holes.astype(np.uint8)
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    n, comp = cv2.connectedComponents(mask, connectivity=8)
    widest = np.zeros(n, np.float32)
    np.maximum.at(widest, comp.ravel(), dist.ravel())
    ok = widest <= max_radius_px + 0.5
    ok[0] = False
    return ok[comp]


def fill_small_holes(rgb: NDArray[np.uint8], depth: NDArray[np.float32] | None, labels: NDArray[np.uint8] | None,
                     holes: BoolImage, max_radius_px: int
                     ) -> tuple[NDArray[np.uint8], NDArray[np.float32] | None, NDArray[np.uint8] | None, BoolImage]:
    """Second stage: fill the holes no wider than ``max_radius_px`` (``small_holes``); returns
    new rgb, depth, labels and the synthesised mask.

    Each small hole is filled in a window around it, so only real observations are used
    as samples: RGB by OpenCV's Telea inpainting with every hole pixel in the window masked
    (a neighbouring big hole still holds the moving object's colour); depth by OpenCV's
    Navier-Stokes inpainting with every pixel without depth masked (so none is read as a
    0-m sample). Telea's float path is broken in OpenCV 4.11 (it returns values metres off
    on a plane), and the nearest boundary depth makes steps: on a slanted plane (6 mm/px),
    NS is within 2-7 mm over 3-7 px wide holes where the nearest depth is 18 mm off at 5 px.
    Labels: the nearest known label (ids cannot be averaged).

    Synthesised pixels are guesses, far less accurate than filled ones (a noisy synthetic
    sequence, radius 3: RGB error 12-37 and depth median 20-100 mm, where keyframe fills
    have 4-5 and 3-13 mm): most holes left after warping sit at depth edges, where the
    boundary mixes two surfaces. Sampling only the farther side of such a hole was tried
    and was worse on both. Hence their own mask, ``synthesized``.
    """
    synth = small_holes(holes, max_radius_px)
    if not synth.any():
        return rgb, depth, labels, synth
    radius = max(3, int(max_radius_px))
    pad = 2 * radius + 2
    rgb = rgb.copy()
    depth = None if depth is None else depth.copy()
    labels = None if labels is None else labels.copy()
    known_depth = None if depth is None else valid_depth(depth) & ~holes
    h, w = holes.shape
    n, comp, boxes, _ = cv2.connectedComponentsWithStats(synth.astype(np.uint8), connectivity=8)
    for k in range(1, n):
        x, y, bw, bh = boxes[k, :4]
        win = np.s_[max(0, y - pad):min(h, y + bh + pad), max(0, x - pad):min(w, x + bw + pad)]
        target = comp[win] == k
        hole_win = holes[win]
        rgb[win][target] = cv2.inpaint(rgb[win], hole_win.astype(np.uint8), radius, cv2.INPAINT_TELEA)[target]
        if depth is not None and known_depth is not None:
            known = known_depth[win]
            if known.any():
                d = np.where(known, depth[win], np.float32(0)).astype(np.float32)
                depth[win][target] = cv2.inpaint(d, (~known).astype(np.uint8), radius, cv2.INPAINT_NS)[target]
            else:
                depth[win][target] = 0.0
        if labels is not None:
            iy, ix = ndimage.distance_transform_edt(hole_win, return_distances=False, return_indices=True)
            labels[win][target] = labels[win][iy[target], ix[target]]
    return rgb, depth, labels, synth


# ---------------------------------------------------------------------------- one image
def inpaint_image(camera: PinholeCamera, T_wc: NDArray[np.float64], rgb: NDArray[np.uint8],
                  depth: NDArray[np.float32] | None, dynamic: BoolImage, sources: Sequence[SourcePoints],
                  cfg: InpaintingConfig, labels: LabelMap | None = None, splat: str = "point",
                  fill_cracks: bool = True) -> InpaintResult:
    """Fill ``dynamic`` from ``sources`` (first stage), then small holes (second stage)."""
    warp = warp_static(camera, T_wc, depth, dynamic, sources, cfg.depth_tolerance_m, splat, fill_cracks)
    filled = warp.filled & dynamic
    if cfg.reject_seen_through and filled.any():
        filled &= ~seen_through(camera, T_wc, np.where(filled, warp.depth, 0).astype(np.float32), filled, sources,
                                cfg.depth_tolerance_m)
    out_rgb = rgb.copy()
    out_rgb[filled] = warp.rgb[filled]
    out_depth = None
    if depth is not None:
        out_depth = depth.astype(np.float32, copy=True)
        out_depth[dynamic] = 0.0  # the moving object's depth is not background
        out_depth[filled] = warp.depth[filled]
    out_labels = labels.labels.copy() if labels is not None else None
    out_conf = None if labels is None or labels.confidence is None else labels.confidence.copy()
    if out_labels is not None:
        # Sources without labels give 0 (VOC "background", NYU "unlabelled"), never the mover's id.
        out_labels[filled] = 0 if warp.labels is None else warp.labels[filled]
        if out_conf is not None:
            out_conf[filled] = np.nan if warp.confidence is None else warp.confidence[filled]
    holes = dynamic & ~filled
    out_rgb, out_depth, out_labels, synth = fill_small_holes(out_rgb, out_depth, out_labels, holes,
                                                             cfg.hole_fill_px)
    if out_conf is not None:
        out_conf[synth] = np.nan
    label_map = None
    if labels is not None and out_labels is not None:
        label_map = LabelMap(labels=out_labels, names=labels.names, confidence=out_conf)
    return InpaintResult(rgb=out_rgb, depth=out_depth, labels=label_map, filled=filled, synthesized=synth,
                         dynamic=holes & ~synth, seen=warp.seen & dynamic)


# ---------------------------------------------------------------------------- stateful
class BackgroundInpainter:
    """Keeps the last ``cfg.keyframes`` keyframes' observed static data and fills new images
    from it. ``inpaint`` fills a keyframe and then adds it to the history; ``fill_pixels``
    fills any frame without adding it. Thread-safe: ``correct_poses`` (loop closing) may run
    while another thread fills; a fill uses the poses known when it started.
    """

    def __init__(self, cfg: InpaintingConfig | None = None, splat: str = "point", fill_cracks: bool = True) -> None:
        self.cfg = cfg or InpaintingConfig()
        self.splat = splat
        self.fill_cracks = fill_cracks
        self._history: deque[tuple[int, SourcePoints]] = deque(maxlen=max(1, self.cfg.keyframes))
        self._lock = threading.Lock()
        warm_up()  # the splat kernel: ~0.2 s from numba's cache, once per process

    def __len__(self) -> int:
        return len(self._history)

    def sources(self) -> list[SourcePoints]:
        """The history, oldest first (a copy; the points themselves are shared, read-only)."""
        with self._lock:
            return [src for _, src in self._history]

    def keyframe_ids(self) -> list[int]:
        with self._lock:
            return [kf for kf, _ in self._history]

    def add(self, snapshot: KeyframeSnapshot) -> None:
        """Remember a keyframe's observed static pixels (not dynamic, with depth)."""
        if snapshot.depth is None:
            return
        static = np.ones(snapshot.depth.shape, bool) if snapshot.dynamic is None else ~snapshot.dynamic
        labels = snapshot.labels
        src = make_source(snapshot.T_wc, snapshot.rgb, snapshot.depth, static, snapshot.camera,
                          None if labels is None else labels.labels, None if labels is None else labels.confidence)
        with self._lock:
            self._history.append((snapshot.keyframe_id, src))

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None:
        """New poses for remembered keyframes (after loop closing or BA); others are ignored."""
        with self._lock:
            self._history = deque(
                ((kf, replace(src, T_wc=np.array(poses_wc[kf], np.float64)) if kf in poses_wc else src)
                 for kf, src in self._history), maxlen=self._history.maxlen)

    def fill_pixels(self, rgb: NDArray[np.uint8], depth: NDArray[np.float32] | None, dynamic: BoolImage,
                    T_wc: NDArray[np.float64], camera: PinholeCamera, labels: LabelMap | None = None) -> InpaintResult:
        """Fill one image's dynamic pixels from the history, without adding it."""
        return inpaint_image(camera, T_wc, rgb, depth, dynamic, self.sources(), self.cfg, labels,
                             self.splat, self.fill_cracks)

    def inpaint(self, snapshot: KeyframeSnapshot, remember: bool = True) -> KeyframeSnapshot:
        """A new snapshot with the dynamic pixels filled (``filled``, ``synthesized``;
        ``dynamic`` = what stays unknown); then the keyframe joins the history (unless
        ``remember`` is false: a frame that is not a keyframe, ``--save-inpainted``)."""
        out = snapshot
        if self.cfg.enabled and snapshot.dynamic is not None and snapshot.dynamic.any():
            res = self.fill_pixels(snapshot.rgb, snapshot.depth, snapshot.dynamic, snapshot.T_wc, snapshot.camera,
                                   snapshot.labels)
            out = replace(snapshot, rgb=res.rgb, depth=res.depth, labels=res.labels, filled=res.filled,
                          synthesized=res.synthesized, dynamic=res.dynamic)
        if self.cfg.enabled and remember:
            self.add(snapshot)
        return out


# ---------------------------------------------------------------------------- evaluation
def seen_by_sources(camera: PinholeCamera, T_wc: NDArray[np.float64], true_depth: NDArray[np.float32],
                    dynamic: BoolImage, sources: Sequence[SourcePoints], depth_tolerance_m: float) -> BoolImage:
    """Target dynamic pixels whose true background (``true_depth``, the scene without the
    moving object) some source observed: the point projects inside the source image onto one
    of its observed static pixels whose depth agrees within the tolerance (not occluded there,
    not in its dynamic mask). The honest denominator of "how much could have been filled"."""
    h, w = dynamic.shape
    flat = np.flatnonzero(dynamic & valid_depth(true_depth))
    z = true_depth.ravel()[flat].astype(np.float32)
    rays = pixel_rays(camera, h, w)[flat]
    pts_c = np.stack([rays[:, 0] * z, rays[:, 1] * z, z], axis=1)
    pts_w = (pts_c @ T_wc[:3, :3].T + T_wc[:3, 3]).astype(np.float32)
    seen = np.zeros(h * w, bool)
    for src in sources:
        sh, sw = src.shape
        rows, u, v, zz = project_to_image(src.camera, pts_w, sh, sw, invert(src.T_wc))
        obs = src.static_depth().ravel()[(v + np.float32(0.5)).astype(np.int64) * sw + (u + np.float32(0.5)).astype(np.int64)]
        ok = (obs > 0) & (np.abs(zz - obs) <= tolerance(obs, depth_tolerance_m))
        seen[flat[rows[ok]]] = True
    return seen.reshape(h, w)


class _Filled(Protocol):
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None
    filled: BoolImage | None
    synthesized: BoolImage | None
    dynamic: BoolImage | None


def fill_stats(result: _Filled, true_rgb: NDArray[np.uint8] | None = None,
               true_depth: NDArray[np.float32] | None = None, seen_mask: BoolImage | None = None) -> dict[str, float]:
    """Shares of the dynamic pixels filled / synthesised / left unknown, the share of the
    *seen* ones filled (``seen_mask``, else the result's own ``seen`` where it has one), and
    errors against the true background (RGB mean abs over channels; depth median and mean
    abs, metres) on filled and on synthesised pixels. Works on an ``InpaintResult`` and on an
    inpainted ``KeyframeSnapshot``; NaN where a number is undefined."""
    unknown = result.dynamic if result.dynamic is not None else np.zeros(result.rgb.shape[:2], bool)
    filled = result.filled if result.filled is not None else np.zeros_like(unknown)
    synth = result.synthesized if result.synthesized is not None else np.zeros_like(unknown)
    dyn = unknown | filled | synth
    n = int(dyn.sum())

    def share(a: BoolImage, of: BoolImage) -> float:
        d = int((of & dyn).sum())
        return float((a & of & dyn).sum()) / d if d else float("nan")

    stats = {"dynamic_px": float(n), "filled_share": share(filled, dyn), "synthesized_share": share(synth, dyn),
             "unknown_share": share(unknown, dyn)}
    seen = seen_mask if seen_mask is not None else getattr(result, "seen", None)
    if seen is not None:
        stats["seen_px"] = float((seen & dyn).sum())
        stats["seen_filled_share"] = share(filled, seen)
    for name, mask in (("filled", filled), ("synthesized", synth)):
        if true_rgb is not None:
            err = np.abs(result.rgb[mask].astype(np.float32) - true_rgb[mask].astype(np.float32))
            stats[f"{name}_rgb_mae"] = float(err.mean()) if err.size else float("nan")
        if true_depth is not None and result.depth is not None:
            m = mask & valid_depth(true_depth) & valid_depth(result.depth)
            err = np.abs(result.depth[m].astype(np.float64) - true_depth[m])
            stats[f"{name}_depth_median_abs_m"] = float(np.median(err)) if err.size else float("nan")
            stats[f"{name}_depth_mean_abs_m"] = float(err.mean()) if err.size else float("nan")
    return stats


# ---------------------------------------------------------------------------- output
def inpaint_mask(snapshot: _Filled) -> NDArray[np.uint8]:
    """0 = observed static, 1 = filled from keyframes, 2 = synthesised, 3 = unknown."""
    mask = np.zeros(snapshot.rgb.shape[:2], np.uint8)
    for value, m in ((MASK_FILLED, snapshot.filled), (MASK_SYNTHESIZED, snapshot.synthesized),
                     (MASK_UNKNOWN, snapshot.dynamic)):
        if m is not None:
            mask[m] = value
    return mask


def write_inpainted(out_dir: Path, stamp: str | float, snapshot: _Filled) -> dict[str, Path]:
    """Write ``rgb/<stamp>.png``, ``depth/<stamp>.png`` (TUM 16-bit, 5000 per metre) and
    ``mask/<stamp>.png`` (``inpaint_mask`` values) so a user sees what was filled."""
    name = f"{stamp:.6f}" if isinstance(stamp, float) else str(stamp)
    images: dict[str, NDArray] = {"rgb": cv2.cvtColor(snapshot.rgb, cv2.COLOR_RGB2BGR), "mask": inpaint_mask(snapshot)}
    if snapshot.depth is not None:
        d = np.where(valid_depth(snapshot.depth), snapshot.depth, 0.0) * TUM_DEPTH_SCALE
        images["depth"] = np.clip(np.rint(d), 0, 65535).astype(np.uint16)
    paths: dict[str, Path] = {}
    for kind, img in images.items():
        path = Path(out_dir) / kind / f"{name}.png"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataError(path.parent, f"cannot create the folder ({exc.strerror})") from None
        if not cv2.imwrite(str(path), img):
            raise DataError(path, "cannot write the image")
        paths[kind] = path
    return paths
