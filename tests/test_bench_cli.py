"""``semslam bench`` on the typer CLI and the run API: each row is the run's RunResult, read
back from the stats.json the run wrote, and the JSON, the table and the files agree."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from semslam.cli.main import main
from semslam.core.types import RunResult
from semslam.experiments.bench import Variant


def test_bench_rows_are_the_runs_results(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, js = tmp_path / "runs", tmp_path / "bench.json"
    assert main(["bench", "--presets", "f2kf", "--variant", "orb-seq:orb:slam.sequential=true,slam.loop_closing=false",
                 "--sequences", "static_xyz", "--frames", "30", "--data", str(tmp_path / "data"), "--out", str(out),
                 "--json", str(js)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads(js.read_text())
    assert [r["variant"] for r in doc["results"]] == ["f2kf", "orb-seq"]
    for row in doc["results"]:
        stats = json.loads((out / row["variant"] / "static_xyz" / "stats.json").read_text())
        result = RunResult.from_dict(stats)
        assert row["ate_rmse_m"] == result.ate_rmse and row["frames"] == result.frames == 30
        assert row["ms_per_frame_median"] == result.ms_per_frame["median"]
        assert f"| static_xyz | 0 | {row['variant']} | 30 ({result.tracked_frames}) |" in printed
    assert doc["results"][1]["loops"] == 0 and doc["results"][0]["loops"] is None  # f2kf has no loop closing


def test_variant_syntax_errors_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert Variant.parse("orb") == Variant("orb", "orb")
    assert Variant.parse("x:orb:a.b=1,c.d=2") == Variant("x", "orb", ("a.b=1", "c.d=2"))
    assert main(["bench", "--variant", "a:b:c:d", "--sequences", "static_xyz"]) == 2
    assert "expected label:preset" in capsys.readouterr().err
    assert main(["bench", "--sequences", "nope"]) == 2
    assert "unknown nope" in capsys.readouterr().err
