"""A random map for the map-structure tests: keyframes with random keypoints and
descriptors, points observed by a random subset of them."""

from __future__ import annotations

import numpy as np

from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints
from semslam.geometry.se3 import invert
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.point_store import MapPoint


def random_map(rng: np.random.Generator, spec: FeatureSpec, n_kf: int = 12, n_kp: int = 60,
               n_pts: int = 150, max_obs: int = 9) -> tuple[Map, list[KeyFrame], list[MapPoint]]:
    """Keyframes with random descriptors of ``spec``'s kind; points observed by 0..max_obs
    of them (at random keypoints)."""
    m = Map(spec)
    kfs = []
    for k in range(n_kf):
        T = np.eye(4)
        T[:3, 3] = rng.normal(0, 1.0, 3)
        if spec.kind is DescriptorKind.BINARY:
            desc = rng.integers(0, 256, (n_kp, 32), dtype=np.uint8)
        else:
            desc = rng.normal(size=(n_kp, 128)).astype(np.float32)
        kps = Keypoints(rng.uniform(0, 640, (n_kp, 2)).astype(np.float32),
                        rng.integers(0, 8, n_kp).astype(np.int32), np.ones(n_kp, np.float32),
                        np.zeros(n_kp, np.float32), desc)
        kf = KeyFrame(m.new_kf_id(), k, float(k), invert(T), kps, kps.xy.astype(np.float64),
                      np.ones(n_kp, np.float32), -np.ones(n_kp), [None] * n_kp)
        m.add_keyframe(kf)
        kfs.append(kf)
    points = []
    for _ in range(n_pts):
        ref = kfs[int(rng.integers(n_kf))]
        p = m.new_point(rng.normal(0, 3.0, 3), ref.keypoints.descriptors[0].copy(), ref)
        n_obs = int(rng.integers(0, max_obs + 1))
        for kf in rng.choice(kfs, n_obs, replace=False):
            p.add_observation(kf, int(rng.integers(n_kp)))
        points.append(p)
    return m, kfs, points
