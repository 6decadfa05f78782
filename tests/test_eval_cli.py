"""``semslam eval``: rich table with the RMSE, JSON/HTML outputs, exit code 2 on user errors."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from semslam.cli import eval_cmd
from semslam.errors import TrajectoryError
from semslam.eval import ate, rpe
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import read_tum, write_tum


def _app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False)

    @app.callback()
    def _root() -> None:  # keeps "eval" a sub-command, as in the real CLI
        pass

    eval_cmd.register(app)
    return app


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    n = 300
    t = 100.0 + np.arange(n) / 30.0
    s = np.linspace(0, 4 * np.pi, n)
    pos = np.stack([np.cos(s), np.sin(s), 0.05 * s], axis=1)
    rots = np.stack([so3_exp([0.0, 0.1 * a, a]) for a in s])
    gt = Trajectory(t, make_pose(rots, pos))
    est_poses = make_pose(so3_exp([0.2, 0.0, -0.1]), [0.5, 0.0, 1.0]) @ gt.poses
    est_poses[:, :3, 3] += rng.normal(scale=0.02, size=(n, 3))
    gt_path, est_path = tmp_path / "gt.txt", tmp_path / "est.txt"
    write_tum(gt_path, gt)
    write_tum(est_path, Trajectory(t + 0.003, est_poses))
    return gt_path, est_path


def test_eval_prints_rmse_and_writes_outputs(files, tmp_path: Path) -> None:
    gt_path, est_path = files
    out_json, out_html = tmp_path / "o.json", tmp_path / "o.html"
    result = CliRunner().invoke(
        _app(),
        ["eval", str(gt_path), str(est_path), "--delta", "10", "--json", str(out_json),
         "--report", str(out_html)],
    )
    assert result.exit_code == 0, result.output
    expected = ate(read_tum(gt_path), read_tum(est_path))
    assert f"{expected.stats['rmse']:.6f}" in result.output
    payload = json.loads(out_json.read_text())
    assert payload["ate"]["rmse"] == pytest.approx(expected.stats["rmse"], rel=1e-12)
    expected_rpe = rpe(read_tum(gt_path), read_tum(est_path), delta=10, align="se3")
    assert payload["rpe"]["trans"]["rmse"] == pytest.approx(expected_rpe.trans_stats["rmse"])
    assert payload["rpe"]["delta_unit"] == "frames"
    assert "data:image/png;base64," in out_html.read_text()


def test_eval_missing_file_is_a_trajectory_error(files, tmp_path: Path) -> None:
    gt_path, _ = files
    missing = tmp_path / "missing.txt"
    result = CliRunner().invoke(_app(), ["eval", str(gt_path), str(missing)])
    assert result.exit_code != 0
    assert isinstance(result.exception, TrajectoryError)
    assert str(missing) in str(result.exception)


def test_eval_kitti_with_times(shared_data: Path) -> None:
    d = shared_data / "trajectories"
    result = CliRunner().invoke(
        _app(),
        ["eval", str(d / "KITTI_00_gt.txt"), str(d / "KITTI_00_ORB.txt"),
         "--gt-times", str(d / "KITTI_00_gt_times.txt"), "--delta", "10", "--delta-unit", "meters"],
    )
    assert result.exit_code == 0, result.output
    assert "1.303450" in result.output  # evo's APE rmse for this pair (orb_ape archive)


def _main_available() -> bool:
    """main() imports every command module; some belong to other work still in progress."""
    try:
        for name in ("semslam.cli.run_cmd", "semslam.cli.synth_cmd"):
            importlib.import_module(name)
    except Exception:  # noqa: BLE001 - any import failure means "not ready yet"
        return False
    return True


@pytest.mark.skipif(not _main_available(), reason="other CLI commands not importable yet")
def test_main_entry_point(files, tmp_path: Path, capsys) -> None:
    from semslam.cli.main import main

    gt_path, est_path = files
    assert main(["eval", str(gt_path), str(est_path)]) == 0
    expected = ate(read_tum(gt_path), read_tum(est_path))
    assert f"{expected.stats['rmse']:.6f}" in capsys.readouterr().out
    missing = tmp_path / "nope.txt"
    assert main(["eval", str(gt_path), str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err
