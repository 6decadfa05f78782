"""ATE/RPE/association must reproduce evo: computed with evo itself here, and against the
result archives evo wrote for KITTI 00 (``evo_reference_results``)."""

from __future__ import annotations

import copy
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semslam.errors import EvalError
from semslam.eval import associate, ate, error_stats, match_timestamps, rpe
from semslam.eval.metrics import STAT_NAMES, pairs_by_time
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import read_trajectory

evo_metrics = pytest.importorskip("evo.core.metrics")
sync = pytest.importorskip("evo.core.sync")
fi = pytest.importorskip("evo.tools.file_interface")
PoseTrajectory3D = pytest.importorskip("evo.core.trajectory").PoseTrajectory3D

#: Relative agreement with evo, as the README states it. Measured worst over every check
#: here: 3.2e-12 on a statistic, 4.8e-12 on one pose's error (EuRoC RPE, a tiny error),
#: 2.3e-13 m on an aligned position (KITTI, positions of hundreds of metres).
REL = 1e-10
MAX_DIFF = 0.02

CASES = {
    "fr1_rgbdslam": ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", None),
    "fr2_orb": ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", None),
    "kitti_orb": ("KITTI_00_gt.txt", "KITTI_00_ORB.txt", "KITTI_00_gt_times.txt"),
    "euroc_v102": ("V102_groundtruth.csv", "V102.txt", None),
}
# RPE deltas in metres: TUM/EuRoC sequences are a few metres long, KITTI 00 is 3.7 km.
METERS = {"fr1_rgbdslam": 0.5, "fr2_orb": 0.5, "kitti_orb": 10.0, "euroc_v102": 0.5}


def _evo_read(path: Path, times: Path | None):
    if times is not None:
        poses = fi.read_kitti_poses_file(str(path)).poses_se3
        return PoseTrajectory3D(poses_se3=poses, timestamps=np.loadtxt(times))
    if path.suffix == ".csv":
        return fi.read_euroc_csv_trajectory(str(path))
    return fi.read_tum_trajectory_file(str(path))


@pytest.fixture(scope="module")
def loaded(shared_data: Path) -> dict[str, tuple]:
    """Per case: (our gt, our est, evo gt, evo est) read from the real files."""
    d = shared_data / "trajectories"
    out = {}
    for case, (gt_name, est_name, times_name) in CASES.items():
        times = d / times_name if times_name else None
        out[case] = (
            read_trajectory(d / gt_name, times_path=times),
            read_trajectory(d / est_name, times_path=times),
            _evo_read(d / gt_name, times),
            _evo_read(d / est_name, times),
        )
    return out


def _evo_synced(loaded, case: str, align: str):
    _, _, g, e = loaded[case]
    g_s, e_s = sync.associate_trajectories(g, e, max_diff=MAX_DIFF)
    e_s = copy.deepcopy(e_s)
    if align != "none":
        e_s.align(g_s, correct_scale=align == "sim3")
    return g_s, e_s


def _close(ours: dict[str, float], theirs: dict[str, float]) -> None:
    for name in STAT_NAMES:
        assert ours[name] == pytest.approx(theirs[name], rel=REL, abs=1e-15), name


def _close_arrays(ours: np.ndarray, theirs: np.ndarray) -> None:
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(ours, theirs, rtol=REL, atol=1e-12 * max(1.0, float(np.max(theirs))))


# --- association -----------------------------------------------------------------------


@pytest.mark.parametrize("case", list(CASES))
def test_association_equals_evo(loaded, case: str) -> None:
    gt, est, g, e = loaded[case]
    g_s, e_s = sync.associate_trajectories(g, e, max_diff=MAX_DIFF)
    idx_gt, idx_est = associate(gt.timestamps, est.timestamps, MAX_DIFF)
    np.testing.assert_array_equal(gt.timestamps[idx_gt], g_s.timestamps)
    np.testing.assert_array_equal(est.timestamps[idx_est], e_s.timestamps)
    np.testing.assert_array_equal(gt.positions[idx_gt], g_s.positions_xyz)
    np.testing.assert_array_equal(est.positions[idx_est], e_s.positions_xyz)


def _indexed_traj(stamps: list[float]):
    """A trajectory whose x coordinate is the pose index, to read indices back after sync."""
    n = len(stamps)
    xyz = np.zeros((n, 3))
    xyz[:, 0] = np.arange(n)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return PoseTrajectory3D(xyz, quat, np.asarray(stamps, dtype=float))


stamp_lists = st.lists(st.integers(0, 60), min_size=1, max_size=25)


@settings(max_examples=200, deadline=None)
@given(
    ref=stamp_lists,
    est=stamp_lists,
    max_diff=st.sampled_from([0.0, 1.0, 2.0, 3.5]),
    offset=st.integers(-4, 4),
    sort_ref=st.booleans(),
    sort_est=st.booleans(),
)
def test_association_equals_evo_on_ties_repeats_and_unsorted(
    ref, est, max_diff, offset, sort_ref, sort_est
) -> None:
    # Integer stamps make exact ties and repeated stamps common.
    ref = sorted(ref) if sort_ref else ref
    est = sorted(est) if sort_est else est
    idx_ref, idx_est = associate(ref, est, max_diff, float(offset))
    try:
        g_s, e_s = sync.associate_trajectories(
            _indexed_traj(ref), _indexed_traj(est), max_diff=max_diff, offset_2=float(offset)
        )
    except sync.SyncException:
        assert len(idx_ref) == len(idx_est) == 0
        return
    np.testing.assert_array_equal(idx_ref, g_s.positions_xyz[:, 0].astype(int))
    np.testing.assert_array_equal(idx_est, e_s.positions_xyz[:, 0].astype(int))


def _tum_associate_reference(first: list[float], second: list[float], max_diff: float, offset: float):
    """TUM associate.py's algorithm, written out directly (quadratic) for comparison."""
    cands = sorted(
        (abs(a - (b + offset)), a, b)
        for a in first
        for b in second
        if abs(a - (b + offset)) < max_diff
    )
    free_a, free_b, out = set(first), set(second), []
    for _, a, b in cands:
        if a in free_a and b in free_b:
            free_a.remove(a)
            free_b.remove(b)
            out.append((a, b))
    return sorted(out)


@settings(max_examples=200, deadline=None)
@given(
    first=st.sets(st.integers(0, 80), min_size=1, max_size=25),
    second=st.sets(st.integers(0, 80), min_size=1, max_size=25),
    max_diff=st.sampled_from([0.5, 1.0, 2.0, 5.0]),
    offset=st.integers(-3, 3),
)
def test_match_timestamps_is_tum_associate(first, second, max_diff, offset) -> None:
    a = np.array(sorted(first), dtype=float) * 0.01
    b = np.random.default_rng(len(second)).permutation(np.array(sorted(second), dtype=float)) * 0.01
    md, off = max_diff * 0.01, offset * 0.01
    ia, ib = match_timestamps(a, b, md, off)
    expected = _tum_associate_reference(list(a), list(b), md, off)
    assert list(zip(a[ia].tolist(), b[ib].tolist())) == expected
    assert len(set(ia.tolist())) == len(ia) and len(set(ib.tolist())) == len(ib)


def test_evo_and_tum_association_differ_on_dense_streams() -> None:
    """evo lets two reference stamps share one estimate stamp; associate.py does not."""
    ref, est = [1.0, 1.01], [1.004, 2.0, 3.0]
    assert [x.tolist() for x in associate(ref, est, 0.02)] == [[0, 1], [0, 0]]
    assert [x.tolist() for x in match_timestamps(ref, est, 0.02)] == [[0], [0]]


def test_pairs_by_time_follow_tum_fixed_delta() -> None:
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.02, 0.05, 200))
    pairs = pairs_by_time(t, 1.0)
    for i, j in pairs:
        target = t[i] + 1.0
        assert abs(t[j] - target) == np.min(np.abs(t - target))
    starts = set(pairs[:, 0].tolist())
    # every start whose closest pose is not the last one is used
    for i in range(len(t)):
        j = int(np.argmin(np.abs(t - (t[i] + 1.0))))
        assert (i in starts) == (j != len(t) - 1 and j > i)


# --- ATE -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "case, align",
    [
        ("fr1_rgbdslam", "se3"),
        ("fr1_rgbdslam", "none"),
        ("fr1_rgbdslam", "sim3"),
        ("fr2_orb", "se3"),
        ("fr2_orb", "sim3"),
        ("kitti_orb", "se3"),
        ("kitti_orb", "sim3"),
        ("euroc_v102", "se3"),
    ],
)
def test_ate_equals_evo(loaded, case: str, align: str) -> None:
    gt, est, _, _ = loaded[case]
    g_s, e_s = _evo_synced(loaded, case, align)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((g_s, e_s))
    ours = ate(gt, est, align=align, max_diff=MAX_DIFF)
    assert ours.n_associated == g_s.num_poses
    _close(ours.stats, ape.get_all_statistics())
    _close_arrays(ours.errors, ape.error)
    np.testing.assert_allclose(ours.aligned.positions, e_s.positions_xyz, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(ours.timestamps, e_s.timestamps)


# --- RPE -------------------------------------------------------------------------------

# evo computes rotation errors pose pair by pose pair (slow), so the long sequences get the
# settings with few pairs; fr1_xyz covers every setting.
ALL_SETTINGS = [
    (1, "frames", False),
    (10, "frames", False),
    (10, "frames", True),
    ("m", "meters", False),
    ("m", "meters", True),
]
RPE_CASES = (
    [("fr1_rgbdslam", "se3", *s) for s in ALL_SETTINGS]
    + [("fr1_rgbdslam", "sim3", *s) for s in (ALL_SETTINGS[0], ALL_SETTINGS[3], ALL_SETTINGS[4])]
    + [("fr2_orb", "none", *s) for s in (ALL_SETTINGS[1], ALL_SETTINGS[3])]
    + [("fr2_orb", "sim3", *ALL_SETTINGS[3])]
    + [("kitti_orb", "none", *s) for s in (ALL_SETTINGS[1], ALL_SETTINGS[3])]
    + [("euroc_v102", "se3", *ALL_SETTINGS[0])]
)


@pytest.mark.parametrize("case, align, delta, unit, all_pairs", RPE_CASES)
def test_rpe_equals_evo(loaded, case: str, align: str, delta, unit: str, all_pairs: bool) -> None:
    gt, est, _, _ = loaded[case]
    if delta == "m":
        delta = METERS[case]
    g_s, e_s = _evo_synced(loaded, case, align)
    evo_unit = evo_metrics.Unit.frames if unit == "frames" else evo_metrics.Unit.meters
    theirs = {}
    for key, relation in (
        ("trans", evo_metrics.PoseRelation.translation_part),
        ("rot", evo_metrics.PoseRelation.rotation_angle_deg),
    ):
        metric = evo_metrics.RPE(relation, delta, evo_unit, 0.1, all_pairs)
        metric.process_data((g_s, e_s))
        theirs[key] = metric
    ours = rpe(gt, est, delta=delta, delta_unit=unit, align=align, max_diff=MAX_DIFF,
               all_pairs=all_pairs)
    assert ours.pairs[:, 1].tolist() == theirs["trans"].delta_ids
    _close(ours.trans_stats, theirs["trans"].get_all_statistics())
    _close(ours.rot_stats, theirs["rot"].get_all_statistics())
    _close_arrays(ours.trans_errors, theirs["trans"].error)
    _close_arrays(ours.rot_errors, theirs["rot"].error)


def test_rpe_pairs_from_reference_equals_evo(loaded) -> None:
    gt, est, _, _ = loaded["fr2_orb"]
    g_s, e_s = _evo_synced(loaded, "fr2_orb", "sim3")
    metric = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, 0.5,
                             evo_metrics.Unit.meters, 0.1, False, pairs_from_reference=True)
    metric.process_data((g_s, e_s))
    ours = rpe(gt, est, delta=0.5, delta_unit="meters", align="sim3", pairs_from_reference=True)
    _close(ours.trans_stats, metric.get_all_statistics())


# --- evo's own result archives (KITTI 00, ORB-SLAM) ------------------------------------


def _archive(shared_data: Path, name: str, tmp_path: Path) -> tuple[dict, dict, np.ndarray]:
    out = tmp_path / name
    with zipfile.ZipFile(shared_data / "evo_reference_results" / f"{name}.zip") as zf:
        zf.extractall(out)
    info = json.loads((out / "info.json").read_text())
    stats = json.loads((out / "stats.json").read_text())
    loaded = np.load(out / "error_array.npz")  # evo stores a plain .npy under this name
    errors = loaded if isinstance(loaded, np.ndarray) else loaded[loaded.files[0]]
    return info, stats, errors


def _kitti(shared_data: Path) -> tuple[Trajectory, Trajectory]:
    d = shared_data / "trajectories"
    return read_trajectory(d / "KITTI_00_gt.txt"), read_trajectory(d / "KITTI_00_ORB.txt")


def test_kitti_orb_ape_matches_evo_archive(shared_data: Path, tmp_path: Path) -> None:
    info, stats, errors = _archive(shared_data, "orb_ape", tmp_path)
    assert info["est_name"].endswith("KITTI_00_ORB.txt")
    assert "translation part" in info["title"]
    align = "se3" if "SE(3) Umeyama" in info["title"] else "sim3" if "Sim(3)" in info["title"] else "none"
    assert align == "se3"
    gt, est = _kitti(shared_data)
    ours = ate(gt, est, align=align)
    _close(ours.stats, stats)
    _close_arrays(ours.errors, errors)


def test_kitti_orb_rpe_matches_evo_archive(shared_data: Path, tmp_path: Path) -> None:
    info, stats, errors = _archive(shared_data, "orb_rpe", tmp_path)
    title = info["title"]
    assert "translation part" in title and "not aligned" in title
    m = re.search(r"delta = ([0-9.]+) \((m|frames)\) using (consecutive|all) pairs", title)
    assert m is not None, title
    delta, unit = float(m.group(1)), {"m": "meters", "frames": "frames"}[m.group(2)]
    gt, est = _kitti(shared_data)
    ours = rpe(gt, est, delta=delta, delta_unit=unit, align="none",
               all_pairs=m.group(3) == "all")
    # The archive was written by an older evo whose consecutive path filter did not start
    # the first pair at pose 0; evo 1.38 (and semslam) add that pair (0, j1). Everything
    # after it is identical.
    assert len(ours.trans_errors) == len(errors) + 1
    _close_arrays(ours.trans_errors[1:], errors)
    _close(error_stats(ours.trans_errors[1:]), stats)


# --- errors ----------------------------------------------------------------------------


def _line(n: int, t0: float, name: str) -> Trajectory:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 0.1
    poses[:, 1, 3] = np.sin(np.arange(n))
    return Trajectory(t0 + np.arange(n) * 0.1, poses, name)


def test_too_few_associated_poses_names_both_files() -> None:
    gt, est = _line(20, 0.0, "gt.txt"), _line(20, 100.0, "est.txt")
    with pytest.raises(EvalError, match=r"only 0 poses of est.txt .* gt.txt"):
        ate(gt, est)
    with pytest.raises(EvalError, match="need at least 3"):
        rpe(gt, _line(2, 0.0, "est.txt"))


def test_bad_rpe_settings_are_errors() -> None:
    gt, est = _line(20, 0.0, "gt.txt"), _line(20, 0.0, "est.txt")
    with pytest.raises(EvalError, match="gives no pose pairs"):
        rpe(gt, est, delta=50)
    with pytest.raises(EvalError, match="whole number"):
        rpe(gt, est, delta=1.5)
    with pytest.raises(EvalError, match="unknown delta unit"):
        rpe(gt, est, delta_unit="degrees")
    with pytest.raises(EvalError, match="unknown alignment"):
        ate(gt, est, align="affine")
    assert rpe(gt, est, delta=0.5, delta_unit="seconds").trans_stats["max"] < 1e-12


# --- EuRoC ground truth as the camera's trajectory (stereo inputs, issue 41) -------------

#: EuRoC V1's cam0 T_BS (mav0/cam0/sensor.yaml): cam0's pose in the body (IMU) frame.
EUROC_V1_T_BS_CAM0 = np.array([
    [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
    [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
    [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
    [0.0, 0.0, 0.0, 1.0]])


def test_euroc_camera_groundtruth_equals_evo_transform(shared_data: Path) -> None:
    """The cam0 trajectory of V1_02's body ground truth, T_WB @ T_BS, is what evo gives for
    ``transform(T_BS, right_mul=True)`` on its own reading of the file."""
    from semslam.io.stereo_sequence import euroc_camera_trajectory
    from semslam.io.trajectory import read_euroc_csv

    path = shared_data / "trajectories" / "V102_groundtruth.csv"
    ours = euroc_camera_trajectory(read_euroc_csv(path), EUROC_V1_T_BS_CAM0)
    theirs = fi.read_euroc_csv_trajectory(str(path))
    theirs.transform(EUROC_V1_T_BS_CAM0, right_mul=True)
    np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
    np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), rtol=0, atol=1e-12)
    # the camera is off the body by T_BS's lever arm (about 7 cm), everywhere
    lever = np.linalg.norm(ours.positions - read_euroc_csv(path).positions, axis=1)
    np.testing.assert_allclose(lever, np.linalg.norm(EUROC_V1_T_BS_CAM0[:3, 3]), rtol=1e-9)


def test_kitti_stereo_folder_groundtruth_equals_evo(shared_data: Path, tmp_path: Path) -> None:
    """A KITTI odometry folder holding sequence 00's real poses.txt and times.txt: the ground
    truth ``semslam run`` evaluates against (the TUM file the stereo reader writes) has evo's
    poses (``read_kitti_poses_file``) at times.txt's stamps."""
    from semslam.io.sequence import open_sequence
    from semslam.io.trajectory import read_tum

    d = shared_data / "trajectories"
    root = tmp_path / "00"
    n = len([ln for ln in (d / "KITTI_00_gt_times.txt").read_text().splitlines() if ln.strip()])
    for side in ("image_0", "image_1"):
        (root / side).mkdir(parents=True)
        for k in range(n):
            (root / side / f"{k:06d}.png").touch()  # the reader lists them; no frame is read here
    p0 = "7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
    p1 = "7.188560e+02 0 6.071928e+02 -3.861448e+02 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
    (root / "calib.txt").write_text(f"P0: {p0}\nP1: {p1}\n")
    (root / "poses.txt").write_text((d / "KITTI_00_gt.txt").read_text())
    (root / "times.txt").write_text((d / "KITTI_00_gt_times.txt").read_text())
    seq = open_sequence(root)
    assert seq.calibration.baseline == pytest.approx(386.1448 / 718.856, rel=1e-9)
    ours = read_tum(seq.groundtruth_path)
    theirs = fi.read_kitti_poses_file(str(d / "KITTI_00_gt.txt"))
    np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), rtol=0, atol=1e-6)
    np.testing.assert_allclose(ours.timestamps, np.loadtxt(d / "KITTI_00_gt_times.txt"), rtol=0, atol=1e-6)
