"""Umeyama alignment and SE(3) helpers: exact recovery of known transforms, degenerate input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semslam.errors import EvalError
from semslam.geometry.alignment import AlignmentError, apply_sim3, sim3_matrix, umeyama
from semslam.geometry.se3 import (
    invert,
    make_pose,
    quat_to_rot,
    rot_to_quat,
    rotation_angle,
    so3_exp,
)

finite = {"allow_nan": False, "allow_infinity": False}
seeds = st.integers(min_value=0, max_value=2**32 - 1)
rotvecs = st.lists(st.floats(-3.0, 3.0, **finite), min_size=3, max_size=3)
translations = st.lists(st.floats(-100.0, 100.0, **finite), min_size=3, max_size=3)
quats = st.lists(st.floats(-1.0, 1.0, **finite), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


@settings(max_examples=60, deadline=None)
@given(
    seed=seeds,
    n=st.integers(3, 60),
    rotvec=rotvecs,
    trans=translations,
    log_scale=st.floats(-3.0, 3.0, **finite),
    spread=st.floats(0.01, 100.0, **finite),
)
def test_umeyama_recovers_sim3(seed, n, rotvec, trans, log_scale, spread) -> None:
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(n, 3)) * spread
    rot, t, s = so3_exp(rotvec), np.asarray(trans), float(np.exp(log_scale))
    dst = s * src @ rot.T + t
    r_est, t_est, s_est = umeyama(src, dst, with_scale=True)
    assert np.linalg.det(r_est) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(r_est, rot, atol=1e-8)
    assert s_est == pytest.approx(s, rel=1e-8)
    np.testing.assert_allclose(t_est, t, atol=1e-8 * (1 + abs(t).max() + s * spread))


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=st.integers(3, 60), rotvec=rotvecs, trans=translations)
def test_umeyama_recovers_se3(seed, n, rotvec, trans) -> None:
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(n, 3))
    rot, t = so3_exp(rotvec), np.asarray(trans)
    dst = src @ rot.T + t
    r_est, t_est, s_est = umeyama(src, dst, with_scale=False)
    assert s_est == 1.0
    np.testing.assert_allclose(r_est, rot, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(seed=seeds, n=st.integers(3, 40), with_scale=st.booleans())
def test_umeyama_matches_evo_on_noisy_points(seed, n, with_scale) -> None:
    geometry = pytest.importorskip("evo.core.geometry")
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(n, 3))
    dst = 2.0 * src @ so3_exp(rng.normal(size=3)).T + rng.normal(size=3)
    dst += rng.normal(scale=0.3, size=dst.shape)
    r, t, s = umeyama(src, dst, with_scale)
    r_evo, t_evo, s_evo = geometry.umeyama_alignment(src.T, dst.T, with_scale)
    np.testing.assert_allclose(r, r_evo, atol=1e-9)
    np.testing.assert_allclose(t, t_evo, atol=1e-9)
    assert s == pytest.approx(s_evo, rel=1e-9)


def test_reflection_is_never_returned() -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # mirror image
    r, _, _ = umeyama(src, dst, with_scale=True)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_apply_sim3_maps_positions_and_keeps_rotations_rigid() -> None:
    rng = np.random.default_rng(2)
    poses = make_pose(so3_exp(rng.normal(size=3))[None].repeat(5, 0), rng.normal(size=(5, 3)))
    rot, t, s = so3_exp([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0]), 2.5
    out = apply_sim3(poses, rot, t, s)
    np.testing.assert_allclose(out[:, :3, 3], s * poses[:, :3, 3] @ rot.T + t)
    np.testing.assert_allclose(out[:, :3, :3], rot @ poses[:, :3, :3])
    m = sim3_matrix(rot, t, s)
    np.testing.assert_allclose(m[:3, :3], s * rot)


@pytest.mark.parametrize(
    "src, why",
    [
        (np.zeros((2, 3)), "at least 3"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [5, 5, 5]]), "colinear"),
        (np.ones((5, 3)), "colinear"),
    ],
)
def test_degenerate_input_is_an_error(src: np.ndarray, why: str) -> None:
    with pytest.raises(AlignmentError, match=why):
        umeyama(src, src + 1.0, with_scale=True)


def test_colinear_target_is_an_error() -> None:
    src = np.random.default_rng(3).normal(size=(10, 3))
    dst = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    with pytest.raises(EvalError, match="colinear"):
        umeyama(src, dst, with_scale=False)


def test_bad_shapes_and_nan_are_errors() -> None:
    with pytest.raises(AlignmentError, match="shape"):
        umeyama(np.zeros((4, 3)), np.zeros((5, 3)), with_scale=False)
    with pytest.raises(AlignmentError, match="shape"):
        umeyama(np.zeros((4, 2)), np.zeros((4, 2)), with_scale=False)
    bad = np.random.default_rng(4).normal(size=(6, 3))
    bad[2, 1] = np.nan
    with pytest.raises(AlignmentError, match="nan"):
        umeyama(bad, bad, with_scale=False)


# --- se3.py properties ------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(q=quats)
def test_quaternion_round_trip(q) -> None:
    q = np.asarray(q) / np.linalg.norm(q)
    r = quat_to_rot(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    q2 = rot_to_quat(r)
    assert q2[3] >= 0
    # q and -q are the same rotation; which one comes back is only fixed when w != 0.
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9
    np.testing.assert_allclose(quat_to_rot(q2), r, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(rotvec=rotvecs, trans=translations)
def test_invert_is_inverse(rotvec, trans) -> None:
    t = make_pose(so3_exp(rotvec), trans)
    np.testing.assert_allclose(invert(t) @ t, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(t @ invert(t), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(invert(invert(t)), t, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(rotvec=rotvecs)
def test_rotation_angle_of_exp(rotvec) -> None:
    angle = float(np.linalg.norm(rotvec))
    expected = angle if angle <= np.pi else 2 * np.pi - angle  # angles wrap at pi
    assert rotation_angle(so3_exp(rotvec)) == pytest.approx(expected, abs=1e-6)
