"""A point's observations live once, in the point store's rows (``PointStore.observers`` /
``observer_kp``): ``MapPoint.observations`` is read from them, in the order a dict would keep
(adds, erases, re-adds, replaced and culled points, rows wider than the initial width), and
``observer_counts`` gives what a ``Counter`` over the observations gives: the same keyframes
in the same first-seen order, with the same counts. Array attributes cannot be changed in
place (the change would not reach the store)."""

from __future__ import annotations

from collections import Counter
from itertools import chain

import numpy as np
import pytest

from semslam.core.types import orb_spec
from semslam.slam.orb.map import KeyFrame, Map
from semslam.slam.orb.point_store import MapPoint
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


def test_observations_keep_the_order_of_a_dict() -> None:
    """Every change goes to the store's rows; the observations read back equal a dict that
    saw the same changes (re-observing keeps the place, erase and re-add goes last)."""
    rng = np.random.default_rng(6)
    m, kfs, points = _world(rng)
    p = next(q for q in points if len(q.observations) >= 4)
    mirror = dict(p.observations)
    first, second = list(mirror)[:2]
    p.add_observation(first, 7)  # keeps its place
    mirror[first] = 7
    p.erase_observation(second)
    del mirror[second]
    p.add_observation(second, 3)  # goes last
    mirror[second] = 3
    assert list(p.observations.items()) == list(mirror.items())
    assert p.n_obs == len(mirror)  # no depth (ur < 0): one each
    with pytest.raises(TypeError):
        p.observations[kfs[0]] = 1  # type: ignore[index]


def test_array_attributes_cannot_be_changed_in_place() -> None:
    """``p.pos[0] = x`` raises instead of changing a copy; assigning the attribute writes
    the store."""
    rng = np.random.default_rng(7)
    m, _, points = _world(rng)
    p = points[0]
    for name in ("pos", "normal", "descriptor"):
        with pytest.raises(ValueError):
            getattr(p, name)[0] = 1
    pos = p.pos + 1.0
    p.pos = pos
    np.testing.assert_array_equal(m.store.pos[p.row], pos)
