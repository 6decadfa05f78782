"""The depth network's prior for a monocular map (slam/orb/depth_prior.py): the checks that
drop it, on depths with a known relation to the map's (analytic cases)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.config import DepthConfig
from semslam.slam.orb.depth_prior import DepthPrior


@pytest.fixture
def room_depths() -> np.ndarray:
    """Depths of 400 points in a room (1-4.5 m), as a two-view map would hold them at scale 0.37."""
    rng = np.random.default_rng(0)
    return rng.uniform(1.0, 4.5, 400)


def _prior() -> DepthPrior:
    return DepthPrior(DepthConfig(use="prior"))


def test_a_right_network_scales_the_initial_map_to_metres(room_depths: np.ndarray) -> None:
    rng = np.random.default_rng(1)
    predicted = room_depths * np.exp(rng.normal(0, 0.08, room_depths.size))  # 8 % errors
    prior = _prior()
    scale = prior.initial_map_scale(0.37 * room_depths, predicted)
    assert scale is not None and scale == pytest.approx(1 / 0.37, rel=0.02)
    assert prior.metric_init is True


@pytest.mark.parametrize("wrong", ["constant", "shuffled", "noise"])
def test_a_wrong_network_is_refused(room_depths: np.ndarray, wrong: str) -> None:
    rng = np.random.default_rng(2)
    predicted = {"constant": np.full(room_depths.size, 2.0),
                 "shuffled": rng.permutation(room_depths),
                 "noise": room_depths * np.exp(rng.normal(0, 0.5, room_depths.size))}[wrong]
    prior = _prior()
    assert prior.initial_map_scale(0.37 * room_depths, predicted) is None
    assert prior.metric_init is False
    assert not prior.check_keyframe(room_depths, predicted).any()  # no prior for this keyframe
    assert prior.stats()["depth_prior_keyframes"] == 0


def test_a_scaled_network_passes_with_its_scale(room_depths: np.ndarray) -> None:
    # Twice the true depth: the structure is right, the map becomes "metric" in its units.
    prior = _prior()
    scale = prior.initial_map_scale(room_depths, 2 * room_depths)
    assert scale == pytest.approx(2.0)


def test_keyframe_prior_follows_the_running_scale_and_drops_outlying_keypoints(room_depths: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    prior = _prior()
    map_depth = 0.5 * room_depths  # the map is at half the network's scale
    predicted = room_depths * np.exp(rng.normal(0, 0.05, room_depths.size))
    predicted[:10] *= 3.0  # ten keypoints on something the network gets badly wrong
    map_depth[-50:] = 0  # keypoints without a map point yet keep the keyframe's prior
    out = prior.check_keyframe(map_depth, predicted)
    assert (out[:10] == 0).all()
    kept = out[10:] > 0
    assert kept.mean() > 0.98  # the 5 % noise's own tail beyond 3 sigma goes too
    assert np.allclose(out[10:][kept], 0.5 * predicted[10:][kept], rtol=0.01)
    assert prior.stats()["depth_prior_scale"] == pytest.approx(0.5, rel=0.02)
    # A later keyframe whose ratios jumped by 60 % is refused (the map's scale did not).
    assert not prior.check_keyframe(0.8 * room_depths, room_depths).any()
    assert prior.stats()["depth_prior_refused"] == {"keyframe: scale jumped": 1}


def test_virtual_right_coordinate_and_baseline(room_depths: np.ndarray) -> None:
    prior = _prior()
    prior.check_keyframe(room_depths, room_depths)
    bf = prior.virtual_bf()
    # One pixel of the residual is prior_sigma (20 %) of the median depth in inverse depth.
    assert bf == pytest.approx(np.median(room_depths) / 0.2, rel=1e-6)
    u = np.array([300.0, 300.0])
    ur = prior.virtual_right(u, np.array([2.0, 0.0]), bf)
    assert ur[0] == pytest.approx(300.0 - bf / 2.0) and ur[1] == -1.0


def test_in_front_of_a_wall_a_constant_depth_sets_units_but_no_prior() -> None:
    # A wall at 3 m +- 2 %: a constant 2 m "network" agrees on one scale (the map's units
    # become its metres, harmless for a map that has none), but it does not explain the
    # depths' variation, so no keyframe gets a prior on its depths.
    rng = np.random.default_rng(4)
    wall = 3.0 * np.exp(rng.normal(0, 0.02, 300))
    prior = _prior()
    assert prior.initial_map_scale(0.5 * wall, np.full(300, 2.0)) == pytest.approx(2.0 / 1.5, rel=0.01)
    assert not prior.check_keyframe(wall, np.full(300, 2.0)).any()
    stats = prior.stats()
    assert stats["depth_prior_keyframes"] == 0
    assert stats["depth_prior_refused"] == {"keyframe: structure not explained": 1}
    assert stats["depth_prior_scale"] == pytest.approx(1.5, rel=0.01)
