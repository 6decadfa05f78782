"""One atlas map moved by a similarity about its origin, ``x' = s R x``: rotated so gravity
points down its z axis and, for a monocular map, scaled to metres, as ORB-SLAM3's
``Map::ApplyScaledRotation`` after its inertial initialisation and refinements.

The keyframes' poses, the points, their normals and matching distance ranges move with it;
everything measured in pixels is unchanged (a keyframe sees its points where it saw them,
at ``s`` times their camera-frame coordinates). A local BA in flight was computed in the old
frame, so the map's generation moves on and its result is discarded (as after a merge). The
caller holds the map lock and moves what it keeps relative to the keyframes: tracking's
frame records (``rescale_frame_records``, also what a monocular loop's Sim(3) correction
scales per keyframe), the last frame, the motion model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from semslam.slam.orb.map import KeyFrame, Map, good_point_rows

Array = NDArray[np.float64]


def scaled_translation(T: np.ndarray, scale: float) -> Array:
    """``T`` (a rigid transform, either direction) with its translation scaled."""
    out = np.array(T, dtype=np.float64, copy=True)
    out[:3, 3] *= scale
    return out


def aligned_pose(T_cw: np.ndarray, rotation: Array, scale: float) -> Array:
    """A camera's ``T_cw`` in the map moved by ``x' = scale * rotation @ x``."""
    out = scaled_translation(T_cw, scale)
    out[:3, :3] = out[:3, :3] @ rotation.T
    return out


def gravity_rotation(gravity: Array) -> Array:
    """The smallest rotation that turns ``gravity``'s direction onto -z (ORB-SLAM3's ``Rwg``,
    inverted): the map's yaw, which gravity does not show, is kept."""
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(g, down)
    s, c = float(np.linalg.norm(axis)), float(g @ down)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # already down / upside down
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def align_map(slam_map: Map, map_id: int, rotation: Array, scale: float) -> list[KeyFrame]:
    """Move atlas map ``map_id`` (its keyframes and their points) by ``x' = scale * rotation
    @ x``; returns its keyframes. Call with ``slam_map.lock`` held."""
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"a map's scale must be positive and finite, got {scale}")
    R = np.asarray(rotation, dtype=np.float64)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("a map's rotation must be a 3x3 rotation matrix")
    slam_map.generation += 1
    kfs = [k for k in slam_map.keyframes.values() if k.map_id == map_id]
    for k in kfs:
        k.set_pose(aligned_pose(k.T_cw, R, scale))
    store = slam_map.store
    rows = good_point_rows(store, kfs)
    store.pos[rows] = scale * store.pos[rows] @ R.T
    store.normal[rows] = store.normal[rows] @ R.T
    store.min_dist[rows] *= scale
    store.max_dist[rows] *= scale
    return kfs


def rescale_frame_records(records: list[tuple[float, KeyFrame, NDArray[np.float64]]],
                          factors: dict[KeyFrame, float]) -> int:
    """Tracked frames' poses relative to their reference keyframe (``T_c_ref``, tracking's
    ``trajectory_refs``) after a Sim(3) correction scaled the map around that keyframe by
    ``factors[kf]``: their translations (and the ``T_cp`` of culled keyframes between a record
    and its live keyframe) scale with it, so the frames keep their place in the corrected map
    (ORB-SLAM keeps the rigid relative poses, which then sit off by the scale change times the
    distance to the keyframe). A rotation of the whole map leaves them as they are. Returns
    the records changed."""
    scaled: set[int] = set()
    n = 0
    for i in range(len(records)):  # tracking may append meanwhile: the entries so far
        t, ref, T = records[i]
        chain, k = [], ref
        while k.bad and k.parent is not None and k.T_cp is not None:
            chain.append(k)
            k = k.parent
        f = factors.get(k)
        if f is None or f == 1.0:
            continue
        records[i] = (t, ref, scaled_translation(T, f))
        n += 1
        for c in chain:
            if c.id not in scaled and c.T_cp is not None:
                scaled.add(c.id)
                c.T_cp = scaled_translation(c.T_cp, f)
    return n
