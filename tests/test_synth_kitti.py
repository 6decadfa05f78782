"""KITTI odometry renders of ``semslam synth``: the project's stereo reader and evo open them
with the TUM-layout render's images (in grey), the rig's fx * B and the rendered poses."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.errors import ConfigError, DataError
from semslam.geometry.se3 import invert, pose_from_tum
from semslam.io.stereo_sequence import open_stereo_sequence, stereo_layout
from semslam.synth import Renderer, SynthConfig, render_sequence

B = 0.12
FRAMES = 6
CFG = SynthConfig(motion="xyz", frames=FRAMES, people=1, seed=5, stereo_baseline=B, width=160, height=120)


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("kitti")
    return {
        "tum": render_sequence(CFG, root / "tum"),
        "kitti": render_sequence(CFG, root / "kitti", layout_format="kitti"),
    }


def _tum_poses(path: Path) -> np.ndarray:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return pose_from_tum(np.array([[float(v) for v in r[1:]] for r in rows]))


def test_kitti_files(renders: dict[str, Path]) -> None:
    """KITTI's own files: grey 8-bit PNGs 000000.png.., calib.txt P0..P3 + Tr, times from 0."""
    k = renders["kitti"]
    assert stereo_layout(k) == "kitti"
    for cam in ("image_0", "image_1"):
        names = sorted(p.name for p in (k / cam).iterdir())
        assert names == [f"{i:06d}.png" for i in range(FRAMES)]
        img = cv2.imread(str(k / cam / names[0]), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (120, 160)
    calib = {}
    for line in (k / "calib.txt").read_text().splitlines():
        key, rest = line.split(":")
        calib[key] = np.array(rest.split(), float).reshape(3, 4)
    assert list(calib) == ["P0", "P1", "P2", "P3", "Tr"]
    fx, fy, cx, cy = CFG.intrinsics()
    np.testing.assert_allclose(calib["P0"], [[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0]], rtol=1e-12)
    assert calib["P1"][0, 3] == pytest.approx(-fx * B, rel=1e-12)
    np.testing.assert_array_equal(calib["P1"][:, :3], calib["P0"][:, :3])
    times = np.loadtxt(k / "times.txt")
    np.testing.assert_allclose(times, np.arange(FRAMES) / CFG.fps, atol=1e-12)
    meta = json.loads((k / "sequence.json").read_text())
    assert meta["layout_format"] == "kitti" and meta["config"]["stereo_baseline"] == B
    assert not (k / "rgb.txt").exists() and not (k / "depth").exists()


def test_open_stereo_sequence_reads_the_render(renders: dict[str, Path]) -> None:
    """Images are the TUM render's left and right in grey; bf is fx * B; the ground truth is
    the rendered left-camera poses relative to the first (KITTI's convention), and
    ``kitti_T_W_C0`` brings them back to the TUM render's world poses."""
    tum, k = renders["tum"], renders["kitti"]
    seq = open_stereo_sequence(k)
    assert len(seq) == FRAMES
    cal = seq.calibration
    fx = CFG.intrinsics()[0]
    assert cal.rectified_input and cal.bf == pytest.approx(fx * B, rel=1e-12)
    assert cal.baseline == pytest.approx(B, rel=1e-12)
    assert (cal.camera.fx, cal.camera.fy, cal.camera.cx, cal.camera.cy) == pytest.approx(CFG.intrinsics())
    assert (cal.camera.width, cal.camera.height) == (160, 120)
    rgb = sorted((tum / "rgb").glob("*.png"))
    rgb_right = sorted((tum / "rgb_right").glob("*.png"))
    for i in (0, 3, FRAMES - 1):
        frame = seq.load(i)
        for got, src in ((frame.rgb, rgb[i]), (frame.right, rgb_right[i])):
            want = cv2.cvtColor(cv2.imread(str(src)), cv2.COLOR_BGR2GRAY)
            np.testing.assert_array_equal(got[..., 0], want)
            np.testing.assert_array_equal(got[..., 2], want)
    exact = Renderer(CFG).poses
    gt = seq.groundtruth()
    assert gt is not None
    np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(gt.poses, invert(exact[0]) @ exact, atol=1e-6)
    np.testing.assert_allclose(gt.timestamps, np.arange(FRAMES) / CFG.fps, atol=1e-12)
    t_w_c0 = np.array(json.loads((k / "sequence.json").read_text())["kitti_T_W_C0"])
    np.testing.assert_allclose(t_w_c0 @ gt.poses, _tum_poses(tum / "groundtruth.txt"), atol=1e-6)
    # the same sequence folder given as the ground truth's place explicitly, as KITTI users do
    again = open_stereo_sequence(k, groundtruth=k / "poses.txt").groundtruth()
    assert again is not None
    np.testing.assert_array_equal(again.poses, gt.poses)


def test_evo_reads_the_poses(renders: dict[str, Path]) -> None:
    from evo.tools import file_interface

    traj = file_interface.read_kitti_poses_file(str(renders["kitti"] / "poses.txt"))
    exact = Renderer(CFG).poses
    np.testing.assert_allclose(np.asarray(traj.poses_se3), invert(exact[0]) @ exact, atol=1e-6)


def test_kitti_render_options(tmp_path: Path) -> None:
    tiny = CFG.replace(frames=2, people=0, width=64, height=48)
    with pytest.raises(ConfigError, match="stereo baseline"):
        render_sequence(tiny.replace(stereo_baseline=0.0), tmp_path / "k", layout_format="kitti")
    with pytest.raises(ConfigError, match="background"):
        render_sequence(tiny.replace(background=True), tmp_path / "k", layout_format="kitti")
    render_sequence(tiny, tmp_path / "t")
    with pytest.raises(DataError, match="another layout"):
        render_sequence(tiny, tmp_path / "t", layout_format="kitti")
    k = render_sequence(tiny, tmp_path / "k", layout_format="kitti")
    with pytest.raises(DataError, match="another layout") as err:
        render_sequence(tiny, k)
    assert str(k / "image_0") in str(err.value)
    render_sequence(tiny.replace(frames=1), k, layout_format="kitti")  # a shorter render leaves no stale frame
    assert len(open_stereo_sequence(k)) == 1 and len(list((k / "image_1").glob("*.png"))) == 1


def test_cli_kitti(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.cli.main import main

    args = ["--frames", "2", "--width", "64", "--height", "48", "--quiet", "--people", "0", "--layout-format", "kitti"]
    assert main(["synth", str(tmp_path / "x"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "kitti" in err[0] and "--stereo-baseline" in err[0]
    assert not (tmp_path / "x").exists()
    assert main(["synth", str(tmp_path / "k"), *args, "--stereo-baseline", "0.2"]) == 0
    assert "stereo 0.2 m, KITTI layout" in capsys.readouterr().out
    seq = open_stereo_sequence(tmp_path / "k")
    assert len(seq) == 2 and seq.calibration.baseline == pytest.approx(0.2, rel=1e-12)
