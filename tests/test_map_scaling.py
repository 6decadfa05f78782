"""Scaling one atlas map about its origin (a monocular map made metric by the IMU): every
keyframe sees its points where it saw them before (camera-frame coordinates scale, pixels
do not move), centres and matching distances scale, another map is untouched, and a local
BA computed before is discarded (the map's generation moves on)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.map_world import random_map
from semslam.core.types import orb_spec
from semslam.slam.orb.map_scaling import rescale_frame_records, scale_map


def _camera_coords(kfs, points):  # type: ignore[no-untyped-def]
    return {(k.id, p.id): k.T_cw[:3, :3] @ p.pos + k.T_cw[:3, 3]
            for p in points for k in p.observations if not p.bad}


def test_scaling_a_map_keeps_every_view_and_scales_positions() -> None:
    rng = np.random.default_rng(4)
    spec = orb_spec(1.2, 8)
    m, kfs, points = random_map(rng, spec)
    other = kfs[-1]
    other.map_id = 1  # another atlas map's keyframe
    for p in points:
        p.min_dist, p.max_dist = 0.5, 4.0
    seen = _camera_coords(kfs, points)
    centres = {k.id: k.center.copy() for k in kfs}
    rotations = {k.id: k.T_cw[:3, :3].copy() for k in kfs}
    mine = {p.id for k in kfs[:-1] for p in k.valid_points()}
    gen = m.generation
    scaled = scale_map(m, 0, 2.5)
    assert other not in scaled and len(scaled) == len(kfs) - 1
    assert m.generation == gen + 1
    for k in scaled:
        np.testing.assert_allclose(k.center, 2.5 * centres[k.id], atol=1e-12)
        np.testing.assert_array_equal(k.T_cw[:3, :3], rotations[k.id])
    np.testing.assert_allclose(other.center, centres[other.id], atol=1e-12)
    after = _camera_coords(kfs, points)
    for (kf_id, pid), x in seen.items():
        if pid in mine and kf_id != other.id:
            np.testing.assert_allclose(after[(kf_id, pid)], 2.5 * x, atol=1e-9)  # same pixel
    for p in points:
        if p.id in mine:
            assert (p.min_dist, p.max_dist) == pytest.approx((1.25, 10.0))
        else:
            assert (p.min_dist, p.max_dist) == pytest.approx((0.5, 4.0))
    with pytest.raises(ValueError, match="positive"):
        scale_map(m, 0, 0.0)


def test_frame_records_follow_their_keyframes_scale() -> None:
    rng = np.random.default_rng(5)
    spec = orb_spec(1.2, 8)
    m, kfs, _ = random_map(rng, spec, n_kf=3, max_obs=3)
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    records = [(0.0, kfs[0], T.copy()), (1.0, kfs[1], T.copy())]
    assert kfs[0] in scale_map(m, 0, 3.0)
    assert rescale_frame_records(records, {kfs[0]: 3.0}) == 1
    np.testing.assert_allclose(records[0][2][:3, 3], [0.3, -0.6, 0.9])
    np.testing.assert_allclose(records[1][2][:3, 3], [0.1, -0.2, 0.3])
