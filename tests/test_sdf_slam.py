"""The monocular SDF-SLAM tracker (``slam/sdf_slam*.py``): exact PnP, the two data
corrections on analytic cases, the ``sdf`` preset as shipped (SDFCNN's depth and classes) on a
short render, and recovery with the oracle depth (``ground_truth_depth``: the render's own
depth, which bounds the tracker, not SDFCNN).

The render is of the room SDFCNN was trained in (layout 0; other seeds, textures and paths):
the preset's bound here is a regression check, not the held-out measurement of the issue's
target (``test_sdf_held_out.py`` runs in layout 1, which no shipped network saw).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semslam.core.types import DescriptorKind, FeatureSpec
from semslam.features.matching import matcher_for
from semslam.geometry.se3 import invert, make_pose
from semslam.io.trajectory import read_trajectory
from semslam.slam.trackers.sdf_slam_correction import (DepthAlignment, Edge, TrackTable, ViewFeatures, candidate_pairs,
                                                       correct_poses, fit_depth_alignment, group_median, intersect_rays,
                                                       pair_constraint)
from semslam.slam.trackers.sdf_slam_pnp import PnpSettings, solve_pnp
from tests.conftest import run_cli

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _project(T_wc: np.ndarray, pts_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera points, pixels and visibility of world points."""
    pc = (pts_w - T_wc[:3, 3]) @ T_wc[:3, :3]
    z = np.where(pc[:, 2] > 0.1, pc[:, 2], 1.0)
    uv = pc[:, :2] / z[:, None] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    vis = (pc[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480)
    return pc, uv, vis


# ------------------------------------------------------------------------------ PnP (eqs. 9-10)
def test_pnp_recovers_the_exact_pose_among_outliers() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform([-2, -1.5, 2], [2, 1.5, 5], (200, 3))
    T = make_pose(_rot("y", 7.0) @ _rot("x", -4.0), np.array([0.1, -0.05, 0.2]))  # world -> camera
    pc = pts @ T[:3, :3].T + T[:3, 3]
    xy = pc[:, :2] / pc[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    xy[:40] += rng.uniform(20, 60, (40, 2))  # 20 % wrong matches
    found, inl = solve_pnp(pts, xy, K, PnpSettings())
    assert found is not None
    np.testing.assert_allclose(found, T, atol=1e-6)
    assert not inl[:40].any() and inl[40:].all()
    # Too few points for a pose: no pose, not a guess.
    assert solve_pnp(pts[:10], xy[:10], K, PnpSettings(min_inliers=25))[0] is None


# ------------------------------------------------------------------------------ local correction
def test_group_median_equals_a_per_group_loop() -> None:
    rng = np.random.default_rng(2)
    keys = rng.integers(0, 40, 300)
    vals = rng.normal(size=(300, 3))
    ids, med = group_median(keys, vals)
    np.testing.assert_array_equal(ids, np.unique(keys))
    for k, m in zip(ids, med):
        np.testing.assert_allclose(m, np.median(vals[keys == k], axis=0), atol=1e-12)


def test_local_correction_gives_one_position_per_track() -> None:
    """Three keyframes see one world point each through a different depth error; the track
    holds one position, the median of the three back-projections (the outlier does not pull it)."""
    poses = np.stack([make_pose(np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.0, 0.1, 0.2)])
    point = np.array([0.3, -0.2, 3.0])
    table = TrackTable()
    track = -1
    for k, err in enumerate((0.02, -0.01, 0.5)):  # metres along the ray; the last an outlier
        pc = point - poses[k, :3, 3]
        pc = pc * (1 + err / pc[2])
        other = np.array([[0.0, 0.0, 2.0 + k]])  # a point seen once: a track of its own
        ids = table.add(k, np.vstack([pc, other]), np.array([track, -1]))
        track = int(ids[0])
    tracks, pos = table.positions(poses)
    assert table.n_tracks == len(tracks) == 4  # one shared track + three single ones
    backprojected = [(point - poses[k, :3, 3]) * (1 + e / (point - poses[k, :3, 3])[2]) + poses[k, :3, 3]
                     for k, e in enumerate((0.02, -0.01, 0.5))]
    np.testing.assert_allclose(pos[tracks == track][0], np.median(backprojected, axis=0), atol=1e-12)
    assert np.linalg.norm(pos[tracks == track][0] - point) < 0.025 < np.linalg.norm(backprojected[2] - point)


# ------------------------------------------------------------------------------ global correction
def _scene_views(poses: np.ndarray, pts_w: np.ndarray, desc: np.ndarray) -> list[ViewFeatures]:
    views = []
    for T in poses:
        pc, uv, vis = _project(T, pts_w)
        views.append(ViewFeatures(uv[vis], desc[vis], pc[vis], np.ones(int(vis.sum()), bool)))
    return views


def test_global_correction_removes_injected_drift() -> None:
    """Twelve keyframes on a back-and-forth path; tracking's keyframe-to-keyframe edges carry
    a bias (0.6 deg of yaw and 1 cm per step: drift), so the chained poses drift away. Sampled
    keyframe pairs, solved by PnP from the exact views, add constraints; the pose graph pulls
    the keyframes back to within a fraction of the drift."""
    rng = np.random.default_rng(3)
    pts_w = rng.uniform([-3, -2, 3], [3, 2, 6], (600, 3))
    desc = rng.normal(size=(600, 32)).astype(np.float32)  # distinct descriptors: exact matches
    xs = 0.25 * np.sin(np.linspace(0, 2 * np.pi, 12))
    truth = np.stack([make_pose(_rot("y", 3 * x), np.array([x, 0.05 * k / 12, 0.0])) for k, x in enumerate(xs)])
    bias = make_pose(_rot("y", 0.6), np.array([0.01, 0.0, 0.0]))
    est, edges = [truth[0]], []
    for k in range(1, len(truth)):
        measured = invert(truth[k - 1]) @ truth[k] @ bias
        est.append(est[-1] @ measured)
        edges.append(Edge(k - 1, k, measured, 1.0, "tracking"))
    est = np.stack(est)
    drift = np.linalg.norm(est[:, :3, 3] - truth[:, :3, 3], axis=1).max()

    views = _scene_views(truth, pts_w, desc)
    spec = FeatureSpec(DescriptorKind.FLOAT, 32, 1.2, 1, th_low=1e9, th_high=1e9)
    pairs = candidate_pairs(est, set(), 12, 30, np.random.default_rng(0), 2.0, 40.0)
    assert pairs and all(j - i >= 2 for i, j in pairs)
    for i, j in pairs:
        found = pair_constraint(views[i], views[j], matcher_for(spec), 1e9, 0.9, K, PnpSettings(min_inliers=40))
        assert found is not None
        np.testing.assert_allclose(found[0], invert(truth[i]) @ truth[j], atol=1e-6)  # exact views: exact edge
        edges.append(Edge(i, j, found[0], found[1] / 100.0, "pair"))
    corrected = correct_poses(est, edges)
    after = np.linalg.norm(corrected[:, :3, 3] - truth[:, :3, 3], axis=1).max()
    assert drift > 0.05 and after < 0.2 * drift
    np.testing.assert_allclose(corrected[0], truth[0], atol=1e-9)  # keyframe 0 held


# ------------------------------------------------------------------------------ end to end
@pytest.fixture(scope="module")
def small_static(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``static_xyz``, 70 frames at 320x240 (half size: a few seconds to render)."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["static_xyz"].replace(frames=70, width=320, height=240)
    return render_sequence(cfg, tmp_path_factory.mktemp("sdf") / "static_xyz")


#: ATE bounds on the 70-frame 320x240 render, from what was measured, with margin: the preset
#: as shipped (FPFDCNN + range matcher, SDFCNN depth, the power depth alignment and triangulated
#: tracks: 1.55 cm Sim(3), 1.77 cm SE(3), scale 1.066 with the SDFCNN weights of 2026-11-29 evening;
#: 1.20 / 1.20 cm with the office-only ones before, 1.27 / 1.28 cm with neither alignment nor
#: triangulation; the earlier FPFDCNN weights gave 4.4 cm, scale 1.04-1.39) and with RootSIFT
#: instead (0.25 cm Sim(3), 0.51 cm SE(3), scale 1.033; office-only SDFCNN 0.29 / 0.43 cm); the
#: oracle depth (0.18 cm).
BOUNDS = {"fpfdcnn": (0.03, 0.04, 0.2), "sift": (0.015, 0.05, 0.2)}  # Sim(3) m, SE(3) m, |scale - 1|
ORACLE_ATE_SIM3_BOUND_M = 0.01


@pytest.mark.parametrize("extractor", ["fpfdcnn", "sift"])
def test_sdf_preset_tracks_a_render_with_bounded_sim3_ate(small_static: Path, tmp_path: Path, extractor: str) -> None:
    features = [] if extractor == "fpfdcnn" else ["--set", "features.extractor=sift", "--set", "features.matcher=default"]
    stats = run_cli(small_static, tmp_path / "run", "--preset", "sdf_paper", "--set", "slam.sequential=true", *features)
    sim3_bound, se3_bound, scale_bound = BOUNDS[extractor]
    assert stats["ate_alignment"] == "sim3" and stats["tracked_frames"] == stats["frames"] == 70
    assert stats["ate"]["rmse"] < sim3_bound
    # SE(3) only: reported beside it, finite, and SDFCNN's metric scale within the bound.
    assert np.isfinite(stats["ate_se3"]["rmse"]) and stats["ate"]["rmse"] - 1e-12 <= stats["ate_se3"]["rmse"]
    assert stats["ate_se3"]["rmse"] < se3_bound and abs(stats["ate_sim3_scale"] - 1.0) < scale_bound
    report = (tmp_path / "run" / "report.html").read_text()
    assert "Sim(3) aligned" in report and "SE(3) aligned, metric scale" in report
    # Local correction: one map point per feature track; the semantic cloud was written.
    assert stats["map_points"] > 500 and (tmp_path / "run" / "map" / "semantic_cloud.ply").is_file()
    # The Sim(3) number is evo's (evo_ape --align --correct_scale) on the written trajectory
    # (its text precision, 9 digits, is what separates the two: rel 1e-8 measured).
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core import sync
    from evo.tools import file_interface

    gt = file_interface.read_tum_trajectory_file(str(small_static / "groundtruth.txt"))
    est = file_interface.read_tum_trajectory_file(str(tmp_path / "run" / "trajectory.txt"))
    gt, est = sync.associate_trajectories(gt, est, max_diff=0.02)
    est.align(gt, correct_scale=True)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((gt, est))
    assert stats["ate"]["rmse"] == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-6)
    assert len(read_trajectory(tmp_path / "run" / "keyframes.txt")) == stats["keyframes"] >= 2
    json.loads((tmp_path / "run" / "config.json").read_text())["sdf_slam"]  # the section is recorded


def test_tracking_recovers_after_frames_without_features(small_static: Path) -> None:
    """With the oracle depth: six black frames (no keypoints: PnP fails) are lost, without a
    pose; the next real frame is matched again to the last keyframe by brute force from the
    constant-velocity prediction, and the trajectory stays within the oracle's bound."""
    from semslam.config import load_config
    from semslam.core.types import Frame, TrackingState
    from semslam.eval.metrics import ate
    from semslam.io.sequence import open_sequence
    from semslam.api import System

    # RootSIFT: the tracker's recovery is under test, not the shipped detector's quality.
    cfg = load_config("sdf_paper", ["slam.sequential=true", "maps.builders=[]", "dynamics.semantic=false",
                              "depth.source=ground_truth_depth", "features.extractor=sift",
                              "features.matcher=default"])
    seq = open_sequence(small_static, kind="mono")
    system = System(cfg, seq.camera)
    try:
        states = []
        for f in seq.frames(0, 40):
            if 16 <= f.index < 22:
                f = Frame(f.index, f.timestamp, np.zeros_like(f.rgb), None, f.rgb_path)
            states.append(system.track_frame(system.prepare(f)).state)
        traj = system.trajectory()
    finally:
        system.close()
    assert all(s is TrackingState.LOST for s in states[16:22])
    assert all(s is TrackingState.OK for s in states[:16] + states[22:])
    assert len(traj) == 34 and ate(read_trajectory(small_static / "groundtruth.txt"), traj, "sim3").stats["rmse"] < ORACLE_ATE_SIM3_BOUND_M


def test_rays_intersect_at_the_point_they_were_cast_through() -> None:
    rng = np.random.default_rng(5)
    points = rng.uniform([-1, -1, 2], [1, 1, 4], (30, 3))
    group = np.repeat(np.arange(30), 3)
    origins = rng.uniform(-0.3, 0.3, (90, 3))
    rays = points[group] - origins
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    found, spread = intersect_rays(group, 30, origins, rays)
    np.testing.assert_allclose(found, points, atol=1e-9)
    assert (spread > 0).all()
    # Two rays: the spread is their angle; one ray, or parallel rays, give no point.
    d = np.array([[0.0, 0.0, 1.0], [np.sin(0.1), 0.0, np.cos(0.1)], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0, 0, 1.0]])
    o = np.array([[0.0, 0, 0], [-0.2, 0, 0], [0, 0, 0], [0.5, 0, 0], [0, 0, 0]])
    found, spread = intersect_rays(np.array([0, 0, 1, 1, 2]), 3, o, d)
    assert spread[0] == pytest.approx(np.degrees(0.1)) and spread[1] == spread[2] == 0.0
    assert np.isfinite(found[0]).all() and np.isnan(found[1:]).all()


def test_triangulated_tracks_ignore_a_distorted_depth() -> None:
    """Keyframes whose depth is 30 % long: the median of their back-projections inherits it,
    the rays' intersection (rays spreading more than ``min_parallax_deg``) does not; with too
    little parallax the median stays."""
    rng = np.random.default_rng(6)
    pts_w = rng.uniform([-1, -1, 3], [1, 1, 5], (50, 3))
    poses = np.stack([make_pose(np.eye(3), np.array([x, 0.0, 0.0])) for x in (-0.3, 0.0, 0.3)])
    table = TrackTable()
    tracks = np.full(50, -1)
    for k, T in enumerate(poses):
        pc, _, _ = _project(T, pts_w)
        tracks = table.add(k, 1.3 * pc, tracks)
    ids, median = table.positions(poses)
    _, crossed = table.positions(poses, min_parallax_deg=2.0)
    assert np.abs(median - pts_w).max() > 0.5
    np.testing.assert_allclose(crossed, pts_w, atol=1e-9)
    _, too_narrow = table.positions(poses, min_parallax_deg=45.0)
    np.testing.assert_array_equal(too_narrow, median)
    # An intersection at under 0.6x the median's range is taken for a wrong match: the median stays.
    far = TrackTable()
    tracks = np.full(50, -1)
    for k, T in enumerate(poses):
        tracks = far.add(k, 2.0 * _project(T, pts_w)[0], tracks)
    np.testing.assert_array_equal(far.positions(poses, min_parallax_deg=2.0)[1], far.positions(poses)[1])


# ------------------------------------------------------------------------------ depth alignment
def test_depth_alignment_recovers_scale_and_power_among_outliers() -> None:
    rng = np.random.default_rng(3)
    z_map = rng.uniform(0.8, 5.0, 400)
    z_pred = 0.8 * z_map ** 1.5  # contrast exaggerated and scaled: z_map = 1.16 * z_pred ** (2 / 3)
    z_pred[:30] *= rng.uniform(1.5, 3.0, 30)  # 7.5 % wrong
    power = fit_depth_alignment(z_map, z_pred, "power", 50)
    assert power is not None and power.power == pytest.approx(2 / 3, abs=1e-9)
    assert power.log_scale == pytest.approx(-np.log(0.8) / 1.5, abs=1e-9)
    np.testing.assert_allclose(power.apply(z_pred[30:]), z_map[30:], rtol=1e-9)
    scale = fit_depth_alignment(z_map, z_map / 1.3, "scale", 50)
    assert scale is not None and scale.power == 1.0 and np.exp(scale.log_scale) == pytest.approx(1.3)
    # No depth stays no depth; too few points, or a fit that is no scale error, gives nothing.
    assert DepthAlignment(0.5, 1.0).apply(np.array([0.0, 4.0])).tolist() == [0.0, pytest.approx(2 * np.e)]
    assert fit_depth_alignment(z_map[:40], z_pred[:40], "power", 50) is None
    assert fit_depth_alignment(z_map, z_map / 3.0, "scale", 50) is None
    assert fit_depth_alignment(z_map, z_map ** 3, "power", 50) is None
    from semslam.config import load_config
    from semslam.errors import ConfigError

    with pytest.raises(ConfigError, match="sdf_slam.depth_alignment"):
        load_config("sdf_paper", ["sdf_slam.depth_alignment=affine"])


class _DriftingDepth:
    """The oracle depth with a scale and contrast that drift from frame to frame, as a depth
    network's do between views of a room it never saw: ``z' = s_k * z ** p_k``, scale
    0.75-1.25 and power 1-1.3 spread over the frames (a golden-ratio sequence)."""

    def __init__(self, oracle: object) -> None:
        self.oracle = oracle

    def depth(self, frame: object) -> np.ndarray | None:
        z = self.oracle.depth(frame)  # type: ignore[attr-defined]
        if z is None:
            return None
        u = (frame.index * 0.618034) % 1.0  # type: ignore[attr-defined]  # spread over [0, 1)
        out = np.zeros_like(z)
        out[z > 0] = (0.75 + 0.5 * u) * z[z > 0] ** (1.0 + 0.3 * u)
        return out


@pytest.mark.parametrize("alignment", ["scale", "power"])
def test_depth_alignment_keeps_the_map_scale_under_drifting_depth(small_static: Path, alignment: str) -> None:
    """Perfect depth made to wander (``_DriftingDepth``: scale 0.75-1.25, power 1-1.3 from frame
    to frame) breaks the paper's tracker, which takes every keyframe's depth as it comes; fitted
    to the map, the same depth keeps its scale and the trajectory its shape (measured: 2.69 cm
    Sim(3) without, 0.27 cm with "scale", 0.16 cm with "power"; triangulated tracks off, so the
    alignment alone is tested), and the stats report how far it wandered."""
    from semslam.config import load_config
    from semslam.eval.metrics import ate
    from semslam.io.sequence import open_sequence
    from semslam.api import System

    seq = open_sequence(small_static, kind="mono")
    gt = read_trajectory(small_static / "groundtruth.txt")
    errors = {}
    for mode in ("none", alignment):
        cfg = load_config("sdf_paper", ["slam.sequential=true", "maps.builders=[]", "dynamics.semantic=false",
                                  "depth.source=ground_truth_depth", "features.extractor=sift",
                                  "features.matcher=default", f"sdf_slam.depth_alignment={mode}",
                                  "sdf_slam.min_parallax_deg=0"])
        system = System(cfg, seq.camera)
        try:
            tracker = system.tracker
            tracker.depth = _DriftingDepth(tracker.depth)  # type: ignore[attr-defined]
            states = [system.track_frame(system.prepare(f)).state.name for f in seq.frames(0, 70)]
            traj = system.trajectory()
            stats = tracker.stats()
        finally:
            system.close()
        assert states.count("OK") == 70
        errors[mode] = ate(gt, traj, "sim3").stats["rmse"]
        if mode == "none":
            assert "depth_alignment_fits" not in stats
            continue
        # The wandering it corrected is reported: map / predicted ratios spread over >= 1.2x,
        # powers 1 for "scale" and spread for "power".
        lo, _, hi = stats["depth_alignment_ratio_p5_p50_p95"]
        assert stats["depth_alignment_fits"] >= 40 and hi / lo > 1.2, stats
        lo, _, hi = stats["depth_alignment_power_p5_p50_p95"]
        assert (lo == hi == 1.0) if alignment == "scale" else (hi - lo > 0.1), stats
    assert errors[alignment] < 0.3 * errors["none"] and errors[alignment] < ORACLE_ATE_SIM3_BOUND_M, errors
