"""Monocular-inertial end to end (issue 42): an EuRoC-layout render with a simulated IMU
(ADIS16448 noise, seeded biases) through ``semslam run --preset mono`` on cam0 alone, and the
same frames and readings through the API.

A monocular map has no metres; the IMU's initialisation estimates its scale once the motion
shows it (``imu.max_scale_spread``) and the map, tracking's state and the frames already
recorded are scaled, so the trajectory is metric: evo's SE(3) ATE (no scale correction) is
near the Sim(3) one and evo's Sim(3) scale is near 1. Without the IMU the map keeps the
two-view scale (median depth 1) and its SE(3) ATE is the size of the path.

Measured (static_xyz, seed 13, 640x480, 240 frames; two-view initialisation at frame 29): the
scale taken 4.0 s later with a 3.7 % spread, corrected 1 and 3 s after (x0.926, x0.979; spreads
2.4, 1.5 %); evo's Sim(3) scale 0.989, SE(3) ATE 0.53 cm against Sim(3) 0.44 cm (visual only:
Sim(3) 0.44 cm, the same, and SE(3) 19 cm).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import evo_ate, run_cli

FRAMES = 240
BLACKOUT = (3.0, 1.5)  # start, seconds: frames 90-134 are black
BLACK_FRAMES = 45


@pytest.fixture(scope="module")
def euroc_mono(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    cfg = replace(SEQUENCES["static_xyz"], frames=FRAMES, seed=13, imu=True)
    return render_sequence(cfg, tmp_path_factory.mktemp("mono_vi") / "static", progress=False,
                           layout_format="euroc")


@pytest.fixture(scope="module")
def euroc_mono_blackout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    cfg = replace(SEQUENCES["blackout_xyz"], frames=200, seed=13, imu=True, blackout_start_s=BLACKOUT[0],
                  blackout_s=BLACKOUT[1])
    return render_sequence(cfg, tmp_path_factory.mktemp("mono_vi") / "blackout", progress=False,
                           layout_format="euroc")


def _cam0_groundtruth(root: Path, dest: Path) -> Path:
    """cam0's ground truth (EuRoC's body poses times cam0's T_BS), as evo reads it."""
    from evo.tools import file_interface

    from semslam.synth.euroc_writer import T_BS_CAM0

    body = file_interface.read_euroc_csv_trajectory(str(root / "mav0" / "state_groundtruth_estimate0" / "data.csv"))
    body.transform(T_BS_CAM0, right_mul=True)
    file_interface.write_tum_trajectory_file(str(dest), body)
    return dest


def _sim3_scale(gt: Path, est: Path) -> float:
    """evo's Sim(3) alignment scale (ground truth = scale x estimate)."""
    from evo.core import sync
    from evo.tools import file_interface

    ref, e = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt)),
                                         file_interface.read_tum_trajectory_file(str(est)), max_diff=0.02)
    return float(e.align(ref, correct_scale=True)[2])


@pytest.mark.slow
def test_monocular_map_made_metric_by_the_imu(euroc_mono: Path, tmp_path: Path) -> None:
    common = ["--preset", "mono", "--sensor", "mono", "--sequential", "--no-report", "--map", "none"]
    with_imu = run_cli(euroc_mono, tmp_path / "imu", *common)
    without = run_cli(euroc_mono, tmp_path / "vis", *common, "--set", "imu.use=false")
    assert with_imu["imu_initialisations"] == 1 and with_imu["imu_scales"]
    # By default only sure scales (spread <= 5 %) are applied.
    assert all(spread <= 0.05 for _, _, spread in with_imu["imu_scales"])
    assert with_imu["lost_frames"] == 0
    # Keyframes made once the map is metric are linked by the IMU's motion (the first ones,
    # before the scale, are not), and local BA holds them to it.
    assert with_imu["imu_keyframe_links"] >= 4 and with_imu["local_ba_links"] >= with_imu["imu_keyframe_links"]
    assert "imu_keyframe_links" not in without and without["local_ba_links"] == 0
    gt = _cam0_groundtruth(euroc_mono, tmp_path / "gt.txt")
    traj = tmp_path / "imu" / "trajectory.txt"
    scale = _sim3_scale(gt, traj)
    assert scale == pytest.approx(1.0, abs=0.03), scale
    se3, sim3 = evo_ate(gt, traj), evo_ate(gt, traj, correct_scale=True)
    assert sim3 < 0.008 and se3 < 1.5 * sim3 + 0.002, (se3, sim3)
    # Without the IMU the same frames are tracked as well, in the two-view map's units: making
    # the map metric mid-run does not disturb the tracking.
    vis = tmp_path / "vis" / "trajectory.txt"
    assert "imu_scales" not in without
    assert sim3 < 1.1 * evo_ate(gt, vis, correct_scale=True)
    assert evo_ate(gt, vis) > 10 * se3


@pytest.mark.slow
def test_provisional_scale_bridges_an_early_blackout(euroc_mono_blackout: Path, tmp_path: Path) -> None:
    # The lens covered 3 s in, about 2 s after the two-view initialisation: the motion has not
    # shown the scale to 5 % yet, but to 50 % it has; the provisional scale lets the IMU pose
    # the black frames, and the run keeps one metric map. Waiting for a sure scale instead
    # (provisional_scale_spread = max_scale_spread, the default), the blackout loses the camera.
    # Measured (640x480): provisional scale at 2.47 s (spread 0.34), 45 IMU-only frames, SE(3)
    # ATE 2.1 cm, evo's Sim(3) scale 0.93; waiting: 59 frames lost, 2 maps, never metric.
    common = ["--preset", "mono", "--sensor", "mono", "--sequential", "--no-report", "--map", "none"]
    bridged = run_cli(euroc_mono_blackout, tmp_path / "imu", *common, "--set", "imu.provisional_scale_spread=0.5")
    waiting = run_cli(euroc_mono_blackout, tmp_path / "wait", *common)  # the default waits
    csv = (euroc_mono_blackout / "mav0" / "cam0" / "data.csv").read_text().splitlines()
    first = int(next(line for line in csv if not line.startswith("#")).split(",")[0]) * 1e-9
    t_scale, _, spread = bridged["imu_scales"][0]
    assert t_scale - first < BLACKOUT[0] and 0.05 < spread <= 0.5
    assert bridged["lost_frames"] == 0 and bridged["maps"] == 1
    assert bridged["imu_only_frames"] == BLACK_FRAMES
    gt = _cam0_groundtruth(euroc_mono_blackout, tmp_path / "gt.txt")
    assert evo_ate(gt, tmp_path / "imu" / "trajectory.txt") < 0.04
    assert _sim3_scale(gt, tmp_path / "imu" / "trajectory.txt") == pytest.approx(1.0, abs=0.1)
    assert waiting["lost_frames"] > BLACK_FRAMES / 2 and waiting["imu_only_frames"] == 0


@pytest.mark.slow
def test_api_monocular_inertial_is_the_cli_run(euroc_mono: Path, tmp_path: Path) -> None:
    # The same frames and readings through System.track(rgb, None, t, imu=...): sequential
    # runs are deterministic, so the scale applied and every pose equal the CLI's.
    from semslam import System
    from semslam.io.imu import open_imu
    from semslam.io.sequence import open_sequence

    cli = run_cli(euroc_mono, tmp_path / "cli", "--preset", "mono", "--sensor", "mono", "--sequential",
                  "--no-report", "--map", "none")
    seq = open_sequence(euroc_mono, kind="mono")
    stream = open_imu(euroc_mono)
    assert stream is not None
    with System("mono", seq.camera, imu=stream.calibration, overrides=["slam.sequential=true"]) as system:
        for frame in seq:
            s = frame.imu
            assert s is not None
            system.track(frame.rgb, None, frame.timestamp, imu=list(zip(s.t, s.gyro, s.acc)))
        stats = system.save(tmp_path / "api", report=False).to_dict()
    assert stats["imu_scales"] == cli["imu_scales"]
    from evo.tools import file_interface

    api, ref = (file_interface.read_tum_trajectory_file(str(tmp_path / d / "trajectory.txt")) for d in ("api", "cli"))
    np.testing.assert_allclose(api.timestamps, ref.timestamps)
    np.testing.assert_allclose(api.positions_xyz, ref.positions_xyz, atol=1e-6)
