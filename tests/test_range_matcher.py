"""The range matcher (SDF-SLAM eq. 8) equals a per-pair brute-force reference, and a
config selects it."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.config import FeatureConfig, load_config
from semslam.core import protocols
from semslam.core.types import DescriptorKind, FeatureSpec, orb_spec
from semslam.errors import ConfigError
from semslam.features import create_matcher
from semslam.features.matching import L2Matcher
from semslam.features.range_matcher import RangeMatcher


def _brute_force(xy_q, d_q, xy_t, d_t, window, ratio=None, mutual=False):
    """Eq. 8 literally: for every query, every train point in the square, nearest in L2."""
    half = window / 2
    def nearest_of_query(i):
        cands = [(float(np.sqrt(((d_q[i] - d_t[j]) ** 2).sum())), j) for j in range(len(xy_t))
                 if abs(xy_q[i, 0] - xy_t[j, 0]) <= half and abs(xy_q[i, 1] - xy_t[j, 1]) <= half]
        return sorted(cands)
    out = []
    for i in range(len(xy_q)):
        c = nearest_of_query(i)
        if not c:
            continue
        d, j = c[0]
        if ratio is not None and not (len(c) > 1 and d < ratio * c[1][0] or len(c) == 1):
            continue
        if mutual:
            back = sorted((float(np.sqrt(((d_q[k] - d_t[j]) ** 2).sum())), k) for k in range(len(xy_q))
                          if abs(xy_q[k, 0] - xy_t[j, 0]) <= half and abs(xy_q[k, 1] - xy_t[j, 1]) <= half)
            if back[0][1] != i:
                continue
        out.append((i, j, d))
    return out


def _random(rng, n, m, dim=32):
    xy_q = rng.uniform(0, 640, (n, 2)).round(0)  # integer pixels: points exactly on the border occur
    xy_t = np.concatenate([xy_q[: m // 2] + rng.integers(-80, 81, (m // 2, 2)), rng.uniform(0, 640, (m - m // 2, 2))])
    d_q = rng.normal(size=(n, dim)).astype(np.float32)
    d_t = rng.normal(size=(m, dim)).astype(np.float32)
    return xy_q, d_q, xy_t, d_t


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("options", [{}, {"ratio": 0.9}, {"mutual": True}, {"window_px": 40.0}])
def test_range_matcher_equals_brute_force(seed, options):
    rng = np.random.default_rng(seed)
    xy_q, d_q, xy_t, d_t = _random(rng, 60, 70)
    matcher = RangeMatcher(**options)
    qi, ti, dd = matcher.match(xy_q, d_q, xy_t, d_t)
    ref = _brute_force(xy_q, d_q, xy_t, d_t, matcher.window_px, options.get("ratio"), options.get("mutual", False))
    assert len(ref) > 0
    assert [int(i) for i in qi] == [r[0] for r in ref]
    assert [int(j) for j in ti] == [r[1] for r in ref]
    np.testing.assert_allclose(dd, [r[2] for r in ref], rtol=1e-5, atol=1e-5)


def test_window_is_a_closed_140_px_square_and_empty_windows_have_no_match():
    m = RangeMatcher()
    xy_q = np.array([[100.0, 100.0], [500.0, 400.0]])
    xy_t = np.array([[170.0, 30.0], [171.0, 100.0]])  # on the border / just outside for query 0
    d = np.eye(2, 4, dtype=np.float32)
    qi, ti, _ = m.match(xy_q, d, xy_t, d[::-1].copy())
    assert qi.tolist() == [0] and ti.tolist() == [0]
    assert len(m.match(xy_q, d, np.zeros((0, 2)), np.zeros((0, 4), np.float32))[0]) == 0


def test_config_selects_the_range_matcher():
    spec = FeatureSpec(DescriptorKind.FLOAT, 256, 2.0, 1, th_low=0.7, th_high=1.0)
    matcher = create_matcher(FeatureConfig(extractor="fpfdcnn", matcher="range"), spec)
    assert isinstance(matcher, RangeMatcher) and isinstance(matcher, protocols.Matcher)
    assert type(create_matcher(FeatureConfig(), spec)) is L2Matcher  # default keeps today's behaviour
    assert load_config("orb").features.matcher == "default"
    assert load_config("orb", ["features.matcher=range"]).features.matcher == "range"
    with pytest.raises(ConfigError, match=r"features\.matcher: unknown matcher 'nope'"):
        load_config("orb", ["features.matcher=nope"])
    with pytest.raises(ConfigError, match="float descriptors"):
        create_matcher(FeatureConfig(matcher="range"), orb_spec(1.2, 8))
