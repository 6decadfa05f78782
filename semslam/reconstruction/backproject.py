"""Which pixels of a keyframe snapshot a map may use, and their 3D points in the camera frame.

Every map builder (keyframe cloud, octree, semantic cloud, TSDF mesh) integrates the same
pixels, so the rule lives here once. A pixel is *usable* when

- its depth is finite and in (0, ``max_depth_m``] (Kinect-class noise grows with depth²);
- it is not in ``snapshot.dynamic`` (after background inpainting, ``dynamic`` marks only what
  stays unknown; pixels filled from earlier keyframes are ordinary static pixels);
- it is not in ``snapshot.synthesized`` unless ``include_synthesized``: image-inpainted pixels
  were never observed, so by default no map takes them for geometry.

Usage::

    v, u = usable_pixels(snapshot, stride=4, max_depth_m=4.0)       # full-resolution rows, cols
    sp = static_points(snapshot, stride=4, max_depth_m=4.0)         # StaticPoints, camera frame
    world = sp.points_c @ T_wc[:3, :3].T + T_wc[:3, 3]

``stride`` samples every ``stride``-th row and column (pixel (0, 0) included);
``stride_for_voxel`` picks the stride that puts neighbouring samples about one voxel apart at
the keyframe's median depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.core.protocols import KeyframeSnapshot
from semslam.core.map_classes import class_image, confidence_image
from semslam.geometry.se3 import rotation_angle


@dataclass(frozen=True)
class StaticPoints:
    """The usable pixels of one snapshot as 3D points, row-aligned arrays of length N.

    ``class_ids`` are global class indices (``semslam.core.map_classes``; 0 = unknown,
    also for every pixel when the snapshot has no labels); ``confidence`` is the segmenter's
    score of that label, None when it gives none. ``v``, ``u`` are the full-resolution pixels.
    """

    points_c: NDArray[np.float32]
    rgb: NDArray[np.uint8]
    class_ids: NDArray[np.uint8]
    confidence: NDArray[np.float32] | None
    v: NDArray[np.intp]
    u: NDArray[np.intp]

    def __len__(self) -> int:
        return len(self.points_c)

    def in_world(self, T_wc: NDArray[np.float64]) -> NDArray[np.float64]:
        """The points in the world frame with the pose ``T_wc``, (N, 3) float64."""
        return self.points_c.astype(np.float64) @ T_wc[:3, :3].T + T_wc[:3, 3]


def usable_mask(snapshot: KeyframeSnapshot, stride: int, max_depth_m: float,
                include_synthesized: bool = False) -> NDArray[np.bool_]:
    """Usable pixels of the ``stride``-subsampled image (all False without depth)."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    if snapshot.depth is None:
        h, w = snapshot.rgb.shape[:2]
        return np.zeros(((h + stride - 1) // stride, (w + stride - 1) // stride), bool)
    depth = snapshot.depth[::stride, ::stride]
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(depth) & (depth > 0) & (depth <= max_depth_m)
    if snapshot.dynamic is not None:
        keep &= ~snapshot.dynamic[::stride, ::stride]
    if snapshot.synthesized is not None and not include_synthesized:
        keep &= ~snapshot.synthesized[::stride, ::stride]
    return keep


def usable_pixels(snapshot: KeyframeSnapshot, stride: int, max_depth_m: float,
                  include_synthesized: bool = False) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Full-resolution rows ``v`` and columns ``u`` of the usable pixels on the stride grid."""
    v, u = np.nonzero(usable_mask(snapshot, stride, max_depth_m, include_synthesized))
    return v * stride, u * stride


def static_points(snapshot: KeyframeSnapshot, stride: int, max_depth_m: float,
                  include_synthesized: bool = False) -> StaticPoints:
    """The usable pixels back-projected into the camera frame with their colour and class
    (lens distortion removed as the camera model says)."""
    v, u = usable_pixels(snapshot, stride, max_depth_m, include_synthesized)
    if len(v) == 0:
        return StaticPoints(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8),
                            None, v, u)
    assert snapshot.depth is not None  # usable_pixels finds none without depth
    z = snapshot.depth[v, u].astype(np.float64)
    cam = snapshot.camera
    xy = cam.undistort_points(np.stack([u, v], axis=1).astype(np.float64))
    pts_c = cam.backproject(xy, z).astype(np.float32)
    shape = snapshot.depth.shape
    classes = class_image(snapshot.labels, shape)[v, u]
    conf = confidence_image(snapshot.labels, shape)
    return StaticPoints(pts_c, snapshot.rgb[v, u].copy(), classes, None if conf is None else conf[v, u], v, u)


def stride_for_voxel(snapshot: KeyframeSnapshot, voxel_m: float, max_depth_m: float) -> int:
    """The stride that puts neighbouring samples ~ one voxel apart at the median usable
    depth (a pixel spans z / f metres): denser sampling than that only repeats the same
    voxels, sparser leaves holes. 1 when the snapshot has no usable depth."""
    coarse = usable_mask(snapshot, 8, max_depth_m)
    if snapshot.depth is None or not coarse.any():
        return 1
    z = float(np.median(snapshot.depth[::8, ::8][coarse]))
    f = max(snapshot.camera.fx, snapshot.camera.fy)
    return max(1, int(voxel_m * f / z))


#: A keyframe whose pose moved more than this since a map integrated it makes the map rebuild
#: from the final poses (loop closing and BA move keyframes by far more; noise by far less).
REBUILD_TRANSLATION_M = 1e-3
REBUILD_ROTATION_DEG = 0.05


def pose_moved(T_a: NDArray[np.float64], T_b: NDArray[np.float64], translation_m: float = REBUILD_TRANSLATION_M,
               rotation_deg: float = REBUILD_ROTATION_DEG) -> bool:
    """Whether two poses differ by more than ``translation_m`` or ``rotation_deg``."""
    if np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) > translation_m:
        return True
    return bool(np.degrees(rotation_angle(T_a[:3, :3].T @ T_b[:3, :3])) > rotation_deg)
