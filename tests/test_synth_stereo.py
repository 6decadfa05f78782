"""Stereo renders (issue 41): the right camera's geometry, its imaging, the TUM-like and the
EuRoC ASL layouts, checked against the pinhole relation u_R = u_L - fx B / z, OpenCV's
FileStorage, PyYAML and evo's EuRoC reader."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from semslam.errors import ConfigError, DataError
from semslam.geometry.se3 import invert, pose_from_tum
from semslam.io.trajectory import read_euroc_csv
from semslam.synth import Renderer, SynthConfig, render_sequence
from semslam.synth import euroc_writer
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.render import Frame

B = 0.11
SMALL = {"width": 320, "height": 240}
CFG = SynthConfig(motion="xyz", frames=4, people=2, seed=3, stereo_baseline=B, **SMALL)


def _list(path: Path) -> list[tuple[str, str]]:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    return [(r[0], r[1]) for r in rows]


def _warp_right_to_left(left: Frame, right: Frame, fx: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The right image and depth sampled where the left pixels' points must appear,
    (u - fx B / z, v), and the mask of left pixels seen by the right camera too (same depth
    there: not occluded, inside the image)."""
    h, w = left.z.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    finite = np.isfinite(left.z)
    disp = np.where(finite, fx * B / np.where(finite, left.z, 1.0), 0.0).astype(np.float32)
    mx = uu - disp
    rgb = cv2.remap(right.rgb, mx, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    zr = cv2.remap(right.z, mx, vv, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
    seen = finite & (mx > 2) & (mx < w - 3) & (np.abs(zr - left.z) < 0.01 * left.z)
    return rgb, zr, seen


def _photometric_error(left: Frame, right: Frame, fx: float, shift: float = 0.0) -> float:
    """Mean absolute grey difference between the left image and the right one warped by the
    left depth's disparity plus ``shift`` pixels, on textured, mutually visible pixels."""
    warped, _, seen = _warp_right_to_left(left, right, fx)
    if shift:
        warped = np.roll(warped, int(shift), axis=1)
    gl = cv2.cvtColor(left.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gr = cv2.cvtColor(warped, cv2.COLOR_RGB2GRAY).astype(np.float32)
    grad = np.hypot(cv2.Sobel(gl, cv2.CV_32F, 1, 0), cv2.Sobel(gl, cv2.CV_32F, 0, 1))
    mask = seen & (grad > 40)
    mask[:, :8] = mask[:, -8:] = False
    assert mask.sum() > 2000  # enough texture to judge
    return float(np.abs(gl - gr)[mask].mean())


def test_right_camera_sees_each_point_at_its_disparity() -> None:
    """With exact depth, the point at (u, v) of depth z in the left image is at
    (u - fx B / z, v) in the right one, at the same depth (a rectified pair)."""
    r = Renderer(CFG.replace(noise=False))
    fx = r.cam.fx
    for i in (0, 3):
        left, right = r.render(i), r.render_right(i)
        _, zr, seen = _warp_right_to_left(left, right, fx)
        finite = np.isfinite(left.z)
        assert seen.sum() > 0.85 * finite.sum()  # all but occlusions and the left border
        rel = np.abs(zr[seen] - left.z[seen]) / left.z[seen]
        assert np.median(rel) < 2e-3
        # the images agree too: textured pixels match at the disparity, not one pixel off
        err = _photometric_error(left, right, fx)
        assert err < 4.0  # vignetting differs a little at u and u - d
        assert _photometric_error(left, right, fx, shift=1) > 3 * err
        assert _photometric_error(left, right, fx, shift=3) > 6 * err
        # the same scene: people and labels are where the disparity puts them
        lab = cv2.remap(right.semantic, np.mgrid[0:240, 0:320][1].astype(np.float32)
                        - fx * B / np.where(finite, left.z, 1.0).astype(np.float32),
                        np.mgrid[0:240, 0:320][0].astype(np.float32), cv2.INTER_NEAREST)
        assert np.mean(lab[seen] == left.semantic[seen]) > 0.99
        assert np.any(left.semantic == 15) and np.any(right.semantic == 15)


def test_right_camera_gets_the_same_imaging() -> None:
    """Gain and white balance swings, blackout and the occluder hit both cameras alike; the
    sensor noise is the right camera's own draw, as strong as the left's."""
    base = CFG.replace(motion="static", people=0, noise=False)
    swung = base.replace(gain_swing=0.4, white_balance_swing=0.2)
    plain_r, swung_r = Renderer(base), Renderer(swung)
    i = 2
    for side in ("render", "render_right"):
        a = getattr(plain_r, side)(i).rgb.reshape(-1, 3).astype(float)
        b = getattr(swung_r, side)(i).rgb.reshape(-1, 3).astype(float)
        ok = (a > 20).all(1) & (b < 235).all(1)  # away from clipping
        ratio = np.median(b[ok] / a[ok], axis=0)
        if side == "render":
            left_ratio = ratio
    np.testing.assert_allclose(ratio, left_ratio, rtol=0.01)
    assert np.abs(left_ratio - 1).max() > 0.03  # the swing is really there
    dark = Renderer(base.replace(blackout_start_s=0.0, blackout_s=0.05))
    assert not dark.render_right(0).rgb.any() and dark.render_right(2).rgb.any()
    covered = Renderer(base.replace(occluder_s=1.0))
    diff_l = np.abs(covered.render(1).rgb.astype(int) - plain_r.render(1).rgb).sum(2) > 30
    diff_r = np.abs(covered.render_right(1).rgb.astype(int) - plain_r.render_right(1).rgb).sum(2) > 30
    assert diff_l.mean() > 0.05 and np.mean(diff_l == diff_r) > 0.95  # the same cover over both lenses
    noisy = Renderer(base.replace(noise=True))
    nl = noisy.render(i).rgb.astype(float) - plain_r.render(i).rgb
    nr = noisy.render_right(i).rgb.astype(float) - plain_r.render_right(i).rgb
    assert 0.5 < nr.std() / nl.std() < 2.0
    assert abs(np.corrcoef(nl.ravel(), nr.ravel())[0, 1]) < 0.1  # independent draws


def test_motion_blur_and_rolling_shutter_in_both() -> None:
    """With exposure and rolling shutter the right image is still the left one at the
    disparity (same sub-frame times), which it would not be without them."""
    hard = CFG.replace(motion="fast_turns", people=0, noise=False, exposure_ms=16.0, rolling_shutter_ms=30.0)
    r = Renderer(hard)
    i = 3
    left, right = r.render(i), r.render_right(i)
    assert not np.array_equal(left.rgb, Renderer(hard.replace(exposure_ms=0.0, rolling_shutter_ms=0.0)).render(i).rgb)
    sharp_right = Renderer(hard.replace(exposure_ms=0.0, rolling_shutter_ms=0.0)).render_right(i)
    assert _photometric_error(left, right, r.cam.fx) < 0.8 * _photometric_error(left, sharp_right, r.cam.fx)


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("stereo")
    return {
        "mono": render_sequence(CFG.replace(stereo_baseline=0.0), root / "mono" / "seq"),
        "tum": render_sequence(CFG, root / "tum" / "seq"),
        "euroc": render_sequence(CFG, root / "euroc" / "seq", layout_format="euroc"),
    }


def test_stereo_leaves_the_rgbd_render_unchanged(renders: dict[str, Path], tmp_path: Path) -> None:
    """The left camera of a stereo render is the RGB-D render, byte for byte; a render with
    no baseline has no stereo files and no new key in sequence.json."""
    mono, tum = renders["mono"], renders["tum"]
    for sub in ("rgb", "depth", "semantic"):
        names = sorted(p.name for p in (mono / sub).glob("*.png"))
        assert len(names) == 4 and names == sorted(p.name for p in (tum / sub).glob("*.png"))
        for n in names:
            assert (mono / sub / n).read_bytes() == (tum / sub / n).read_bytes(), f"{sub}/{n}"
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "calib.txt", "scene.json", "movers.json"):
        assert (mono / name).read_bytes() == (tum / name).read_bytes(), name
    assert not (mono / "rgb_right").exists() and not (mono / "camera.yaml").exists()
    assert "stereo_baseline" not in json.loads((mono / "sequence.json").read_text())["config"]
    meta = json.loads((tum / "sequence.json").read_text())
    assert meta["config"]["stereo_baseline"] == B and meta["stereo"]["baseline_m"] == B
    # an RGB-D render into a stereo render's folder leaves no right camera behind
    again = render_sequence(CFG.replace(stereo_baseline=0.0, frames=2), tmp_path / "seq")
    render_sequence(CFG.replace(frames=2), again)
    assert (again / "rgb_right.txt").is_file()
    render_sequence(CFG.replace(stereo_baseline=0.0, frames=2), again)
    assert not list((again / "rgb_right").glob("*.png")) and not (again / "rgb_right.txt").exists()
    assert not (again / "camera.yaml").exists()


def test_tum_like_layout(renders: dict[str, Path]) -> None:
    tum = renders["tum"]
    rgb, right = _list(tum / "rgb.txt"), _list(tum / "rgb_right.txt")
    assert [s for s, _ in right] == [s for s, _ in rgb]
    assert all(n == f"rgb_right/{s}.png" and (tum / n).is_file() for s, n in right)
    fs = cv2.FileStorage(str(tum / "camera.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    assert fs.getNode("File.version").string() == "1.0"
    assert fs.getNode("Camera.type").string() == "Rectified"
    for key, want in zip(("Camera1.fx", "Camera1.fy", "Camera1.cx", "Camera1.cy"), CFG.intrinsics()):
        assert fs.getNode(key).isReal() and fs.getNode(key).real() == pytest.approx(want, abs=1e-6)
    assert fs.getNode("Stereo.b").isReal() and fs.getNode("Stereo.b").real() == pytest.approx(B, abs=1e-12)
    assert fs.getNode("Stereo.ThDepth").real() == 40.0
    for key, want in (("Camera.width", 320), ("Camera.height", 240), ("Camera.fps", 30), ("Camera.RGB", 1),
                      ("ORBextractor.nFeatures", 1200), ("ORBextractor.nLevels", 8)):
        assert fs.getNode(key).isInt() and int(fs.getNode(key).real()) == want, key
    assert fs.getNode("ORBextractor.scaleFactor").isReal() and fs.getNode("Viewer.ViewpointF").isReal()
    fs.release()
    # the right images are the renderer's right camera (exact down to the PNG)
    r = Renderer(CFG)
    img = cv2.cvtColor(cv2.imread(str(tum / right[1][1])), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, r.render_right(1).rgb)


def _tum_poses(path: Path) -> np.ndarray:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return pose_from_tum(np.array([[float(v) for v in r[1:]] for r in rows]))


def test_euroc_layout_read_by_evo(renders: dict[str, Path]) -> None:
    """evo reads the EuRoC ground truth as the body poses the renderer meant: the left camera
    composed with T_BS^-1; cam1's T_BS puts the right camera B along the left's x axis."""
    from evo.tools import file_interface

    eu, tum = renders["euroc"] / "mav0", renders["tum"]
    cam0 = _tum_poses(tum / "groundtruth.txt")  # the left camera, as the TUM render has it
    exact = Renderer(CFG).poses
    np.testing.assert_allclose(cam0, exact, atol=2e-9)
    t_bs = []
    for cam in (0, 1):
        doc = yaml.safe_load((eu / f"cam{cam}" / "sensor.yaml").read_text())
        assert doc["sensor_type"] == "camera" and doc["camera_model"] == "pinhole"
        assert doc["resolution"] == [320, 240] and doc["rate_hz"] == 30
        np.testing.assert_allclose(doc["intrinsics"], CFG.intrinsics(), atol=1e-9)
        assert doc["distortion_model"] == "radial-tangential" and doc["distortion_coefficients"] == [0.0] * 4
        assert doc["T_BS"]["rows"] == doc["T_BS"]["cols"] == 4
        t_bs.append(np.array(doc["T_BS"]["data"], float).reshape(4, 4))
        csv = (eu / f"cam{cam}" / "data.csv").read_text().splitlines()
        assert csv[0] == "#timestamp [ns],filename" and len(csv) == 5
        for line in csv[1:]:
            ns, name = line.split(",")
            assert name == f"{ns}.png" and (eu / f"cam{cam}" / "data" / name).is_file()
    assert np.abs(t_bs[0][:3, :3] - np.eye(3)).max() > 0.5  # a real body frame, as EuRoC's
    traj = file_interface.read_euroc_csv_trajectory(str(eu / "state_groundtruth_estimate0" / "data.csv"))
    body = exact @ invert(t_bs[0])
    assert traj.num_poses == 4
    np.testing.assert_allclose(traj.poses_se3, body, atol=1e-9)
    ns = [int(ln.split(",")[0]) for ln in (eu / "cam0" / "data.csv").read_text().splitlines()[1:]]
    np.testing.assert_array_equal(traj.timestamps, np.array(ns, float) / 1e9)
    np.testing.assert_array_equal(np.array(ns) - ns[0], np.round(np.arange(4) * 1e9 / 30.0))  # exact in ns
    ours = read_euroc_csv(eu / "state_groundtruth_estimate0" / "data.csv")
    np.testing.assert_allclose(ours.poses, traj.poses_se3, atol=1e-12)
    np.testing.assert_array_equal(ours.timestamps, traj.timestamps)
    # the cameras from the body: cam0 is the left camera, cam1 the left shifted by B along its x
    np.testing.assert_allclose(np.asarray(traj.poses_se3) @ t_bs[0], exact, atol=1e-9)
    cam1 = np.asarray(traj.poses_se3) @ t_bs[1]
    np.testing.assert_allclose(cam1[:, :3, :3], exact[:, :3, :3], atol=1e-9)
    np.testing.assert_allclose(cam1[:, :3, 3], exact[:, :3, 3] + B * exact[:, :3, 0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(cam1[:, :3, 3] - exact[:, :3, 3], axis=1), B, atol=1e-9)
    # velocities: the body's, against differences of its positions; biases zero
    rows = np.loadtxt(eu / "state_groundtruth_estimate0" / "data.csv", delimiter=",", comments="#")
    assert rows.shape == (4, 17) and not rows[:, 11:].any()
    p = body[:, :3, 3]
    np.testing.assert_allclose(rows[2, 8:11], (p[3] - p[1]) * 15.0, atol=0.005)  # frame 1: still speeding up
    t = np.arange(4) / 30.0
    step = [camera_trajectory(CFG.motion, t + d, CFG.duration, CFG.seed) @ invert(t_bs[0]) for d in (1e-3, -1e-3)]
    np.testing.assert_allclose(rows[:, 8:11], (step[0][:, :3, 3] - step[1][:, :3, 3]) / 2e-3, atol=1e-3)
    # the EuRoC images are the TUM render's left and right images
    for cam, folder in ((0, "rgb"), (1, "rgb_right")):
        a = cv2.imread(str(eu / f"cam{cam}" / "data" / f"{ns[2]}.png"))
        b = cv2.imread(str(sorted((tum / folder).glob("*.png"))[2]))
        np.testing.assert_array_equal(a, b)
    assert ns == list(euroc_writer.ns_stamps(CFG.start_time, 4, 30.0))


def test_project_stereo_reader_reads_both_layouts(renders: dict[str, Path]) -> None:
    """``open_stereo_sequence`` finds the rig and the left camera's ground truth in both."""
    from semslam.io.stereo_sequence import open_stereo_sequence

    r = Renderer(CFG)
    tum = open_stereo_sequence(renders["tum"])
    cal = tum.calibration
    assert cal.rectified_input and len(tum) == 4
    assert cal.baseline == pytest.approx(B, abs=1e-12) and cal.bf == pytest.approx(CFG.intrinsics()[0] * B)
    assert (cal.camera.fx, cal.camera.fy, cal.camera.cx, cal.camera.cy) == pytest.approx(CFG.intrinsics())
    frame = tum.load(2)
    np.testing.assert_array_equal(frame.right, r.render_right(2).rgb)
    np.testing.assert_allclose(tum.groundtruth().poses, r.poses, atol=2e-9)
    eu = open_stereo_sequence(renders["euroc"])
    assert len(eu) == 4 and eu.calibration.baseline == pytest.approx(B, abs=1e-9)
    np.testing.assert_allclose(eu.groundtruth().poses, r.poses, atol=1e-9)  # body poses back to cam0


def test_bad_stereo_options(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="stereo_baseline"):
        CFG.replace(stereo_baseline=-0.1).validate()
    with pytest.raises(ConfigError, match="layout format"):
        render_sequence(CFG, tmp_path / "x", layout_format="bogus")
    with pytest.raises(ConfigError, match="background"):
        render_sequence(CFG.replace(background=True), tmp_path / "x", layout_format="euroc")
    small = CFG.replace(frames=1, people=0, width=64, height=48)
    render_sequence(small, tmp_path / "e", layout_format="euroc")
    with pytest.raises(DataError, match="another layout") as err:
        render_sequence(small, tmp_path / "e")
    assert str(tmp_path / "e" / "mav0") in str(err.value)
    render_sequence(small.replace(stereo_baseline=0.0), tmp_path / "e", layout_format="euroc")
    assert not (tmp_path / "e" / "mav0" / "cam1" / "data.csv").exists()  # no stale right camera
    render_sequence(small, tmp_path / "t")
    with pytest.raises(DataError, match="another layout"):
        render_sequence(small, tmp_path / "t", layout_format="euroc")


def test_cli_stereo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.cli.main import main

    args = ["--frames", "2", "--width", "160", "--height", "120", "--quiet", "--people", "0",
            "--stereo-baseline", "0.2"]
    assert main(["synth", str(tmp_path / "t"), *args]) == 0
    assert len(list((tmp_path / "t" / "rgb_right").glob("*.png"))) == 2
    assert main(["synth", str(tmp_path / "e"), *args, "--layout-format", "euroc"]) == 0
    assert "stereo 0.2 m, EuRoC layout" in capsys.readouterr().out
    assert len(list((tmp_path / "e" / "mav0" / "cam1" / "data").glob("*.png"))) == 2
    assert main(["synth", str(tmp_path / "x"), *args, "--layout-format", "bogus"]) == 2
    assert main(["synth", str(tmp_path / "x"), "--stereo-baseline", "-1"]) == 2
