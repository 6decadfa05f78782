"""Pinhole camera with optional Brown-Conrady distortion (OpenCV's k1 k2 p1 p2 k3)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of one camera; ``dist`` is all zeros when the images are undistorted."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    source: str = field(default="", compare=False)
    # Image size in pixels; 0 = unknown (then 2 cx + 1 by 2 cy + 1, the centred-principal-point
    # guess). Sequence readers set it from the first image.
    width: int = 0
    height: int = 0

    @property
    def image_size(self) -> tuple[float, float]:
        """(width, height) used for in-image tests."""
        w = self.width if self.width > 0 else 2 * self.cx + 1
        h = self.height if self.height > 0 else 2 * self.cy + 1
        return w, h

    def with_image_size(self, width: int, height: int) -> PinholeCamera:
        return replace(self, width=int(width), height=int(height))

    def in_image(self, uv: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Which (undistorted) pixel positions fall inside the image."""
        w, h = self.image_size
        return (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)

    @property
    def K(self) -> NDArray[np.float64]:  # noqa: N802 - the usual name of the matrix
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> NDArray[np.float64]:
        return np.asarray(self.dist, dtype=np.float64)

    @property
    def is_distorted(self) -> bool:
        return any(abs(d) > 0.0 for d in self.dist)

    def undistort_points(self, xy: NDArray[np.floating]) -> NDArray[np.float64]:
        """Pixel coordinates as an ideal pinhole camera with the same K would see them."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not self.is_distorted or len(xy) == 0:
            return xy.copy()
        und = cv2.undistortPoints(xy.reshape(-1, 1, 2), self.K, self.dist_coeffs, P=self.K)
        return und.reshape(-1, 2)

    def distort_points(self, xy: NDArray[np.floating]) -> NDArray[np.float64]:
        """Raw image pixels of undistorted ones (the inverse of ``undistort_points``)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not self.is_distorted or len(xy) == 0:
            return xy.copy()
        rays = np.stack([(xy[:, 0] - self.cx) / self.fx, (xy[:, 1] - self.cy) / self.fy, np.ones(len(xy))], 1)
        out, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.dist_coeffs)
        return out.reshape(-1, 2)

    def backproject(self, xy: NDArray[np.floating], depth: NDArray[np.floating]) -> NDArray[np.float64]:
        """Camera-frame 3D points from undistorted pixels ``(N, 2)`` and depths ``(N,)``."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        x = (xy[:, 0] - self.cx) / self.fx * z
        y = (xy[:, 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], axis=1)

    def project(self, pts_c: NDArray[np.floating]) -> NDArray[np.float64]:
        """Undistorted pixels ``(N, 2)`` of camera-frame points ``(N, 3)`` (z must be > 0)."""
        p = np.asarray(pts_c, dtype=np.float64).reshape(-1, 3)
        return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)
