"""Trajectory readers/writers: round trips, clear errors, agreement with evo's readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.errors import TrajectoryError
from semslam.geometry.se3 import make_pose, quat_to_rot, so3_exp
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import (
    detect_format,
    read_euroc_csv,
    read_kitti,
    read_trajectory,
    read_tum,
    write_tum,
)

GOOD = "1.0 0 0 0 0 0 0 1\n"


def _random_traj(n: int = 50, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    rots = np.stack([so3_exp(rng.normal(size=3)) for _ in range(n)])
    poses = make_pose(rots, rng.normal(scale=3.0, size=(n, 3)))
    stamps = 1305031102.0 + np.cumsum(rng.uniform(0.01, 0.05, n))
    return Trajectory(np.round(stamps, 6), poses, "random")


def test_tum_round_trip(tmp_path: Path) -> None:
    traj = _random_traj()
    path = tmp_path / "traj.txt"
    write_tum(path, traj)
    back = read_tum(path)
    assert len(back) == len(traj) == 50
    np.testing.assert_allclose(back.timestamps, traj.timestamps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.poses, traj.poses, rtol=0, atol=1e-8)
    assert back.positions.shape == (50, 3)
    assert back.name == str(path)


def test_written_tum_is_read_by_evo(tmp_path: Path) -> None:
    fi = pytest.importorskip("evo.tools.file_interface")
    traj = _random_traj(seed=1)
    path = tmp_path / "traj.txt"
    write_tum(path, traj)
    evo_traj = fi.read_tum_trajectory_file(str(path))
    np.testing.assert_allclose(evo_traj.timestamps, traj.timestamps, atol=1e-6)
    np.testing.assert_allclose(np.array(evo_traj.poses_se3), traj.poses, atol=1e-8)


def test_tum_separators_comments_and_repeated_stamps(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    path.write_text(
        "# header\n\n1.0,0,0,0,0,0,0,1\n"
        "2.0\t1 2 3\t0 0 0 2\n"  # unnormalised quaternion
        "2.0, 1, 2, 3, 0, 0, 0, 1,\n"  # repeated stamp, trailing comma
    )
    traj = read_tum(path)
    np.testing.assert_array_equal(traj.timestamps, [1.0, 2.0, 2.0])
    np.testing.assert_allclose(traj.poses[1], make_pose(np.eye(3), [1, 2, 3]))


@pytest.mark.parametrize(
    "content, expect",
    [
        (GOOD + "2.0 0 0 0 0 0 1\n", "line 2: expected 8 values"),
        (GOOD + "2.0 0 0 0 0 0 0 1 5\n", "line 2: expected 8 values"),
        ("# c\n" + GOOD + "2.0 0 0 x 0 0 0 1\n", "line 3: 'x' is not a number"),
        (GOOD + "2.0 0 nan 0 0 0 0 1\n", "line 2: non-finite"),
        (GOOD + "2.0 0 0 inf 0 0 0 1\n", "line 2: non-finite"),
        (GOOD + "2.0 0 0 0 0 0 0 0\n", "line 2: zero-length quaternion"),
        (GOOD + "3.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", "line 3: timestamp 0.500000 is before"),
        ("", "no poses found"),
        ("# only a comment\n\n", "no poses found"),
    ],
)
def test_tum_bad_input_names_file_and_line(tmp_path: Path, content: str, expect: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(TrajectoryError) as info:
        read_tum(path)
    assert str(path) in str(info.value)
    assert expect in str(info.value)
    assert info.value.path == path


def test_missing_file_and_directory(tmp_path: Path) -> None:
    for reader in (read_tum, read_kitti, read_euroc_csv, read_trajectory):
        with pytest.raises(TrajectoryError, match="file not found") as info:
            reader(tmp_path / "nope.txt")
        assert str(tmp_path / "nope.txt") in str(info.value)
    with pytest.raises(TrajectoryError, match="not a regular file"):
        read_tum(tmp_path)


def test_binary_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "bin.txt"
    path.write_bytes(b"\xff\xfe\x00\x81\x90" * 10)
    with pytest.raises(TrajectoryError, match="not a text file"):
        read_tum(path)


def test_kitti_reader_and_times(tmp_path: Path) -> None:
    traj = _random_traj(5)
    rows = traj.poses[:, :3, :].reshape(5, 12)
    path = tmp_path / "poses.txt"
    np.savetxt(path, rows)
    k = read_kitti(path)
    np.testing.assert_array_equal(k.timestamps, np.arange(5.0))
    np.testing.assert_allclose(k.poses, traj.poses, atol=1e-12)
    times = tmp_path / "times.txt"
    times.write_text("\n".join(f"{0.1 * i:e}" for i in range(5)) + "\n")
    k = read_kitti(path, times)
    np.testing.assert_allclose(k.timestamps, 0.1 * np.arange(5))
    times.write_text("0.0\n0.1\n")
    with pytest.raises(TrajectoryError, match="has 2 times but the pose file") as info:
        read_kitti(path, times)
    assert str(times) in str(info.value)


@pytest.mark.parametrize(
    "line, expect",
    [
        ("1 0 0 0 0 1 0 0 0 0 1\n", "line 2: expected 12 values"),
        ("2 0 0 0 0 1 0 0 0 0 1 0\n", "line 2: the 3x3 block is not a rotation"),
        ("-1 0 0 0 0 1 0 0 0 0 1 0\n", "line 2: the 3x3 block is not a rotation"),
        ("1 0 0 0 0 1 0 0 0 0 1 nan\n", "line 2: non-finite"),
    ],
)
def test_kitti_bad_input(tmp_path: Path, line: str, expect: str) -> None:
    path = tmp_path / "k.txt"
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" + line)
    with pytest.raises(TrajectoryError, match=expect) as info:
        read_kitti(path)
    assert str(path) in str(info.value)


def test_euroc_reader(tmp_path: Path) -> None:
    path = tmp_path / "data.csv"
    path.write_text(
        "#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z, v_x\n"
        "1403715524907143168,1,2,3,1,0,0,0,9\n"
        "1403715525007143168,1,2,3,0,1,0,0,9\n"
    )
    traj = read_euroc_csv(path)
    np.testing.assert_allclose(traj.timestamps, [1403715524.907143168, 1403715525.007143168])
    np.testing.assert_allclose(traj.poses[1, :3, :3], quat_to_rot([1, 0, 0, 0]))
    path.write_text("1403715524907143168,1,2,3,1,0,0\n")
    with pytest.raises(TrajectoryError, match="line 1: expected at least 8 values"):
        read_euroc_csv(path)


def test_format_detection(tmp_path: Path) -> None:
    tum = tmp_path / "a.txt"
    tum.write_text("# c\n" + GOOD)
    kitti = tmp_path / "b.txt"
    kitti.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    csv = tmp_path / "c.csv"
    csv.write_text("1403715524907143168,1,2,3,1,0,0,0\n")
    odd = tmp_path / "d.txt"
    odd.write_text("1 2 3 4 5\n")
    assert [detect_format(p) for p in (tum, kitti, csv)] == ["tum", "kitti", "euroc"]
    assert [len(read_trajectory(p)) for p in (tum, kitti, csv)] == [1, 1, 1]
    with pytest.raises(TrajectoryError, match="cannot detect the trajectory format: line 1 has 5"):
        read_trajectory(odd)
    with pytest.raises(TrajectoryError, match="only applies to KITTI"):
        read_trajectory(tum, times_path=tmp_path / "times.txt")
    with pytest.raises(TrajectoryError, match="unknown trajectory format"):
        read_trajectory(tum, fmt="bag")
    assert len(read_trajectory(tum, fmt="tum")) == 1


# --- real files against evo's readers ---------------------------------------------------


def test_real_files_match_evo_readers(shared_data: Path) -> None:
    fi = pytest.importorskip("evo.tools.file_interface")
    d = shared_data / "trajectories"
    for name in ("KITTI_00_gt.txt", "KITTI_00_ORB.txt"):
        ours = read_trajectory(d / name)
        theirs = np.array(fi.read_kitti_poses_file(str(d / name)).poses_se3)
        np.testing.assert_array_equal(ours.poses, theirs)
        np.testing.assert_array_equal(ours.timestamps, np.arange(len(theirs), dtype=float))
    with_times = read_kitti(d / "KITTI_00_gt.txt", d / "KITTI_00_gt_times.txt")
    np.testing.assert_array_equal(with_times.timestamps, np.loadtxt(d / "KITTI_00_gt_times.txt"))

    ours = read_trajectory(d / "V102_groundtruth.csv")
    theirs = fi.read_euroc_csv_trajectory(str(d / "V102_groundtruth.csv"))
    np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
    np.testing.assert_array_equal(ours.positions, theirs.positions_xyz)
    np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), rtol=0, atol=1e-12)

    for name in ("freiburg1_xyz-groundtruth.txt", "fr2_desk_ORB.txt", "V102.txt"):
        ours = read_trajectory(d / name)
        theirs = fi.read_tum_trajectory_file(str(d / name))
        np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
        np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), rtol=0, atol=1e-12)
