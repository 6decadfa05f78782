"""One atlas map scaled about its origin (a monocular map made metric by the IMU's scale
estimate, as ORB-SLAM3's ``Map::ApplyScaledRotation`` after its inertial initialisation).

The keyframes' positions, the points and their matching distance ranges scale by the same
factor; orientations, normals and everything measured in pixels are unchanged. A local BA
in flight was computed at the old scale, so the map's generation moves on and its result
is discarded (as after a merge). The caller holds the map lock and scales what it keeps
relative to the keyframes: tracking's frame records (``rescale_frame_records``, also what a
monocular loop's Sim(3) correction scales per keyframe), the last frame, the motion model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.slam.orb.map import KeyFrame, Map, good_point_rows


def scaled_translation(T: np.ndarray, scale: float) -> np.ndarray:
    """``T`` (a rigid transform, either direction) with its translation scaled."""
    out = np.array(T, dtype=np.float64, copy=True)
    out[:3, 3] *= scale
    return out


def scale_map(slam_map: Map, map_id: int, scale: float) -> list[KeyFrame]:
    """Scale atlas map ``map_id`` (its keyframes and their points) by ``scale`` about its
    origin; returns its keyframes. Call with ``slam_map.lock`` held."""
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"a map's scale must be positive and finite, got {scale}")
    slam_map.generation += 1
    kfs = [k for k in slam_map.keyframes.values() if k.map_id == map_id]
    for k in kfs:
        k.set_pose(scaled_translation(k.T_cw, scale))
    store = slam_map.store
    rows = good_point_rows(store, kfs)
    store.pos[rows] *= scale
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
    distance to the keyframe). Returns the records changed."""
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
