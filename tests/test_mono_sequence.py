"""Monocular input: TUM folders read without depth, image folders without any, the stand-in
depth sources, and both monocular presets end to end (``sdf``: the SDF-SLAM tracker;
``sdf_rgbd``: the ORB core on a depth source's depth)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.config import load_config
from semslam.core import registry
from semslam.core.protocols import TrackerInputs
from semslam.errors import ConfigError, DataError
from semslam.geometry.camera import PinholeCamera
from semslam.io.depth import SensorDepth
from semslam.io.sequence import ImageFolderSequence, TumRgbdSequence, kind_for_sensor, open_sequence
from semslam.io.standin_depth import ConstantDepth, GroundTruthDepth
from tests.conftest import run_cli

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, width=640, height=480)


def test_a_tum_folder_read_as_mono_has_no_depth(tum_folder: Path) -> None:
    mono = open_sequence(tum_folder, kind=kind_for_sensor("mono"))
    rgbd = open_sequence(tum_folder, kind=kind_for_sensor("rgbd"))
    assert isinstance(mono, ImageFolderSequence) and isinstance(rgbd, TumRgbdSequence)
    assert not mono.has_depth and mono.groundtruth_path == rgbd.groundtruth_path is not None
    np.testing.assert_array_equal(mono.timestamps, rgbd.timestamps)
    frames = list(mono.frames())
    assert len(frames) == 5 and all(f.depth is None for f in frames)


def test_ground_truth_depth_reads_the_sequences_depth_in_mono_mode(tum_folder: Path) -> None:
    """The oracle finds each colour image's depth image by timestamp (4 ms apart here), the
    same image the RGB-D reader pairs with it."""
    oracle = GroundTruthDepth()
    for m, r in zip(open_sequence(tum_folder, kind="mono").frames(), open_sequence(tum_folder).frames()):
        np.testing.assert_array_equal(oracle.depth(m), r.depth)
        assert r.depth is not None and float(r.depth[0, 0]) == pytest.approx(2.0)


def test_ground_truth_depth_without_depth_files_is_one_clear_error(tmp_path: Path, tum_folder: Path) -> None:
    folder = tmp_path / "images"
    shutil.copytree(tum_folder / "rgb", folder / "rgb")
    frame = next(open_sequence(folder, kind="mono").frames())
    with pytest.raises(DataError, match=r"depth\.txt.*file not found"):
        GroundTruthDepth().depth(frame)
    assert ConstantDepth().depth(frame).shape == frame.rgb.shape[:2]


def test_mono_without_a_depth_source_is_refused() -> None:
    with pytest.raises(ConfigError, match="a monocular sequence has no sensor depth"):
        registry.create("tracker", "sdf_slam", load_config("sdf_paper", ["depth.source=sensor"]), CAM,
                        TrackerInputs(SensorDepth()))


@pytest.fixture(scope="module")
def short_render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``static_xyz``, 40 frames at 320x240 (RPE over 1 s needs more than 30)."""
    from semslam.synth import SEQUENCES, render_sequence

    cfg = SEQUENCES["static_xyz"].replace(frames=40, width=320, height=240)
    return render_sequence(cfg, tmp_path_factory.mktemp("mono") / "static_xyz")


def test_a_monocular_image_folder_without_depth_runs(short_render: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A bare folder of images (no lists, no depth, no ground truth) through ``--preset sdf``
    as shipped: SDFCNN gives depth and classes. The oracle depth source, asked for on such a
    folder, is one clear line (exit 2)."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for p in sorted((short_render / "rgb").glob("*.png"))[:12]:
        shutil.copy(p, folder / p.name)
    (folder / "calib.txt").write_text((short_render / "calib.txt").read_text())
    out = tmp_path / "out"
    assert main(["run", str(folder), "--out", str(out), "-q", "--preset", "sdf_paper", "--set", "dynamics.semantic=false",
                 "--set", "depth.source=ground_truth_depth"]) == 2
    err = capsys.readouterr().err
    assert "depth.txt" in err and len(err.strip().splitlines()) == 1
    # the refused run wrote what it had: the next one replaces it
    stats = run_cli(folder, out, "--preset", "sdf_paper", "--set", "slam.sequential=true", "--overwrite")
    assert stats["frames"] == stats["tracked_frames"] == 12 and "ate" not in stats
    assert (out / "trajectory.txt").is_file() and (out / "map" / "semantic_cloud.ply").is_file()


def test_sdf_rgbd_runs_the_orb_core_on_the_depth_sources_depth(short_render: Path, tmp_path: Path) -> None:
    """``sdf_rgbd``: the monocular frames (read without depth) get the depth source's depth,
    here the oracle's, so the ORB core tracks them as RGB-D and the scale is metric."""
    stats = run_cli(short_render, tmp_path / "run", "--preset", "sdf_rgbd", "--set", "slam.sequential=true",
                    "--set", "depth.source=ground_truth_depth", "--set", "semantics.backend=ground_truth")
    assert stats["ate_alignment"] == "sim3" and stats["tracked_frames"] == stats["frames"] == 40
    assert stats["ate"]["rmse"] < 0.01 and stats["ate_se3"]["rmse"] < 0.01
    assert abs(stats["ate_sim3_scale"] - 1.0) < 0.05
