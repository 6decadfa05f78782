"""The multi-map atlas (issue 13 item 3): a new map when tracking stays lost, maps merged
when one sees a place of another, one trajectory of every frame.

Through the CLI on the ``jump_back`` and ``blackout_xyz`` renders at 320x240 (as
``test_orb_slam.py``'s loop test: half the focal length, half the virtual stereo bf),
sequential so that the runs are deterministic. The ATE bounds are about twice what was
measured when they were written (jump_back 3.6 cm, blackout 2.2 cm; the same xyz motion
without the blackout: 1.5 cm).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semslam.geometry.se3 import invert, make_pose, so3_exp
from semslam.synth import SEQUENCES, render_sequence

COMMON = ["--preset", "orb", "--sequential", "--quiet", "--no-report", "--set", "features.n_features=600",
          "--set", "slam.min_init_keypoints=300", "--set", "slam.bf=20"]


def _run(seq: Path, out: Path, *extra: str, sequential: bool = True) -> dict:
    from semslam.cli.main import main

    common = COMMON if sequential else [a for a in COMMON if a != "--sequential"]
    assert main(["run", str(seq), "--out", str(out), *common, *extra]) == 0
    return json.loads((out / "stats.json").read_text())


def _stamps(path: Path) -> np.ndarray:
    return np.array([float(line.split()[0]) for line in path.read_text().splitlines()
                     if line.strip() and not line.startswith("#")])


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("atlas")
    return {name: render_sequence(SEQUENCES[name].replace(width=320, height=240), root / name)
            for name in ("jump_back", "blackout_xyz")}


def test_jump_into_unmapped_part_starts_a_map_that_merges_back(renders: dict[str, Path], tmp_path: Path) -> None:
    """The cut to an unmapped wall loses tracking; after slam.new_map_after_s (1 s) a new
    map starts, and when the camera turns back the maps merge: every tracked frame ends in
    the first map's frame, with a small ATE over all of them."""
    seq = renders["jump_back"]
    stats = _run(seq, tmp_path / "run")
    assert stats["maps"] >= 2 and stats["merges"] >= 1
    assert stats["frames_outside_first_map"] == 0
    assert stats["trajectory_frames_by_map"] == {"0": stats["tracked_frames"]}
    # Lost only between the cut and the new map (1 s = 30 frames; the new map starts at once).
    assert stats["lost_frames"] <= 35
    assert stats["tracked_frames"] == stats["frames"] - stats["lost_frames"]
    assert stats["ate"]["rmse"] < 0.07


def test_threaded_jump_back_merges_right_or_not_at_all(renders: dict[str, Path], tmp_path: Path) -> None:
    """Threaded, tracking runs ahead of local mapping and loses the young second map on the
    turn back, then relocalises in the first map; loop closing's merge hint (the left map's
    last keyframes against the keyframes where tracking went on, bridged by the motion
    model) tries the merge, through the same checks as any (slam/orb/merge_check.py). Not
    deterministic: with the final checks merged in 1 of 6 runs on 2026-12-04 (within 2 cm
    at the weld); the others kept the maps apart, some candidates 15-24 cm / 6-8 deg off the
    truth (the left map's last keyframes, placed before local mapping caught up on the fast
    turn back, agree with each other but with no keyframe of the first map), others right
    but never confirmed by a keyframe of the first map (docs/results/merge_verification.md). Before the checks the hint
    merged in 24 of 24 runs, some ~50 cm off (global BA pulled them back to ~10 cm).

    So: a merge made puts every frame in the first map's frame with a small ATE; none made
    leaves the second map's frames in their own frame, and stats.json says which."""
    stats = _run(renders["jump_back"], tmp_path / "run", sequential=False)
    assert stats["maps"] >= 2
    runs = stats["trajectory_map_runs"]
    assert sum(n for _, n, _ in runs) == stats["tracked_frames"]
    if stats["merges"] >= 1:
        assert stats["frames_outside_first_map"] == 0
        assert stats["ate"]["rmse"] < 0.15
    else:
        assert stats["frames_outside_first_map"] == sum(n for _, n, m in runs if m != 0) > 0


def test_bridge_is_the_map_change_the_motion_model_implies() -> None:
    """Tracking's bridge across a relocalisation into another map: the last frame tracked in
    the left map, carried by the constant-velocity model over the gap, is the relocalised
    frame; ``S`` (new world <- left world) follows exactly for an exact motion."""
    from types import SimpleNamespace

    from semslam.slam.orb.atlas import AtlasFollower, LastTracked

    rng = np.random.default_rng(5)
    S = make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    V = make_pose(so3_exp([0.0, 0.03, 0.0]), [0.01, 0.0, 0.002])  # per frame, 30 Hz
    T_last = make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    dt = 1 / 30
    slam_map = SimpleNamespace(active_map=1)
    follower = AtlasFollower(SimpleNamespace(map=slam_map))  # type: ignore[arg-type]
    follower.last_tracked = LastTracked(10.0, T_last, V, dt, map_id=1)
    cur = SimpleNamespace(timestamp=10.0 + 3 * dt, T_cw=V @ V @ V @ T_last @ invert(S))  # 3 frames on, in S's world
    np.testing.assert_allclose(follower.bridge_to(cur), S, atol=1e-9)  # type: ignore[arg-type]
    cur.timestamp = 11.0  # too long a gap for the motion model
    assert follower.bridge_to(cur) is None  # type: ignore[arg-type]
    slam_map.active_map = 2  # the last tracked frame was in another map than the one left
    cur.timestamp = 10.0 + dt
    assert follower.bridge_to(cur) is None  # type: ignore[arg-type]


def test_blackout_new_map_right_after_it_and_one_trajectory(renders: dict[str, Path], tmp_path: Path) -> None:
    """Covered for 2 s while moving: every frame after the blackout is tracked (the new map
    is already due when the lens is uncovered), the maps merge, and the trajectory covers
    both sides of the blackout in one frame."""
    seq = renders["blackout_xyz"]
    cfg = SEQUENCES["blackout_xyz"]
    stats = _run(seq, tmp_path / "run")
    t_rgb = _stamps(seq / "rgb.txt")
    t_est = _stamps(tmp_path / "run" / "trajectory.txt")
    rel = t_rgb - t_rgb[0]
    end = cfg.blackout_start_s + cfg.blackout_s
    before, after = t_rgb[rel < cfg.blackout_start_s - 1e-6], t_rgb[rel >= end - 1e-6]
    assert np.isin(after, t_est).all(), "a frame after the blackout was left untracked"
    assert np.isin(before, t_est).all()
    assert stats["maps"] == 2 and stats["merges"] == 1 and stats["frames_outside_first_map"] == 0
    assert stats["ate"]["rmse"] < 0.05


def test_feature_off_is_orb_slam2(renders: dict[str, Path], tmp_path: Path) -> None:
    """slam.new_map_after_s=0: no new map, ever (ORB-SLAM2 stays lost until it relocalises)."""
    stats = _run(renders["blackout_xyz"], tmp_path / "run", "--set", "slam.new_map_after_s=0")
    assert stats["maps"] == 1 and stats["merges"] == 0
    assert stats["trajectory_frames_by_map"] == {"0": stats["tracked_frames"]}
    assert stats["lost_frames"] >= 60  # the blackout itself


def test_merge_transform_puts_the_weld_keyframe_where_the_match_says() -> None:
    """S (kept world <- moved world) from T12 maps kf's pose to ``T12 @ cand.T_cw``, and the
    other way round when cand's map is the one moved."""
    from types import SimpleNamespace

    from semslam.slam.orb.map_merging import merge_transform

    rng = np.random.default_rng(3)

    def pose() -> np.ndarray:
        return make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))

    kf, cand = SimpleNamespace(T_cw=pose()), SimpleNamespace(T_cw=pose())
    T12 = pose()
    S = merge_transform(kf, cand, T12, move_kf_map=True)  # type: ignore[arg-type]
    np.testing.assert_allclose(kf.T_cw @ invert(S), T12 @ cand.T_cw, atol=1e-9)
    S = merge_transform(kf, cand, T12, move_kf_map=False)  # type: ignore[arg-type]
    np.testing.assert_allclose(cand.T_cw @ invert(S), invert(T12) @ kf.T_cw, atol=1e-9)


def test_reroot_hangs_the_moved_tree_under_the_anchor() -> None:
    """The parent chain from the weld keyframe to its map's root is reversed (ORB-SLAM3):
    one tree, no cycle, children sets consistent with parents."""
    from semslam.slam.orb.map_merging import _reroot

    class Node:
        def __init__(self, name: str) -> None:
            self.name, self.parent, self.children = name, None, set()

    root, a, b, c, anchor = (Node(n) for n in ("root", "a", "b", "c", "anchor"))
    for child, parent in ((a, root), (b, a), (c, b)):
        child.parent = parent
        parent.children.add(child)
    _reroot(c, anchor)  # type: ignore[arg-type]
    assert (c.parent, b.parent, a.parent, root.parent) == (anchor, c, b, a)
    for n in (root, a, b, c, anchor):
        for ch in n.children:
            assert ch.parent is n
    node, seen = root, set()
    while node is not None:  # walks up to the anchor without a cycle
        assert node not in seen
        seen.add(node)
        node = node.parent
    assert anchor in seen
