"""The point store's observer rows (``PointStore.observers``) mirror the points'
``observations`` dicts through every change the map makes (adds, erases, re-adds, replaced
and culled points, rows wider than the initial width), and ``observer_counts`` gives what
the ``Counter`` over those dicts gave tracking: the same keyframes in the same first-seen
order, with the same counts."""

from __future__ import annotations

from collections import Counter
from itertools import chain

import numpy as np

from semslam.core.types import Keypoints, orb_spec
from semslam.geometry.se3 import invert
from semslam.slam.map import KeyFrame, Map, MapPoint


def _world(rng: np.random.Generator, n_kf: int = 30, n_kp: int = 80, n_pts: int = 300
           ) -> tuple[Map, list[KeyFrame], list[MapPoint]]:
    m = Map(orb_spec(1.2, 8))
    kfs = []
    for k in range(n_kf):
        T = np.eye(4)
        T[:3, 3] = rng.normal(0, 1.0, 3)
        kps = Keypoints(rng.uniform(0, 640, (n_kp, 2)).astype(np.float32), rng.integers(0, 8, n_kp).astype(np.int32),
                        np.ones(n_kp, np.float32), np.zeros(n_kp, np.float32),
                        rng.integers(0, 256, (n_kp, 32), dtype=np.uint8))
        kf = KeyFrame(m.new_kf_id(), k, float(k), invert(T), kps, kps.xy.astype(np.float64),
                      np.ones(n_kp, np.float32), -np.ones(n_kp), [None] * n_kp)
        m.add_keyframe(kf)
        kfs.append(kf)
    points = []
    for _ in range(n_pts):
        ref = kfs[int(rng.integers(n_kf))]
        p = m.new_point(rng.normal(0, 3.0, 3), ref.keypoints.descriptors[0].copy(), ref)
        for kf in rng.choice(kfs, int(rng.integers(0, 20)), replace=False):  # up to 19: rows widen past 8
            p.add_observation(kf, int(rng.integers(n_kp)))
        points.append(p)
    return m, kfs, points


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
