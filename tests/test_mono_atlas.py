"""The monocular atlas (``--preset mono``, issue 40): a new map after a loss, started by the
two-view initialisation, and merged back into the older map with a similarity (ORB-SLAM3
LoopClosing::MergeLocal with a Sim3; slam/orb/map_merging.py, merge_check.py's
reprojection-only mode, loop_closing.py's merge detection).

End to end on one ``blackout_xyz`` render at 320x240 (240 frames, 2 s of black frames from
3 s on, seed 13 layout 0), sequential (deterministic). Measured here: initialised at frame
42, 48 frames tracked before the blackout; a new map 1.5 s after the last tracked frame
(mono.yaml), initialised 26 frames after the lens is uncovered; every frame after it tracked;
merged from keyframe 9 (new map) with keyframe 1, confirmed by 3 keyframes, 0.88 cm / 0.57 deg
off the truth at the weld; the 112 tracked frames in the first map's frame with an evo Sim(3)
ATE of 1.42 cm (the same motion without the blackout: 1.32 cm). Held-out renders
(seeds/layouts 3/2, 5/3, 21/1, 8/0, 17/2, 30/3, 4/1): merged in all 7, Sim(3) ATE median
1.30 cm, worst 1.93 cm; threaded 1.54 / 4.12 cm (docs/results/atlas.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from semslam.backend.sim3 import rigid_part
from semslam.backend.sim3 import sim3_inverse
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.experiments.merge_error import WRONG_DEG, WRONG_M
from tests.conftest import evo_ate, run_cli

BLACKOUT_START_S, BLACKOUT_S = 3.0, 2.0


def _stamps(path: Path) -> np.ndarray:
    return np.array([float(line.split()[0]) for line in path.read_text().splitlines()
                     if line.strip() and not line.startswith("#")])


@pytest.fixture(scope="module")
def blackout_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    """One render and one sequential mono run of it, shared by the end-to-end tests."""
    from semslam.synth import SEQUENCES, render_sequence

    root = tmp_path_factory.mktemp("mono_atlas")
    cfg = SEQUENCES["blackout_xyz"].replace(frames=240, width=320, height=240, seed=13, layout=0,
                                            blackout_start_s=BLACKOUT_START_S, blackout_s=BLACKOUT_S)
    seq = render_sequence(cfg, root / "seq")
    out = root / "run"
    stats = run_cli(seq, out, "--preset", "mono", "--sequential", "--no-report", "--map", "none")
    return seq, out, stats


def _similarity(rng: np.random.Generator, scale: float) -> np.ndarray:
    S = make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    S[:3, :3] *= scale
    return S


def _pose(rng: np.random.Generator) -> np.ndarray:
    return make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def _pixel(T_cw: np.ndarray, p: np.ndarray) -> np.ndarray:
    x = T_cw[:3, :3] @ p + T_cw[:3, 3]
    return x[:2] / x[2]


@pytest.mark.slow
def test_new_map_after_the_blackout_tracks_every_frame_after_its_initialisation(blackout_run) -> None:
    """The blackout loses tracking; relocalisation fails on black frames, and 1.5 s after the
    last tracked frame a new map is due; the two-view initialisation starts it once the lens
    is uncovered and the camera has moved enough, and from then on every frame is tracked."""
    seq, out, stats = blackout_run
    assert stats["maps"] == 2
    assert stats["relocalisations"] == 0  # the new map took over, not a relocalisation
    t_rgb, t_est = _stamps(seq / "rgb.txt"), _stamps(out / "trajectory.txt")
    rel = t_rgb - t_rgb[0]
    after = t_rgb[rel >= BLACKOUT_START_S + BLACKOUT_S - 1e-6]
    tracked_after = np.isin(after, t_est)
    first = int(np.argmax(tracked_after))
    assert tracked_after.any() and tracked_after[first:].all(), "a frame after the new map's start was lost"
    assert first <= 40, first  # measured: 26 frames (the initialisation's parallax)
    # Before the blackout: every frame from the first map's initialisation on.
    before = t_rgb[rel < BLACKOUT_START_S - 1e-6]
    tracked_before = np.isin(before, t_est)
    assert tracked_before[int(np.argmax(tracked_before)):].all()
    assert stats["tracked_frames"] == len(t_est) == int(tracked_before.sum() + tracked_after.sum())


@pytest.mark.slow
def test_new_map_merges_into_the_first_in_sim3(blackout_run) -> None:
    """The new map sees the first map's room again: found by bag of words, a 7-DoF RANSAC +
    OptimizeSim3, checked by reprojection on 3 keyframes of both maps, merged with the
    similarity. Every tracked frame ends in the first map's frame, and one Sim(3) aligns
    both sides of the blackout to the ground truth (evo, the reference) about as well as it
    aligns an uninterrupted run (1.32 cm on this motion)."""
    seq, out, stats = blackout_run
    assert stats["merges"] == 1 and stats["maps_unmerged"] == 1
    assert stats["frames_outside_first_map"] == 0
    assert stats["trajectory_frames_by_map"] == {"0": stats["tracked_frames"]}
    merged = [c for c in stats["merge_checks"] if c["result"] == "merged"]
    assert len(merged) == 1 and merged[0]["coincidences"] >= 3
    S = np.array(merged[0]["S"]).reshape(4, 4)
    assert abs(np.cbrt(np.linalg.det(S[:3, :3])) - 1.0) > 1e-3  # a similarity, not a rigid move
    ate = evo_ate(seq / "groundtruth.txt", out / "trajectory.txt", correct_scale=True)
    assert ate < 0.025, ate  # measured 1.42 cm (held-out renders: worst 1.93 cm)
    d, a = _weld_error(seq, out, merged[0])
    assert d <= WRONG_M and a <= WRONG_DEG, (d, a)  # measured 0.88 cm, 0.57 deg


def _weld_error(seq: Path, out: Path, check: dict) -> tuple[float, float]:
    """The merge's T12 (kf camera <- cand camera, a similarity in kf's map units) against the
    ground truth as RGB-D merges are judged (``merge_error.weld_error``: where it and the
    truth put the scene kf sees, from the render's depth). Metres per unit: the first map's
    from evo's Sim(3) alignment of the final trajectory (all in its frame), kf's map's
    through the similarity's scale."""
    from evo.core.geometry import umeyama_alignment

    from semslam.experiments.merge_error import true_T12, weld_error
    from semslam.io.trajectory import read_tum

    gt = read_tum(seq / "groundtruth.txt")
    est = read_tum(out / "trajectory.txt")
    near = [int(np.argmin(np.abs(gt.timestamps - t))) for t in est.timestamps]
    _, _, metres = umeyama_alignment(est.poses[:, :3, 3].T, gt.poses[near, :3, 3].T, True)
    T12 = np.array(check["T12"]).reshape(4, 4)
    s12 = float(np.cbrt(np.linalg.det(T12[:3, :3])))
    assert check["cand_map"] == 0 and check["kf_map"] == 1
    metric = make_pose(T12[:3, :3] / s12, T12[:3, 3] * metres / s12)
    return weld_error(seq, check["kf_time"], metric, true_T12(gt, check["kf_time"], check["cand_time"]))


def test_merge_similarity_puts_the_weld_keyframe_where_the_sim3_says() -> None:
    """S (kept world <- moved world) from a similarity S12 (kf camera <- cand camera):
    kf's similarity in the kept world is ``S12 @ cand.T_cw``, either map moved."""
    from semslam.slam.orb.map_merging import merge_similarity

    rng = np.random.default_rng(5)
    kf, cand = SimpleNamespace(T_cw=_pose(rng)), SimpleNamespace(T_cw=_pose(rng))
    S12 = _similarity(rng, 2.7)
    S = merge_similarity(kf, cand, S12, move_kf_map=True)  # type: ignore[arg-type]
    np.testing.assert_allclose(kf.T_cw @ sim3_inverse(S), S12 @ cand.T_cw, atol=1e-9)
    assert np.cbrt(np.linalg.det(S[:3, :3])) == pytest.approx(1 / 2.7)  # cand's units per kf's
    S = merge_similarity(kf, cand, S12, move_kf_map=False)  # type: ignore[arg-type]
    np.testing.assert_allclose(cand.T_cw @ sim3_inverse(S), sim3_inverse(S12) @ kf.T_cw, atol=1e-9)


def test_placed_keyframe_sees_the_other_maps_points_where_the_similarity_does() -> None:
    """``place``: a keyframe put in the other map's world by a similarity's rigid part sees each
    point of that map at the pixel the similarity predicts; ``relative`` turns a refit there
    back into the similarity T12, which the merger turns into the inverse of S."""
    from semslam.slam.orb.map_merging import merge_similarity
    from semslam.slam.orb.merge_check import MergeVerifier, place

    rng = np.random.default_rng(6)
    S = _similarity(rng, 0.6)  # kf's world <- cand's world
    kf, cand = SimpleNamespace(T_cw=_pose(rng)), SimpleNamespace(T_cw=_pose(rng))
    cand.T_wc = np.linalg.inv(cand.T_cw)
    T = place(kf.T_cw, S, mono=True)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)  # rigid
    for p in rng.normal(size=(5, 3)) + [0, 0, 8]:
        np.testing.assert_allclose(_pixel(T, p), _pixel(kf.T_cw, S[:3, :3] @ p + S[:3, 3]), atol=1e-9)
    verifier = MergeVerifier(None, 0.0, np.ones(1), lambda *a: None, mono=True)  # type: ignore[arg-type]
    T12 = verifier.relative(SimpleNamespace(T_cw=T), cand, S)  # type: ignore[arg-type]
    np.testing.assert_allclose(T12, kf.T_cw @ S @ cand.T_wc, atol=1e-9)
    np.testing.assert_allclose(merge_similarity(kf, cand, T12, move_kf_map=True), sim3_inverse(S), atol=1e-9)  # type: ignore[arg-type]


def test_world_change_of_a_similarity_keeps_the_frames_view() -> None:
    """After a monocular merge moved the active map by a similarity, tracking's last frame
    keeps the rigid part of its moved pose: it sees every moved point at the same pixel; a
    rigid world change is applied as before."""
    from semslam.slam.orb.atlas import AtlasFollower

    rng = np.random.default_rng(7)
    S = _similarity(rng, 1.8)
    T0 = _pose(rng)
    atlas = SimpleNamespace(take_world_change=lambda: S)
    frame = SimpleNamespace(T_cw=T0.copy())
    AtlasFollower(atlas).apply_world_change(frame)  # type: ignore[arg-type]
    np.testing.assert_allclose(frame.T_cw, rigid_part(T0 @ sim3_inverse(S)), atol=1e-12)
    for p in rng.normal(size=(5, 3)) + [0, 0, 8]:
        np.testing.assert_allclose(_pixel(frame.T_cw, S[:3, :3] @ p + S[:3, 3]), _pixel(T0, p), atol=1e-9)
    R = _pose(rng)
    atlas.take_world_change = lambda: R
    frame.T_cw = T0.copy()
    AtlasFollower(atlas).apply_world_change(frame)  # type: ignore[arg-type]
    np.testing.assert_allclose(frame.T_cw, T0 @ np.linalg.inv(R), atol=1e-12)



@pytest.fixture(scope="module")
def two_mono_maps(blackout_run) -> Iterator[tuple[object, Path]]:
    """The same render run again with merging switched off: the tracker with its two maps."""
    import cv2

    from semslam.api import System
    from semslam.io.sequence import read_file_list
    from semslam.slam.orb.loop_closing import LoopClosing

    seq = blackout_run[0]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(LoopClosing, "_check_merge", lambda self, *a, **k: None)
        slam = System("mono", camera=seq / "calib.txt", bgr=True, overrides={"slam.sequential": True, "maps.builders": []})
        for e in read_file_list(seq / "rgb.txt"):
            slam.track(cv2.imread(str(e.path), cv2.IMREAD_COLOR), None, e.timestamp)
    core = slam.tracker
    assert core.atlas.live_maps() == [0, 1]
    yield core, seq
    slam.close()


def _metres_per_unit(seq: Path, kf: object) -> float:
    """Metres per unit of kf's (unmerged) map: the render's true depth at kf's keypoints over
    the depths of kf's own map points there (median)."""
    from semslam.experiments.merge_error import DEPTH_SCALE
    from semslam.io.images import read_depth
    from semslam.io.sequence import read_file_list

    depth = read_file_list(seq / "depth.txt")
    img = read_depth(depth[int(np.argmin([abs(e.timestamp - kf.timestamp) for e in depth]))].path, DEPTH_SCALE)
    ratios = []
    for i, p in enumerate(kf.points):
        if p is not None and not p.bad:
            u, v = np.round(kf.xy[i]).astype(int)
            z_map = (kf.T_cw[:3, :3] @ p.pos + kf.T_cw[:3, 3])[2]
            if 0 <= v < img.shape[0] and 0 <= u < img.shape[1] and img[v, u] > 0 and z_map > 0:
                ratios.append(float(img[v, u]) / z_map)
    return float(np.median(ratios))


@pytest.mark.slow
def test_monocular_merge_check_refuses_wrong_scales_and_offsets(two_mono_maps) -> None:
    """For new-map keyframes whose true view is within 50 cm of a first-map keyframe's: the
    Sim(3) found by ``_compute_transform``, and the same moved sideways / along the view / turned
    or scaled by 0.85, 1.2, 0.7, through the monocular check. Every accepted one is within
    5 cm / 2 deg of the truth at the weld (``merge_error.weld_error``, with metres per unit
    of kf's map from the render's depth at its points); every wrong scale is refused (the
    own-points depth check: median errors 0.15-0.30, against 0.037-0.044 for the found
    scale); the found one is accepted for at least one pair. Measured (4 pairs here; 5 and 4
    on held-out seeds/layouts 8/0, 4/1): the found Sim(3), the 0.03 / 0.06 unit sideways and up,
    the 0.05 / 0.15 along the view and the 4 deg turn accepted and refitted to 0.8-2.0 cm /
    0.4-0.9 deg of the truth; 0.1 / 0.2 units sideways and 6 / 10 deg refused (inliers); every
    wrong scale refused (depth agreement)."""
    from semslam.experiments.merge_error import true_T12, weld_error
    from semslam.io.trajectory import read_tum
    from semslam.slam.orb.merge_check import enough

    core, seq = two_mono_maps
    gt = read_tum(seq / "groundtruth.txt")
    kfs = [k for k in core.map.all_keyframes() if not k.bad]
    pairs = [(k1, k0) for k1 in kfs if k1.map_id == 1 for k0 in kfs if k0.map_id == 0
             and np.linalg.norm(true_T12(gt, k1.timestamp, k0.timestamp)[:3, 3]) < 0.5]
    closer = core.closer
    found_accepted, tried = 0, 0
    for k1, k0 in pairs[:6]:
        res = closer._compute_transform(k1, k0)
        if res is None:
            continue
        tried += 1
        S12 = res[1]
        true = true_T12(gt, k1.timestamp, k0.timestamp)
        covis = [k for k in k1.best_covisibles(5) if not k.bad]
        cand_covis = [k for k in k0.best_covisibles(5) if not k.bad]
        for i, (delta, wrong_scale) in enumerate([(np.eye(4), False), *WRONG]):
            T12 = delta @ S12
            v = closer.verifier.verify(k1, k0, T12, closer._match_at(k1, k0, T12) or {}, covis, cand_covis)
            if not v.ok or not enough(v.confirmers):
                continue
            assert not wrong_scale, f"kf {k1.id} vs {k0.id}: a scale off by {delta[0, 0]:.2f} accepted"
            s12 = float(np.cbrt(np.linalg.det(v.T12[:3, :3])))
            metric = make_pose(v.T12[:3, :3] / s12, v.T12[:3, 3] * _metres_per_unit(seq, k1) / s12)
            d, a = weld_error(seq, k1.timestamp, metric, true)
            assert d <= WRONG_M and a <= WRONG_DEG, f"kf {k1.id} vs {k0.id}, #{i}: accepted {d:.3f} m {a:.2f} deg off"
            found_accepted += i == 0
    assert tried >= 2 and found_accepted >= 1, (tried, found_accepted)


def _scaled(s: float) -> np.ndarray:
    D = np.eye(4)
    D[:3, :3] *= s
    return D


#: Wrong similarities (in the new map's units, ~3.5-4 m each here): sideways, along the view,
#: turned, and scaled (True: must be refused).
WRONG = ([(make_pose(np.eye(3), np.array(v)), False) for v in
          ([0.03, 0, 0], [0.1, 0, 0], [-0.2, 0, 0], [0, 0.06, 0], [0, 0, 0.05], [0, 0, -0.15])]
         + [(make_pose(so3_exp(np.radians(np.array(r))), np.zeros(3)), False) for r in ([0, 4.0, 0], [0, -10.0, 0], [6.0, 0, 0])]
         + [(_scaled(s), True) for s in (0.85, 1.2, 0.7)])
