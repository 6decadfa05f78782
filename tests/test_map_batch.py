"""Batched map point statistics equal the per-point originals (ORB-SLAM's
ComputeDistinctiveDescriptors and UpdateNormalAndDepth)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.core.types import DescriptorKind, FeatureSpec, Keypoints, orb_spec
from semslam.features.matching import matcher_for
from semslam.slam.orb.map import KeyFrame, Map, update_normals_and_depths
from semslam.slam.orb.map_batch import compute_distinctive_descriptors
from semslam.slam.orb.point_store import MapPoint
from tests.map_world import random_map


def _reference_descriptor(p: MapPoint, matcher) -> np.ndarray | None:
    """MapPoint.compute_distinctive_descriptor as it was, one point at a time."""
    descs = [kf.keypoints.descriptors[i] for kf, i in p.observations.items() if not kf.bad]
    if len(descs) < 2:
        return descs[0] if descs else None
    d = np.stack(descs)
    n = len(d)
    ii, jj = np.triu_indices(n, 1)
    pair = matcher.distances(d[ii], d[jj])
    dist = np.zeros((n, n), pair.dtype)
    dist[ii, jj] = dist[jj, ii] = pair
    return d[int(np.argmin(np.median(dist, axis=1)))].copy()


def _reference_normals(points: list[MapPoint], scales: np.ndarray) -> dict[int, tuple]:
    """update_normals_and_depths as it was, returning (normal, min, max) per point id."""
    out = {}
    for p in points:
        if p.bad or not p.observations:
            continue
        d = np.array([p.pos - kf.center for kf in p.observations])
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        n = d.sum(0)
        n /= max(np.linalg.norm(n), 1e-9)
        mn = mx = None
        idx = p.observations.get(p.ref_kf)
        if idx is not None:
            mx = np.linalg.norm(p.pos - p.ref_kf.center) * scales[p.ref_kf.keypoints.octave[idx]]
            mn = mx / scales[-1]
        out[p.id] = (n, mn, mx)
    return out


def _world(rng: np.random.Generator, spec: FeatureSpec, n_kf: int = 12, n_kp: int = 60,
           n_pts: int = 150, max_obs: int = 9) -> tuple[Map, list[MapPoint]]:
    """``random_map`` with its fourth keyframe bad (observations by bad keyframes are ignored)."""
    m, kfs, points = random_map(rng, spec, n_kf, n_kp, n_pts, max_obs)
    kfs[3].bad = True
    return m, points


@pytest.mark.parametrize("spec", [orb_spec(1.2, 8),
                                  FeatureSpec(DescriptorKind.FLOAT, 128, 2 ** (1 / 3), 12,
                                              th_low=0.3, th_high=0.5)],
                         ids=["hamming", "l2"])
def test_distinctive_descriptors_equal_per_point(spec: FeatureSpec) -> None:
    rng = np.random.default_rng(1)
    _, points = _world(rng, spec)
    matcher = matcher_for(spec)
    before = {p.id: p.descriptor.copy() for p in points}
    want = {p.id: _reference_descriptor(p, matcher) for p in points}
    compute_distinctive_descriptors(points, matcher)
    n_multi = 0
    for p in points:
        expected = want[p.id] if want[p.id] is not None else before[p.id]
        np.testing.assert_array_equal(p.descriptor, expected)
        n_multi += sum(1 for kf in p.observations if not kf.bad) >= 3
    assert n_multi > 50  # the test exercised real medians
    # one point alone gives the same
    q = points[7]
    q.descriptor = before[q.id]
    compute_distinctive_descriptors([q], matcher)
    np.testing.assert_array_equal(q.descriptor, want[q.id] if want[q.id] is not None else before[q.id])


def test_distinctive_descriptor_ties_take_the_first_observation() -> None:
    rng = np.random.default_rng(2)
    m, points = _world(rng, orb_spec(1.2, 8), n_pts=1, max_obs=0)
    kfs = m.all_keyframes()
    p = points[0]
    for kf in (kfs[0], kfs[1], kfs[2]):  # three identical descriptors: all medians 0
        kf.keypoints.descriptors[5] = 7
        p.add_observation(kf, 5)
    kfs[0].keypoints.descriptors[5, 0] = 6  # now 0 and 1 differ by a bit, 1 and 2 equal
    compute_distinctive_descriptors([p], m.matcher)
    np.testing.assert_array_equal(p.descriptor, kfs[1].keypoints.descriptors[5])


def test_update_normals_and_depths_equals_per_point() -> None:
    rng = np.random.default_rng(3)
    m, points = _world(rng, orb_spec(1.2, 8))
    for p in points[::5]:  # some points lose their reference keyframe's observation (and keep it as reference)
        m.store.unobserve(p.row, p.ref_kf)
    points[1].bad = True
    scales = m.spec.pyramid.scales
    want = _reference_normals(points, scales)
    untouched = {p.id: (p.normal.copy(), p.min_dist, p.max_dist) for p in points}
    update_normals_and_depths(points, scales)
    assert len(want) > 100
    for p in points:
        if p.id not in want:
            np.testing.assert_array_equal(p.normal, untouched[p.id][0])
            continue
        n, mn, mx = want[p.id]
        np.testing.assert_allclose(p.normal, n, atol=1e-12)
        if mx is None:
            assert (p.min_dist, p.max_dist) == untouched[p.id][1:]
        else:
            assert p.max_dist == pytest.approx(mx, rel=1e-12)
            assert p.min_dist == pytest.approx(mn, rel=1e-12)


def test_hamming_kernel_equals_generic_path() -> None:
    """The compiled Hamming choice and the matcher-based one agree (odd and even counts,
    ties included: descriptors drawn from few distinct values)."""
    from semslam.slam.orb.map_batch import _POPCOUNT, _generic_choice, _hamming_choice

    rng = np.random.default_rng(4)
    cnt = rng.integers(1, 12, 400).astype(np.intp)
    start = np.zeros(cnt.size, np.intp)
    np.cumsum(cnt[:-1], out=start[1:])
    for values in (256, 3):
        desc = rng.integers(0, values, (int(cnt.sum()), 32), dtype=np.uint8)
        fast = _hamming_choice(desc, start, cnt, _POPCOUNT)
        slow = _generic_choice(desc, start, cnt, matcher_for(orb_spec(1.2, 8)))
        np.testing.assert_array_equal(fast, slow)


def test_ba_problem_from_an_observation_table_equals_the_direct_one() -> None:
    """build_ba_problem gives the same arrays whether it walks the observations itself or
    gets local mapping's one-pass table of every observer."""
    from semslam.geometry.camera import PinholeCamera
    from semslam.slam.orb.local_mapping import build_ba_problem
    from semslam.slam.orb.map_batch import observation_table

    rng = np.random.default_rng(5)
    m, points = _world(rng, orb_spec(1.2, 8))
    for kf in m.all_keyframes():
        kf.ur[::3] = 100.0  # some observations with depth
    points = [p for p in points if p.observations]
    kfs = m.all_keyframes()
    free, fixed = kfs[2:7], kfs[8:10]  # the others observe too and are left out
    cam = PinholeCamera(525.0, 525.0, 319.5, 239.5)
    a = build_ba_problem(free, fixed, points, cam, m.spec.pyramid, 40.0)
    b = build_ba_problem(free, fixed, points, cam, m.spec.pyramid, 40.0, observation_table(points))
    assert a.obs_pose.size > 100
    for field in ("poses_cw", "pose_fixed", "points_w", "obs_pose", "obs_point", "uv", "ur", "inv_sigma2"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    # and they are the observations themselves
    for m_ in range(0, a.obs_pose.size, 7):
        kf, p = (free + fixed)[a.obs_pose[m_]], points[a.obs_point[m_]]
        i = p.observations[kf]
        np.testing.assert_array_equal(a.uv[m_], kf.xy[i])
        assert a.inv_sigma2[m_] == m.spec.pyramid.inv_sigma2[kf.keypoints.octave[i]]


def _fusion_world() -> tuple[Map, list[KeyFrame], list[MapPoint], list[MapPoint]]:
    """Three keyframes looking at 30 points; keyframes 0 and 1 share points ``a`` (also seen
    by keyframe 2), keyframe 2 has its own duplicates ``b`` of the same 3D points at the same
    keypoints."""
    from semslam.slam.orb.map import update_normals_and_depths

    rng = np.random.default_rng(6)
    m = Map(orb_spec(1.2, 8))
    n = 30
    X = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.7, 0.7, n), rng.uniform(2.5, 4.0, n)])
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    kfs = []
    for k in range(3):
        T = np.eye(4)
        T[0, 3] = -0.1 * k  # camera k at x = 0.1 k
        pc = X + T[:3, 3]
        xy = np.column_stack([525 * pc[:, 0] / pc[:, 2] + 319.5, 525 * pc[:, 1] / pc[:, 2] + 239.5])
        kps = Keypoints(xy.astype(np.float32), np.zeros(n, np.int32), np.ones(n, np.float32),
                        np.zeros(n, np.float32), desc.copy())
        kf = KeyFrame(m.new_kf_id(), k, float(k), T, kps, xy, pc[:, 2].astype(np.float32),
                      xy[:, 0] - 40.0 / pc[:, 2], [None] * n)
        m.add_keyframe(kf)
        kfs.append(kf)
    a, b = [], []
    for i in range(n):
        p = m.new_point(X[i], desc[i].copy(), kfs[0])
        for kf in kfs[:2]:
            p.add_observation(kf, i)
            kf.points[i] = p
        a.append(p)
        q = m.new_point(X[i] + 1e-4, desc[i].copy(), kfs[2])
        q.add_observation(kfs[2], i)
        kfs[2].points[i] = q
        b.append(q)
    update_normals_and_depths(a + b, m.spec.pyramid.scales)
    return m, kfs, a, b


def test_fusion_plan_reads_only_and_apply_merges_duplicates() -> None:
    """Fuse split in plan (no change to the map) and apply: a's points projected into
    keyframe 2 find b's duplicates and replace them (a has more observations); points
    keyframe 2 already observes are not planned; matches gone stale are dropped."""
    from semslam.geometry.camera import PinholeCamera
    from semslam.slam.orb.fusion import PointArrays, PointFusion

    m, kfs, a, b = _fusion_world()
    fusion = PointFusion(m, PinholeCamera(525.0, 525.0, 319.5, 239.5, width=640, height=480), 40.0)
    before = {p.id: dict(p.observations) for p in a + b}
    plan = fusion.plan(kfs[2], PointArrays.of(a))
    assert len(plan) == len(a) and {(p.id, t) for p, t in plan} == {(p.id, i) for i, p in enumerate(a)}
    assert {p.id: dict(p.observations) for p in a + b} == before  # planning changed nothing
    assert fusion.plan(kfs[0], PointArrays.of(a)) == []  # keyframe 0 observes them already
    b[0].bad = True  # gone bad meanwhile: a[0] is added to the free keypoint instead
    kfs[2].points[0] = None
    a[1].bad = True  # a planned point gone bad: dropped
    touched: dict[int, MapPoint] = {}
    n = fusion.apply(kfs[2], plan, touched)
    assert n == len(a) - 1 and a[1].id not in touched
    assert kfs[2].points[0] is a[0] and a[0].observations[kfs[2]] == 0
    for i in range(2, len(a)):
        assert b[i].bad and b[i].replaced_by is a[i] and kfs[2].points[i] is a[i]
        assert set(a[i].observations) == set(kfs)


def test_normals_of_a_pending_change_equal_those_after_it() -> None:
    """normals_and_depths with new positions, camera centres and observations to erase
    (local BA computes them before taking the lock) equals it computed after the change:
    reference keyframes that go take the first remaining one, points left with <= 1
    observation go bad and are left out."""
    from semslam.slam.orb.map_batch import normals_and_depths

    rng = np.random.default_rng(7)
    m, points = _world(rng, orb_spec(1.2, 8), max_obs=6)
    points = [p for p in points if p.observations]
    kfs = m.all_keyframes()
    scales = m.spec.pyramid.scales
    new_pos = np.array([p.pos for p in points]) + rng.normal(0, 0.05, (len(points), 3))
    new_T = {kf: kf.T_cw @ np.r_[np.c_[np.eye(3), rng.normal(0, 0.1, 3)], [[0, 0, 0, 1]]] for kf in kfs[:4]}
    centers = {kf: -T[:3, :3].T @ T[:3, 3] for kf, T in new_T.items()}
    erased: dict[int, set] = {}
    for p in points[::3]:
        obs = list(p.observations)
        gone = {p.ref_kf} if p.ref_kf in p.observations else set()
        gone |= set(obs[1:2]) if len(obs) > 3 else set(obs[:1])
        erased[p.id] = gone
    pending = normals_and_depths(points, scales, new_pos, centers, erased)
    for p, x in zip(points, new_pos):
        p.pos = x
    for kf, T in new_T.items():
        kf.set_pose(T)
    for p in points:
        for kf in erased.get(p.id, ()):
            p.erase_observation(kf)
    assert any(p.bad for p in points) and any(not p.bad for p in points if p.id in erased)
    after = normals_and_depths(points, scales)
    assert [p.id for p in pending.points] == [p.id for p in after.points]
    np.testing.assert_allclose(pending.normal, after.normal, atol=1e-12)
    np.testing.assert_array_equal(pending.ranged, after.ranged)
    np.testing.assert_allclose(pending.max_dist, after.max_dist, rtol=1e-12)
    np.testing.assert_allclose(pending.min_dist, after.min_dist, rtol=1e-12)


def test_observation_table_lists_every_observation_in_order() -> None:
    """The flattened table equals walking each point's observations in order, with every
    keyframe numbered first-seen, or by a given index (observers outside it left out)."""
    from semslam.slam.orb.map_batch import observation_table

    rng = np.random.default_rng(11)
    m, points = _world(rng, orb_spec(1.2, 8))
    points = [p for p in points if p.observations] + [p for p in points if not p.observations][:3]
    direct = [(j, kf, i) for j, p in enumerate(points) for kf, i in p.observations.items()]
    pr, kr, kp, kfs = observation_table(points)
    assert kfs == list(dict.fromkeys(kf for _, kf, _ in direct))
    assert [(int(a), kfs[b], int(c)) for a, b, c in zip(pr, kr, kp)] == direct
    some = m.all_keyframes()[1:6:2]
    index = {kf: k for k, kf in enumerate(some)}
    pr, kr, kp, kfs = observation_table(points, index)
    assert kfs == some
    assert [(int(a), kfs[b], int(c)) for a, b, c in zip(pr, kr, kp)] == [t for t in direct if t[1] in index]
    empty = observation_table([])
    assert all(a.size == 0 for a in empty[:3]) and empty[3] == []


def test_store_gathers_equal_the_per_point_attributes() -> None:
    """The point store's flags and rows give what the objects say: a keyframe's good points
    and free slots, and ``PointArrays`` (gathered by rows, and point by point for points
    in stores of their own)."""
    from semslam.slam.orb.fusion import PointArrays

    rng = np.random.default_rng(8)
    m, points = _world(rng, orb_spec(1.2, 8))
    kf = m.all_keyframes()[0]
    for i, p in enumerate(points[:40]):
        kf.points[i] = p
    for p in points[:40:3]:
        p.bad = True
    assert kf.valid_points() == [p for p in kf.points if p is not None and not p.bad]
    np.testing.assert_array_equal(kf.free_mask(), [p is None or p.bad for p in kf.points])
    arrays = PointArrays.of(points)
    loose = [MapPoint(1000 + i, p.pos, p.descriptor, p.ref_kf) for i, p in enumerate(points)]  # own stores
    for q, p in zip(loose, points):
        q.bad, q.min_dist, q.max_dist, q.normal = p.bad, p.min_dist, p.max_dist, p.normal
    per_point = PointArrays.of(loose)
    assert arrays.points == [p for p in points if not p.bad]
    for name in ("pos", "min_dist", "max_dist", "normal", "descriptors"):
        np.testing.assert_array_equal(getattr(arrays, name), getattr(per_point, name))
    assert len(arrays.points) == len(per_point.points) > 100


def test_fusion_apply_leaves_each_merged_point_its_distinctive_descriptor() -> None:
    """apply computes the merged points' descriptors in one batch at its end: each equals
    the per-point original over the point's final observations, as replace_point leaves it."""
    from semslam.geometry.camera import PinholeCamera
    from semslam.slam.orb.fusion import PointFusion

    m, kfs, a, b = _fusion_world()
    rng = np.random.default_rng(9)
    kfs[2].keypoints.descriptors[:] = rng.integers(0, 256, kfs[2].keypoints.descriptors.shape, dtype=np.uint8)
    kfs[1].keypoints.descriptors[:, :4] ^= 0x0F  # three different observations per point
    fusion = PointFusion(m, PinholeCamera(525.0, 525.0, 319.5, 239.5, width=640, height=480), 40.0)
    plan = [(p, i) for i, p in enumerate(a)]  # every a[i] onto keyframe 2's b[i]
    for p in a:
        p.descriptor = np.zeros(32, np.uint8)  # stale: none of its observations'
    stale = {p.id: p.descriptor.copy() for p in a}
    assert fusion.apply(kfs[2], plan) == len(a)
    changed = 0
    for p in a:
        assert not p.bad and kfs[2] in p.observations
        np.testing.assert_array_equal(p.descriptor, _reference_descriptor(p, m.matcher))
        changed += not np.array_equal(p.descriptor, stale[p.id])
    assert changed == len(a)  # the batch did recompute them


def test_point_slots_put_equals_item_assignment() -> None:
    """put() sets many slots (and their store rows) as item assignment does one by one."""
    from semslam.slam.orb.point_store import PointSlots

    rng = np.random.default_rng(10)
    _, points = _world(rng, orb_spec(1.2, 8), n_pts=20)
    one, many = PointSlots([None] * 30), PointSlots([None] * 30)
    idx = np.array([3, 7, 8, 20, 29, 7], np.intp)  # 7 twice: the last wins
    new = [points[0], points[1], None, points[2], points[3], points[4]]
    for i, p in zip(idx.tolist(), new):
        one[i] = p
    many.put(idx, new)
    assert list(one) == list(many) and np.array_equal(one.rows, many.rows)
    many.put(idx[:2], [points[5], points[6]], np.array([points[5].row, points[6].row]))
    one[3], one[7] = points[5], points[6]
    assert list(one) == list(many) and np.array_equal(one.rows, many.rows)


def test_point_slots_hold_rows_only() -> None:
    """A keyframe's slots are its points' store rows: the point in a slot is the store's
    object at its row, the rows cannot be written around the slots, and a point of another
    store is refused (rows and objects cannot disagree)."""
    rng = np.random.default_rng(11)
    m, points = _world(rng, orb_spec(1.2, 8))
    kf = m.all_keyframes()[0]
    for i, p in enumerate(points[:10]):
        kf.points[i] = p
    assert [kf.points[i] for i in range(10)] == points[:10]
    assert kf.points.rows[:10].tolist() == [p.row for p in points[:10]]
    with pytest.raises(ValueError):
        kf.points.rows[4] = points[20].row
    kf.points[4] = None
    assert kf.points[4] is None and kf.points.rows[4] == -1
    assert kf.valid_points() == points[:4] + points[5:10]
    loose = MapPoint(10_000, points[0].pos, points[0].descriptor, points[0].ref_kf)  # a store of its own
    with pytest.raises(ValueError):
        kf.points[5] = loose
