"""``semslam demo`` as a user runs it first: render, run (default preset, threaded),
print the ATE. A 40-frame demo measures 0.67 cm; the bound is the default preset's
static-scene accuracy with people in view (< 2 cm), and the printed number must be the
one evo computes from the files the demo wrote."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from semslam.cli.main import main
from tests.conftest import evo_ate


@pytest.mark.slow
def test_demo_runs_and_prints_ate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mediapipe")
    assert main(["demo", "--frames", "40", "--out", str(tmp_path), "-q"]) == 0
    printed = re.search(r"ATE RMSE ([0-9.]+) cm,", capsys.readouterr().out)
    assert printed is not None
    ate_cm = float(printed.group(1))
    stats = json.loads((tmp_path / "run" / "stats.json").read_text())
    assert stats["frames"] == 40 and stats["tracked_frames"] == 40
    reference = evo_ate(tmp_path / "demo" / "groundtruth.txt", tmp_path / "run" / "trajectory.txt")
    assert ate_cm == pytest.approx(reference * 100, abs=0.005)  # printed with 2 decimals
    assert ate_cm < 2.0
