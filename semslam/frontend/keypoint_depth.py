"""Depth at keypoints: what an RGB-D frame's keypoints carry into tracking."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def sample_depth(depth: NDArray[np.float32], xy: NDArray[np.floating]) -> NDArray[np.float32]:
    """Depth at the nearest pixel of each keypoint (0 outside the image)."""
    h, w = depth.shape
    u = np.rint(xy[:, 0]).astype(np.intp)
    v = np.rint(xy[:, 1]).astype(np.intp)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros(len(xy), np.float32)
    out[inside] = depth[v[inside], u[inside]]
    return out
