"""The ORB core (preset ``orb``) end to end on real data: the first 50 frames of TUM RGB-D
freiburg2_desk (Kinect v1, fr2 calibration with radial distortion, motion-capture ground
truth), through the CLI with ``--sequential`` (deterministic).

Bound. ORB-SLAM3 v1.0 gets 1.2 cm ATE on these frames; we measure 0.93 cm with all 50
frames tracked and no relocalisation (5 s). The bound is ORB-SLAM3's 1.2 cm: we must do at
least as well as the reference implementation on the same frames, and it leaves 29 % over
our number for numerical differences across OpenCV/GTSAM/BLAS builds. For scale: the
camera travels 37 cm, and a camera standing still would score 12 cm.

What the ATE cannot tell on 1.6 s of video, measured: ignoring the distortion gives
1.17 cm, generic Kinect intrinsics (525, 525, 319.5, 239.5) 1.12 cm, and local BA off
0.63 cm. So the calibration is asserted directly here, and that BA runs and lowers its cost
is checked in tests/test_orb_slam.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import evo_ate, run_cli

FR2_DESK = "rgbd_dataset_freiburg2_desk_first50"


@pytest.mark.slow
def test_orb_on_real_fr2_desk(shared_data: Path, tmp_path: Path) -> None:
    seq = shared_data / FR2_DESK
    if not seq.is_dir():
        pytest.skip(f"{seq} not found")
    out = tmp_path / "run"
    stats = run_cli(seq, out, "--preset", "orb", "--sequential", "--no-report")
    # The reader must have taken the fr2 calibration (with its distortion) from the name.
    cam = stats["camera"]
    assert "freiburg2" in cam["source"]
    assert (cam["fx"], cam["fy"], cam["cx"], cam["cy"]) == (520.9, 521.0, 325.1, 249.7)
    assert cam["dist"] == [0.2312, -0.7849, -0.0033, -0.0001, 0.9172]
    assert stats["frames"] == stats["tracked_frames"] == 50  # no frame lost
    assert stats["relocalisations"] == 0
    ate = stats["ate"]["rmse"]
    assert ate < 0.012, ate
    assert abs(ate - evo_ate(seq / "groundtruth.txt", out / "trajectory.txt")) < 1e-9
