"""The simulated IMU of ``semslam synth --imu`` (issue 42, synth/imu.py) and the EuRoC layout's
``imu0`` and ``depth0`` (synth/euroc_writer.py)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import gtsam
import numpy as np
import pytest
import yaml

from semslam.core.imu import ADIS16448, GRAVITY
from semslam.errors import ConfigError
from semslam.synth import euroc_writer
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.imu import (
    ACC_BIAS0,
    GYRO_BIAS0,
    LEAD_S,
    TAIL_S,
    body_poses_at,
    exact_imu,
    initial_biases,
    sample_times,
    simulate_imu,
)
from semslam.synth.render import Renderer, render_sequence
from semslam.synth.sequences import SynthConfig

T_BC = euroc_writer.T_BS_CAM0
FPS = 30.0
RATE = ADIS16448.rate_hz
TINY = SynthConfig(motion="xyz", frames=3, people=0, width=64, height=48, seed=3)


def _path(motion: str, frames: int = 150):
    duration = frames / FPS
    return lambda t: camera_trajectory(motion, np.asarray(t, np.float64), duration, 0)


def test_sample_times_cover_every_frame() -> None:
    t = sample_times(10, FPS)
    assert t[0] == pytest.approx(-LEAD_S) and t[-1] >= 9 / FPS + TAIL_S - 1e-12
    np.testing.assert_allclose(np.diff(t), 1 / RATE, atol=1e-12)
    assert np.any(np.abs(t) < 1e-12)  # on a grid through the first frame


@pytest.mark.parametrize("motion", ["xyz", "rpy", "fast_turns"])
def test_at_rest_before_the_first_frame(motion: str) -> None:
    """The camera stands still before t = 0: the accelerometer reads gravity's reaction, up,
    in B, and the gyroscope nothing."""
    sim = exact_imu(_path(motion), T_BC, 30, FPS, 0.0)
    rest = sim.t_rel < 0
    r_wb = body_poses_at(_path(motion), T_BC)(sim.t_rel[rest])[:, :3, :3]
    up_b = np.einsum("nji,j->ni", r_wb, [0.0, 0.0, GRAVITY])  # R_WB^T (0, 0, +g)
    np.testing.assert_allclose(sim.samples.acc[rest], up_b, atol=1e-5)  # rounding of 2nd differences
    np.testing.assert_allclose(sim.samples.gyro[rest], 0.0, atol=1e-9)
    # EuRoC-like mounting: the body's x axis points up (camera y down is body -x).
    assert np.all(sim.samples.acc[rest][:, 0] > 9.0)


def test_static_tripod_reads_gravity_and_its_tremor() -> None:
    """``static`` keeps a sub-millimetre tremor (0.3 mm at 1.3 Hz: 0.02 m/s^2, 0.02 deg at
    ~1 Hz: 0.0025 rad/s), nothing more."""
    sim = exact_imu(_path("static"), T_BC, 30, FPS, 0.0)
    r_wb = body_poses_at(_path("static"), T_BC)(sim.t_rel)[:, :3, :3]
    up_b = np.einsum("nji,j->ni", r_wb, [0.0, 0.0, GRAVITY])
    assert np.abs(sim.samples.acc - up_b).max() < 0.03
    assert np.abs(sim.samples.gyro).max() < 0.003


def _integrate(sim, motion: str, start: float, span: float, substeps: int) -> tuple[float, float]:
    """GTSAM's preintegration of the noiseless stream from the true state at sample time
    ``start`` over ``span`` seconds; (position error in m, rotation error in degrees)."""
    body = body_poses_at(_path(motion), T_BC)
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    k0 = int(np.argmin(np.abs(sim.t_rel - start)))
    n = int(round(span * RATE))
    acc, gyro = sim.samples.acc, sim.samples.gyro
    for k in range(k0, k0 + n):
        for j in range(substeps):  # substeps: readings linear between samples
            f = (j + 0.5) / substeps if substeps > 1 else 0.0
            pim.integrateMeasurement((1 - f) * acc[k] + f * acc[k + 1], (1 - f) * gyro[k] + f * gyro[k + 1],
                                     1.0 / RATE / substeps)
    t0, t1 = sim.t_rel[k0], sim.t_rel[k0 + n]
    h = 1e-4
    p0, p1 = body(np.array([t0]))[0], body(np.array([t1]))[0]
    v0 = (body(np.array([t0 + h]))[0][:3, 3] - body(np.array([t0 - h]))[0][:3, 3]) / (2 * h)
    pred = pim.predict(gtsam.NavState(gtsam.Rot3(p0[:3, :3]), p0[:3, 3], v0), gtsam.imuBias.ConstantBias())
    d_rot = gtsam.Rot3.Logmap(gtsam.Rot3(p1[:3, :3]).between(pred.attitude()))
    return float(np.linalg.norm(pred.position() - p1[:3, 3])), float(np.rad2deg(np.linalg.norm(d_rot)))


#: Worst errors measured (windows every 0.25 s over 9 s) with readings linear between samples
#: (10 substeps, so that GTSAM's own first-order steps add little), over 0.5 s / 1 s: xyz
#: 0.006 / 0.022 mm, rpy 0.086 / 0.34 mm and 1e-4 deg, fast_turns 1.8 / 3.8 mm and 0.01 deg.
#: What is left on fast_turns is its 200 deg/s glances between the 5 ms samples (the readings
#: themselves agree with a 3x smaller differentiation step to 1e-6, except at the C1 kinks
#: where the glances start and stop). Bounds, about 2x those: (m over 0.5 s, m over 1 s, deg).
TOLERANCE = {"xyz": (0.1e-3, 0.2e-3, 0.001), "rpy": (0.2e-3, 0.7e-3, 0.001), "fast_turns": (4e-3, 8e-3, 0.02)}
#: Windows: from rest into the motion, and over the first glance of fast_turns (1.0-1.27 s).
WINDOWS = ((-0.3, 0.5), (0.9, 0.5), (-0.3, 1.0), (0.8, 1.0))


@pytest.mark.parametrize("motion", ["xyz", "rpy", "fast_turns"])
def test_gtsam_preintegration_reproduces_the_body_pose(motion: str) -> None:
    sim = exact_imu(_path(motion), T_BC, 90, FPS, 0.0)
    tol_half, tol_one, tol_deg = TOLERANCE[motion]
    for start, span in WINDOWS:
        dp, dr = _integrate(sim, motion, start, span, substeps=10)
        assert dp < (tol_half if span == 0.5 else tol_one) and dr < tol_deg, (motion, start, span, dp, dr)


def test_gtsam_preintegration_with_readings_held() -> None:
    """GTSAM's plain use (each reading held over its 5 ms): within 2 mm and 0.05 deg over 0.5 s
    (measured: xyz 0.37 mm and 0.002 deg, rpy 0.17 mm and 0.03 deg: the readings lag half a
    sample)."""
    for motion in ("xyz", "rpy"):
        sim = exact_imu(_path(motion), T_BC, 60, FPS, 0.0)
        for start in (-0.3, 0.9):
            dp, dr = _integrate(sim, motion, start, 0.5, substeps=1)
            assert dp < 2e-3 and dr < 0.05, (motion, start, dp, dr)


def test_noise_model() -> None:
    """White noise sigma_c * sqrt(rate) per sample, bias random walks sigma_rw / sqrt(rate)
    per step from the seeded initial biases; noisy=False is the exact stream."""
    path = _path("xyz", 300)
    exact = exact_imu(path, T_BC, 300, FPS, 100.0)
    sim = simulate_imu(path, T_BC, 300, FPS, 100.0, seed=7)
    np.testing.assert_array_equal(sim.samples.t, exact.samples.t)
    np.testing.assert_allclose(sim.samples.t[0], 100.0 - LEAD_S)
    b_g0, b_a0 = initial_biases(7)
    np.testing.assert_array_equal(sim.gyro_bias[0], b_g0)
    np.testing.assert_array_equal(sim.acc_bias[0], b_a0)
    assert np.all(np.abs(b_g0) <= GYRO_BIAS0) and np.all(np.abs(b_a0) <= ACC_BIAS0)
    white_g = sim.samples.gyro - exact.samples.gyro - sim.gyro_bias
    white_a = sim.samples.acc - exact.samples.acc - sim.acc_bias
    assert np.std(white_g) == pytest.approx(ADIS16448.gyro_noise_density * np.sqrt(RATE), rel=0.05)
    assert np.std(white_a) == pytest.approx(ADIS16448.acc_noise_density * np.sqrt(RATE), rel=0.05)
    assert np.std(np.diff(sim.gyro_bias, axis=0)) == pytest.approx(
        ADIS16448.gyro_random_walk / np.sqrt(RATE), rel=0.05)
    assert np.std(np.diff(sim.acc_bias, axis=0)) == pytest.approx(ADIS16448.acc_random_walk / np.sqrt(RATE), rel=0.05)
    # A longer render's recording starts with the shorter one's, sample for sample.
    short = simulate_imu(_path("xyz", 300), T_BC, 30, FPS, 100.0, seed=7)
    np.testing.assert_array_equal(short.samples.acc, sim.samples.acc[: len(short.samples)])
    exact2 = simulate_imu(path, T_BC, 300, FPS, 100.0, seed=7, noisy=False)
    np.testing.assert_array_equal(exact2.samples.acc, exact.samples.acc)
    assert not exact2.gyro_bias.any() and not exact2.acc_bias.any()


def _csv(path: Path) -> tuple[str, np.ndarray]:
    lines = path.read_text().splitlines()
    return lines[0], np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])


@pytest.fixture(scope="module")
def euroc_imu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("imu")
    return render_sequence(TINY.replace(imu=True, euroc_depth=True), root / "e", layout_format="euroc", workers=1)


def test_euroc_imu0(euroc_imu: Path) -> None:
    mav = euroc_imu / "mav0"
    header = mav.joinpath("imu0", "data.csv").read_text().splitlines()[0]
    assert header == ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                      "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
    lines = mav.joinpath("imu0", "data.csv").read_text().splitlines()[1:]
    ns = np.array([int(ln.split(",")[0]) for ln in lines])  # integer nanoseconds
    data = np.array([[float(v) for v in ln.split(",")[1:]] for ln in lines])
    frames = euroc_writer.ns_stamps(TINY.start_time, TINY.frames, TINY.fps)
    assert np.all(np.diff(ns) == 5_000_000)  # 200 Hz
    assert ns[0] == frames[0] - 500_000_000 and ns[-1] >= frames[-1] + 50_000_000
    assert np.all((ns - frames[0]) % 5_000_000 == 0)  # the frames' clock
    cfg = yaml.safe_load(mav.joinpath("imu0", "sensor.yaml").read_text())
    assert cfg["sensor_type"] == "imu" and cfg["rate_hz"] == 200
    np.testing.assert_array_equal(np.array(cfg["T_BS"]["data"]).reshape(cfg["T_BS"]["rows"], cfg["T_BS"]["cols"]),
                                  np.eye(4))
    assert cfg["gyroscope_noise_density"] == ADIS16448.gyro_noise_density
    assert cfg["gyroscope_random_walk"] == ADIS16448.gyro_random_walk
    assert cfg["accelerometer_noise_density"] == ADIS16448.acc_noise_density
    assert cfg["accelerometer_random_walk"] == ADIS16448.acc_random_walk
    # At rest (the 0.5 s before the first frame) the spread is the white noise's.
    rest = data[ns < frames[0]]
    assert len(rest) == 100
    assert np.std(rest[:, :3], axis=0).mean() == pytest.approx(ADIS16448.gyro_noise_density * np.sqrt(200), rel=0.1)
    assert np.std(rest[:, 3:], axis=0).mean() == pytest.approx(ADIS16448.acc_noise_density * np.sqrt(200), rel=0.1)
    # The file is the simulation, to the last digit, and the ground truth holds its biases.
    r = Renderer(TINY)
    sim = simulate_imu(r.poses_at, T_BC, TINY.frames, TINY.fps, TINY.start_time, TINY.seed)
    np.testing.assert_array_equal(data, np.concatenate([sim.samples.gyro, sim.samples.acc], axis=1))
    _, gt = _csv(mav / "state_groundtruth_estimate0" / "data.csv")
    b_g, b_a = sim.biases_at(r.times)
    np.testing.assert_allclose(gt[:, 11:14], b_g, atol=1e-11)
    np.testing.assert_allclose(gt[:, 14:17], b_a, atol=1e-11)
    assert abs(b_g).max() > 1e-4  # real biases, not zeros


def test_euroc_depth0_is_the_tum_depth(euroc_imu: Path, tmp_path: Path) -> None:
    mav = euroc_imu / "mav0"
    tum = render_sequence(TINY, tmp_path / "t", workers=1)
    tum_depth = sorted((tum / "depth").glob("*.png"))
    frames = euroc_writer.ns_stamps(TINY.start_time, TINY.frames, TINY.fps)
    assert mav.joinpath("depth0", "data.csv").read_text().splitlines() == [
        "#timestamp [ns],filename", *(f"{s},{s}.png" for s in frames)]
    for s, t in zip(frames, tum_depth):
        ours = cv2.imread(str(mav / "depth0" / "data" / f"{s}.png"), cv2.IMREAD_UNCHANGED)
        assert ours.dtype == np.uint16 and ours.shape == (TINY.height, TINY.width)
        np.testing.assert_array_equal(ours, cv2.imread(str(t), cv2.IMREAD_UNCHANGED))
    cfg = yaml.safe_load(mav.joinpath("depth0", "sensor.yaml").read_text())
    assert cfg["sensor_type"] == "depth" and cfg["depth_scale"] == 5000.0
    assert cfg["resolution"] == [TINY.width, TINY.height] and cfg["rate_hz"] == TINY.fps
    np.testing.assert_array_equal(np.array(cfg["T_BS"]["data"]).reshape(4, 4), T_BC)


def test_exact_imu_render_and_stale_lists(tmp_path: Path) -> None:
    """noise=False: the exact stream and zero biases in the ground truth; a render without
    --imu/--depth into the same folder leaves no imu0/depth0 lists behind."""
    out = render_sequence(TINY.replace(imu=True, euroc_depth=True, noise=False), tmp_path / "e",
                          layout_format="euroc", workers=1)
    mav = out / "mav0"
    _, data = _csv(mav / "imu0" / "data.csv")
    sim = exact_imu(Renderer(TINY).poses_at, T_BC, TINY.frames, TINY.fps, TINY.start_time)
    np.testing.assert_array_equal(data[:, 1:], np.concatenate([sim.samples.gyro, sim.samples.acc], axis=1))
    _, gt = _csv(mav / "state_groundtruth_estimate0" / "data.csv")
    assert not gt[:, 11:].any()
    info = json.loads((out / "sequence.json").read_text())
    assert info["imu0"]["noise"]["gyro_noise_density"] == ADIS16448.gyro_noise_density
    assert info["config"]["imu"] is True
    render_sequence(TINY, out, layout_format="euroc", workers=1)
    for sensor in ("imu0", "depth0"):
        assert not (mav / sensor / "data.csv").exists() and not (mav / sensor / "sensor.yaml").exists()
    assert not list((mav / "depth0" / "data").glob("*.png"))
    assert "imu0" not in json.loads((out / "sequence.json").read_text())


def test_sequence_json_records_the_seeded_biases(euroc_imu: Path) -> None:
    info = json.loads((euroc_imu / "sequence.json").read_text())["imu0"]
    b_g, b_a = initial_biases(TINY.seed)
    assert info["initial_gyro_bias_rad_s"] == b_g.tolist() and info["initial_acc_bias_m_s2"] == b_a.tolist()
    assert info["noise"]["acc_random_walk"] == ADIS16448.acc_random_walk and info["samples"] == 125


def test_imu_and_depth0_need_the_euroc_layout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.cli.main import main

    with pytest.raises(ConfigError, match="euroc layout format only"):
        render_sequence(TINY.replace(imu=True), tmp_path / "t")
    with pytest.raises(ConfigError, match="depth0"):
        render_sequence(TINY.replace(euroc_depth=True, stereo_baseline=0.1), tmp_path / "k", layout_format="kitti")
    assert not (tmp_path / "t").exists()
    args = ["--frames", "2", "--width", "64", "--height", "48", "--people", "0", "--quiet"]
    assert main(["synth", str(tmp_path / "c"), *args, "--imu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--layout-format euroc" in err[0]
    assert main(["synth", str(tmp_path / "c"), *args, "--imu", "--depth", "--layout-format", "euroc"]) == 0
    assert "EuRoC layout + IMU 200 Hz + depth" in capsys.readouterr().out
