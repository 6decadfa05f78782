"""The point store's observer rows (``PointStore.observers``) mirror the points'
``observations`` dicts through every change the map makes (adds, erases, re-adds, replaced
and culled points, rows wider than the initial width), and ``observer_counts`` gives what
the ``Counter`` over those dicts gave tracking: the same keyframes in the same first-seen
order, with the same counts."""

from __future__ import annotations

from collections import Counter
from itertools import chain

import numpy as np

from semslam.core.types import orb_spec
from semslam.slam.map import KeyFrame, Map, MapPoint
from tests.map_world import random_map


def _world(rng: np.random.Generator) -> tuple[Map, list[KeyFrame], list[MapPoint]]:
    # up to 19 observers a point: rows widen past their first width of 8
    return random_map(rng, orb_spec(1.2, 8), n_kf=30, n_kp=80, n_pts=300, max_obs=19)


def _assert_mirrors(m: Map, points: list[MapPoint]) -> None:
    store = m.store
    for p in points:
        n = int(store.n_kf_obs[p.row])
        assert n == len(p.observations)
        assert store.observers[p.row, :n].tolist() == [kf.id for kf in p.observations]


def test_observer_rows_follow_every_change_of_the_observations() -> None:
    rng = np.random.default_rng(4)
    m, kfs, points = _world(rng)
    _assert_mirrors(m, points)
    assert m.store.observers.shape[1] >= 19
    for _ in range(600):  # erase, re-add (goes last), re-observe (keeps its place)
        p = points[int(rng.integers(len(points)))]
        if p.bad:
            continue
        kf = kfs[int(rng.integers(len(kfs)))]
        if kf in p.observations and rng.random() < 0.6:
            p.erase_observation(kf)  # may cull the point (<= 1 observation left)
        else:
            p.add_observation(kf, int(rng.integers(80)))
    for old, new in zip(points[:20], points[20:40]):
        m.replace_point(old, new, descriptor=False)
    for p in points[40:50]:
        m.set_bad_point(p)
    m.set_bad_keyframe(kfs[5])
    _assert_mirrors(m, points)


def test_observer_counts_equal_the_counter_over_the_dicts() -> None:
    rng = np.random.default_rng(5)
    m, kfs, points = _world(rng)
    for p in points[::3]:
        for kf in list(p.observations)[:2]:
            p.erase_observation(kf)
    for _ in range(20):
        chosen = [p for p in rng.choice(points, 120, replace=False) if not p.bad]
        rows = np.array([p.row for p in chosen], np.intp)
        observers, counts = m.store.observer_counts(rows)
        want = Counter(chain.from_iterable(p.observations for p in chosen))
        assert observers == list(want)
        assert counts.tolist() == list(want.values())
        if want:  # the first of the most observed, as max() over the Counter picks it
            assert observers[int(np.argmax(counts))] is max(want, key=lambda k: want[k])
    observers, counts = m.store.observer_counts(np.zeros(0, np.intp))
    assert observers == [] and counts.size == 0
