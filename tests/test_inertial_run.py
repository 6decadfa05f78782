"""Visual-inertial runs end to end (issue 42): an EuRoC-layout render with a simulated IMU,
the camera covered for 1.5 s while it moves, through ``semslam run`` as RGB-D-inertial
(cam0 + depth0) and stereo-inertial (cam0 + cam1), and through the API.

Without the IMU the blackout's frames are lost (and a second map is started); with it every
frame is posed, the blind stretch by the IMU alone and then re-posed between the tracked
ends, and the trajectory stays at the accuracy of vision (evo's ATE, against the render's
exact ground truth). The inputs' checks give one line naming the file.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from semslam.eval.gravity import gravity_tilt_deg
from semslam.io.trajectory import read_tum
from tests.conftest import evo_ate, run_cli

FRAMES = 150
BLACKOUT = (1.5, 1.5)  # start, seconds: frames 45-89 are black
BLACK_FRAMES = 45


@pytest.fixture(scope="module")
def euroc_blackout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    cfg = replace(SEQUENCES["blackout_xyz"], frames=FRAMES, width=320, height=240, blackout_start_s=BLACKOUT[0],
                  blackout_s=BLACKOUT[1], imu=True, euroc_depth=True, stereo_baseline=0.11)
    return render_sequence(cfg, tmp_path_factory.mktemp("vi") / "blackout", progress=False, layout_format="euroc")


@pytest.mark.slow
@pytest.mark.parametrize("sensor", ["rgbd", "stereo"])
def test_blackout_bridged_by_the_imu(euroc_blackout: Path, tmp_path: Path, sensor: str) -> None:
    # Measured (320x240, seed 13): RGB-D-inertial 0.62 cm over all 150 frames (the 45 blind
    # ones at most 0.51 cm off), stereo-inertial 1.39 cm (1.6); without the IMU the black
    # frames are lost and the 105 others 1.40 / 1.67 cm.
    common = ["--preset", "default", "--sensor", sensor, "--sequential", "--no-report"]
    with_imu = run_cli(euroc_blackout, tmp_path / "imu", *common)
    without = run_cli(euroc_blackout, tmp_path / "vis", *common, "--set", "imu.use=false")
    assert without["tracked_frames"] <= FRAMES - BLACK_FRAMES + 2
    assert with_imu["tracked_frames"] == FRAMES and with_imu["lost_frames"] == 0
    assert with_imu["maps"] == 1
    assert with_imu["imu_initialisations"] == 1 and with_imu["imu_init_frame"] <= 31
    assert with_imu["imu_only_frames"] == BLACK_FRAMES == with_imu["imu_bridged_frames"]
    # Each black frame after the first searched the local map from the IMU's pose before the
    # IMU posed it.
    assert with_imu["imu_local_map_searches"] >= BLACK_FRAMES - 1
    (span,) = with_imu["imu_only_spans"]
    assert span[2] == BLACK_FRAMES
    gt = euroc_blackout / "groundtruth_cam0.txt"
    _write_cam0_groundtruth(euroc_blackout, gt)
    ate = evo_ate(gt, tmp_path / "imu" / "trajectory.txt")
    # The map is turned so gravity points down its z axis (ORB-SLAM3's gravity-aligned
    # world): the turn applied first is the one from the first camera's frame, and the
    # trajectory, aligned to the render's (whose gravity is -z) by evo, needs no tilt.
    from evo.tools import file_interface

    first = file_interface.read_tum_trajectory_file(str(gt)).poses_se3[0]
    g_first = first[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    assert with_imu["imu_gravity_alignments"][0][1] == pytest.approx(np.degrees(np.arccos(-g_first[2])), abs=2.0)
    np.testing.assert_allclose(with_imu["imu_gravity"], [0.0, 0.0, -9.81], atol=0.2)
    assert gravity_tilt_deg(read_tum(gt), read_tum(tmp_path / "imu" / "trajectory.txt")) < 2.0
    assert without.get("imu_gravity_alignments") is None
    ate, ate_without = evo_ate(gt, tmp_path / "imu" / "trajectory.txt"), evo_ate(gt, tmp_path / "vis" / "trajectory.txt")
    bound = {"rgbd": 0.01, "stereo": 0.025}[sensor]  # stereo at 320x240 is 1.6-2.6 cm without a blackout
    assert ate < bound and ate < 1.2 * ate_without, (ate, ate_without)
    # The blind stretch itself, against the ground truth after the run's own alignment.
    assert _blind_error(gt, tmp_path / "imu" / "trajectory.txt", span) < 1.5 * bound


def _write_cam0_groundtruth(root: Path, dest: Path) -> None:
    """cam0's ground truth as evo reads EuRoC's (the body's poses) times cam0's T_BS."""
    from evo.tools import file_interface

    from semslam.synth.euroc_writer import T_BS_CAM0

    if dest.exists():
        return
    body = file_interface.read_euroc_csv_trajectory(str(root / "mav0" / "state_groundtruth_estimate0" / "data.csv"))
    body.transform(T_BS_CAM0, right_mul=True)
    file_interface.write_tum_trajectory_file(str(dest), body)


def _blind_error(gt_path: Path, est_path: Path, span: list[float]) -> float:
    """Largest position error over the IMU-only frames, SE(3)-aligned on every frame (evo)."""
    from evo.core import sync
    from evo.tools import file_interface

    ref, est = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt_path)),
                                           file_interface.read_tum_trajectory_file(str(est_path)), max_diff=0.02)
    est.align(ref)
    err = np.linalg.norm(est.positions_xyz - ref.positions_xyz, axis=1)
    blind = (est.timestamps >= span[0] - 1e-6) & (est.timestamps <= span[1] + 1e-6)
    assert blind.sum() == span[2]
    return float(err[blind].max())


@pytest.mark.slow
def test_api_track_with_readings(euroc_blackout: Path, tmp_path: Path) -> None:
    # The same render through System.track(rgb, depth, t, imu=readings): the API and the
    # CLI pose the blind frames alike; here with the opt-in pose prior (tracking's pose
    # optimisation held near the IMU's prediction), which keeps the CLI run's accuracy.
    from semslam import System
    from semslam.io.imu import open_imu
    from semslam.io.sequence import open_sequence
    from semslam.io.trajectory import write_tum

    seq = open_sequence(euroc_blackout, kind="rgbd")
    stream = open_imu(euroc_blackout)
    assert stream is not None
    overrides = ["slam.sequential=true", "imu.pose_prior=true"]
    with System("default", seq.camera, imu=stream.calibration, overrides=overrides) as system:
        posed = []
        for frame in seq:
            s = frame.imu
            assert s is not None
            readings = list(zip(s.t, s.gyro, s.acc))
            result = system.track(frame.rgb, frame.depth, frame.timestamp, imu=readings)
            posed.append(result.posed_by)
    assert posed.count("inertial") == BLACK_FRAMES
    assert system.trajectory().timestamps.size == FRAMES
    gt, est = tmp_path / "gt.txt", tmp_path / "trajectory.txt"
    _write_cam0_groundtruth(euroc_blackout, gt)
    write_tum(est, system.trajectory())
    assert evo_ate(gt, est) < 0.01


def test_api_checks_the_readings(euroc_blackout: Path) -> None:
    from semslam import System
    from semslam.core.imu import ADIS16448, ImuCalibration
    from semslam.errors import ConfigError, DataError
    from semslam.io.sequence import open_sequence

    seq = open_sequence(euroc_blackout, kind="rgbd")
    frame = seq.load(0)
    reading = (frame.timestamp - 0.01, np.zeros(3), np.array([0.0, 0.0, 9.81]))
    with System("orb", seq.camera, overrides=["slam.sequential=true"]) as plain:
        with pytest.raises(ConfigError, match="no IMU calibration"):
            plain.track(frame.rgb, frame.depth, frame.timestamp, imu=[reading])
    with System("orb", seq.camera, imu=ImuCalibration(ADIS16448), overrides=["slam.sequential=true"]) as system:
        with pytest.raises(DataError, match="not after the one before"):
            system.track(frame.rgb, frame.depth, frame.timestamp, imu=[reading, reading])
        with pytest.raises(DataError, match="after the frame"):
            system.track(frame.rgb, frame.depth, frame.timestamp, imu=[(frame.timestamp + 0.01, *reading[1:])])
        with pytest.raises(DataError, match="7 numbers|expected"):
            system.track(frame.rgb, frame.depth, frame.timestamp, imu=np.zeros((3, 4)))


def test_bad_imu_files_are_one_line(euroc_blackout: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # A copy whose IMU readings go back in time, and one whose recording stops before the
    # frames do: `semslam run` exits 2 with one line naming imu0/data.csv.
    import shutil

    from semslam.cli.main import main

    for case in ("backwards", "short"):
        root = tmp_path / case
        shutil.copytree(euroc_blackout / "mav0" / "imu0", root / "mav0" / "imu0")
        for sub in ("cam0", "depth0", "state_groundtruth_estimate0"):
            (root / "mav0" / sub).symlink_to(euroc_blackout / "mav0" / sub)
        csv = root / "mav0" / "imu0" / "data.csv"
        lines = csv.read_text().splitlines()
        lines = lines[:200] + [lines[150]] + lines[200:] if case == "backwards" else lines[: len(lines) // 2]
        csv.write_text("\n".join(lines) + "\n")
        code = main(["run", str(root), "--out", str(tmp_path / f"out_{case}"), "--quiet", "--preset", "orb"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2, err
        assert len(err) == 1 and "imu0/data.csv" in err[0], err
