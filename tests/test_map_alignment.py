"""Moving one atlas map by a similarity about its origin (gravity down its z axis; a
monocular map made metric by the IMU): every keyframe sees its points where it saw them
before (camera-frame coordinates scale, pixels do not move), centres, points and normals
turn and scale, matching distances scale, another map is untouched, and a local BA computed
before is discarded (the map's generation moves on)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.map_world import random_map
from semslam.core.types import orb_spec
from semslam.slam.orb.map_alignment import align_map, gravity_rotation, rescale_frame_records


def _camera_coords(kfs, points):  # type: ignore[no-untyped-def]
    return {(k.id, p.id): k.T_cw[:3, :3] @ p.pos + k.T_cw[:3, 3]
            for p in points for k in p.observations if not p.bad}


@pytest.mark.parametrize("angle_deg, scale", [(0.0, 2.5), (37.0, 1.0), (120.0, 0.4)])
def test_aligning_a_map_keeps_every_view_and_moves_positions(angle_deg: float, scale: float) -> None:
    rng = np.random.default_rng(4)
    spec = orb_spec(1.2, 8)
    m, kfs, points = random_map(rng, spec)
    R = Rotation.from_rotvec(np.radians(angle_deg) * np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5]))
    R = R.as_matrix()
    other = kfs[-1]
    other.map_id = 1  # another atlas map's keyframe
    for p in points:
        p.min_dist, p.max_dist = 0.5, 4.0
    seen = _camera_coords(kfs, points)
    centres = {k.id: k.center.copy() for k in kfs}
    rotations = {k.id: k.T_wc[:3, :3].copy() for k in kfs}
    mine = {p.id for k in kfs[:-1] for p in k.valid_points()}
    positions = {p.id: p.pos.copy() for p in points}
    normals = {p.id: p.normal.copy() for p in points}
    gen = m.generation
    moved = align_map(m, 0, R, scale)
    assert other not in moved and len(moved) == len(kfs) - 1
    assert m.generation == gen + 1
    for k in moved:
        np.testing.assert_allclose(k.center, scale * R @ centres[k.id], atol=1e-12)
        np.testing.assert_allclose(k.T_wc[:3, :3], R @ rotations[k.id], atol=1e-12)
    np.testing.assert_allclose(other.center, centres[other.id], atol=1e-12)
    after = _camera_coords(kfs, points)
    for (kf_id, pid), x in seen.items():
        if pid in mine and kf_id != other.id:
            np.testing.assert_allclose(after[(kf_id, pid)], scale * x, atol=1e-9)  # same pixel
    for p in points:
        if p.id in mine:
            np.testing.assert_allclose(p.pos, scale * R @ positions[p.id], atol=1e-12)
            np.testing.assert_allclose(p.normal, R @ normals[p.id], atol=1e-12)
            assert (p.min_dist, p.max_dist) == pytest.approx((0.5 * scale, 4.0 * scale))
        else:
            assert (p.min_dist, p.max_dist) == pytest.approx((0.5, 4.0))
    with pytest.raises(ValueError, match="positive"):
        align_map(m, 0, R, 0.0)
    with pytest.raises(ValueError, match="rotation"):
        align_map(m, 0, np.diag([1.0, 1.0, -1.0]), 1.0)


def test_gravity_rotation_turns_gravity_down_and_keeps_the_yaw() -> None:
    rng = np.random.default_rng(0)
    down = np.array([0.0, 0.0, -1.0])
    for g in [*rng.normal(size=(20, 3)), down, -down, np.array([0.0, 9.81, 0.0])]:
        R = gravity_rotation(9.81 * g)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R @ (g / np.linalg.norm(g)), down, atol=1e-12)
        # The smallest such rotation: its axis is horizontal (no turn about gravity).
        axis = Rotation.from_matrix(R).as_rotvec()
        assert abs(axis @ down) < 1e-9


def test_frame_records_follow_their_keyframes_scale() -> None:
    rng = np.random.default_rng(5)
    spec = orb_spec(1.2, 8)
    m, kfs, _ = random_map(rng, spec, n_kf=3, max_obs=3)
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    records = [(0.0, kfs[0], T.copy()), (1.0, kfs[1], T.copy())]
    assert kfs[0] in align_map(m, 0, np.eye(3), 3.0)
    assert rescale_frame_records(records, {kfs[0]: 3.0}) == 1
    np.testing.assert_allclose(records[0][2][:3, 3], [0.3, -0.6, 0.9])
    np.testing.assert_allclose(records[1][2][:3, 3], [0.1, -0.2, 0.3])
