"""HTML report: one self-contained file with the statistics and embedded plots."""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np

from semslam.eval import ate, rpe
from semslam.eval.report import write_report
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.core.trajectory import Trajectory


def _pair(n: int = 3000) -> tuple[Trajectory, Trajectory]:
    """A wavy ground truth and a noisy, rigidly moved estimate of it."""
    rng = np.random.default_rng(0)
    t = 1305031102.0 + np.arange(n) / 30.0
    s = np.linspace(0, 6 * np.pi, n)
    pos = np.stack([np.cos(s), np.sin(2 * s), 0.1 * s], axis=1)
    rots = np.stack([so3_exp([0.0, 0.0, a]) for a in s])
    gt = Trajectory(t, make_pose(rots, pos), "gt.txt")
    moved = make_pose(so3_exp([0.1, -0.2, 0.3]), [1.0, 2.0, 0.5]) @ gt.poses
    moved[:, :3, 3] += rng.normal(scale=0.01, size=(n, 3))
    return gt, Trajectory(t + 0.001, moved, "est.txt")


def test_report_contains_stats_and_images(tmp_path: Path) -> None:
    gt, est = _pair()
    a = ate(gt, est, align="se3")
    r = rpe(gt, est, delta=1.0, delta_unit="seconds")
    out = tmp_path / "report.html"
    written = write_report(out, gt, est, a, r, title="My <run>", extra={"fps": 31.25, "preset": "ddl"})
    assert written == out and out.is_file()  # (its speed is a benchmark's business, not a test's)
    text = out.read_text()
    assert "<title>My &lt;run&gt;</title>" in text
    for value in (a.stats["rmse"], a.stats["max"], r.trans_stats["rmse"], r.rot_stats["mean"]):
        assert f"{value:.6g}" in text
    assert "fps" in text and "31.25" in text and "ddl" in text
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(images) == 3  # trajectory, ATE over time, RPE over time
    for b64 in images:
        assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "src=\"http" not in text and "<script" not in text  # self-contained


def test_report_without_rpe(tmp_path: Path) -> None:
    gt, est = _pair(200)
    out = write_report(tmp_path / "r.html", gt, est, ate(gt, est, align="sim3"))
    text = out.read_text()
    assert text.count("data:image/png;base64,") == 2
    assert "RPE" not in text.split("<h2>Trajectory")[0].split("<table>")[1]
