"""Pinhole projection of many points at once (tracking, fusion, loop closing, Sim(3) RANSAC)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def project(T_cw: NDArray[np.float64], pts_w: NDArray[np.float64], fx: float, fy: float, cx: float, cy: float
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel positions and depths of world points seen from ``T_cw``."""
    pc = pts_w @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
    uv = np.stack([fx * pc[:, 0] / zs + cx, fy * pc[:, 1] / zs + cy], axis=1)
    return uv, z
