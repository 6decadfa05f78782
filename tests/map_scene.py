"""An analytic scene for the map builders' tests: exact depth, colour and labels by ray casting.

World frame z up. A floor z = 0 (class "floor"), a wall y = WALL_Y (class "wall") and, when
asked, a flat "person" PERSON_BOUNDS at y = PERSON_Y, all seen by a small pinhole camera pitched
down towards the wall. Label ids are backend-style (synthetic 100 + NYU id, VOC's 15 for the
person) with their names, as a segmenter would give them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.core.protocols import KeyframeSnapshot
from semslam.core.types import LabelMap
from semslam.geometry.camera import PinholeCamera

WALL_Y = 3.0
PERSON_Y = 1.5
PERSON_BOUNDS = ((-0.3, 0.3), (0.3, 1.5))  # x range, z range of the person rectangle
NAMES = {0: "background", 101: "wall", 102: "floor", 15: "person"}
WALL_ID, FLOOR_ID, PERSON_ID = 101, 102, 15
RGB = {WALL_ID: (30, 30, 200), FLOOR_ID: (200, 30, 30), PERSON_ID: (30, 200, 30)}


def camera(width: int = 160, height: int = 120, f: float = 130.0) -> PinholeCamera:
    return PinholeCamera(f, f, (width - 1) / 2, (height - 1) / 2, width=width, height=height)


def pose(x: float = 0.0, y: float = 0.0, yaw_deg: float = 0.0, height: float = 1.2, pitch_deg: float = 20.0
         ) -> NDArray[np.float64]:
    """T_wc of a camera at (x, y, height) looking along +y, turned by yaw (about z), pitched down."""
    p, q = np.radians(pitch_deg), np.radians(yaw_deg)
    x_c = np.array([1.0, 0.0, 0.0])
    z_c = np.array([0.0, np.cos(p), -np.sin(p)])
    y_c = np.cross(z_c, x_c)
    yaw = np.array([[np.cos(q), -np.sin(q), 0.0], [np.sin(q), np.cos(q), 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = yaw @ np.stack([x_c, y_c, z_c], axis=1)
    T[:3, 3] = [x, y, height]
    return T


def render(cam: PinholeCamera, T_wc: NDArray[np.float64], person: bool = True
           ) -> tuple[NDArray[np.float32], NDArray[np.uint8], NDArray[np.uint8]]:
    """Exact z-depth (NaN where no surface), RGB and label ids of the scene."""
    h, w = cam.height, cam.width
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    d_c = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)  # z = 1
    d = d_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
        t_wall = np.where(d[..., 1] > 0, (WALL_Y - o[1]) / d[..., 1], np.inf)
        t_person = np.where(d[..., 1] > 0, (PERSON_Y - o[1]) / d[..., 1], np.inf)
    p_floor = o + t_floor[..., None] * d
    p_wall = o + t_wall[..., None] * d
    p_person = o + t_person[..., None] * d
    t_floor = np.where(p_floor[..., 1] <= WALL_Y, t_floor, np.inf)
    t_wall = np.where(p_wall[..., 2] >= 0, t_wall, np.inf)
    (x0, x1), (z0, z1) = PERSON_BOUNDS
    on_person = (p_person[..., 0] >= x0) & (p_person[..., 0] <= x1) & (p_person[..., 2] >= z0) & (p_person[..., 2] <= z1)
    t_person = np.where(on_person & person & (t_person > 0), t_person, np.inf)
    ts = np.stack([t_wall, t_floor, t_person])
    which = np.argmin(ts, axis=0)
    depth = np.min(ts, axis=0)
    labels = np.array([WALL_ID, FLOOR_ID, PERSON_ID], np.uint8)[which]
    labels[~np.isfinite(depth)] = 0
    rgb = np.zeros((h, w, 3), np.uint8)
    for lid, colour in RGB.items():
        rgb[labels == lid] = colour
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32), rgb, labels


def snapshot(kf_id: int, T_wc: NDArray[np.float64], cam: PinholeCamera | None = None, person: bool = True,
             mask_person: bool = True, with_labels: bool = True) -> KeyframeSnapshot:
    """A keyframe snapshot of the scene; the person's pixels are ``dynamic`` when ``mask_person``."""
    cam = cam or camera()
    depth, rgb, labels = render(cam, T_wc, person)
    dynamic = (labels == PERSON_ID) if mask_person else np.zeros(labels.shape, bool)
    lm = LabelMap(labels, dict(NAMES)) if with_labels else None
    return KeyframeSnapshot(kf_id, float(kf_id), T_wc, rgb, depth, dynamic, lm, cam)


def poses() -> list[NDArray[np.float64]]:
    """A few keyframes looking at the wall from slightly different places."""
    return [pose(0.0, 0.0), pose(-0.3, 0.2, yaw_deg=8.0), pose(0.3, 0.3, yaw_deg=-8.0), pose(0.0, -0.2, pitch_deg=30.0)]


def nearest_surface(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Distance of world points to the nearer of floor and wall, and that surface's NYU id
    (floor 2, wall 1), i.e. the global class index the maps should give them."""
    d_floor = np.abs(points[:, 2])
    d_wall = np.abs(points[:, 1] - WALL_Y)
    return np.minimum(d_floor, d_wall), np.where(d_floor < d_wall, 2, 1)
