"""``benchmarks/long_run.py``'s verdict (issue 13, 6): what counts as growth between the
second and the last full thousand frames, and reusing a longer cached render. The run
itself takes minutes to hours and is not a test (README: Results)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "long_run.py"


@pytest.fixture(scope="module")
def long_run() -> Any:
    spec = importlib.util.spec_from_file_location("long_run", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _row(k: int, rss: float, workers: float, ms: float, n: int = 1000) -> dict[str, Any]:
    return {"frames": f"{k * 1000}-{k * 1000 + n - 1}", "n": n, "ms_median": ms, "ms_p95": 2 * ms, "cpu_ms_median": ms / 2, "rss_mb": rss,
            "workers_rss_mb": workers, "keyframes": 40, "map_points": 6000, "culled_keyframes": 0, "loops": 1,
            "lost": 0}


def test_growth_compares_the_second_and_the_last_full_window(long_run: Any) -> None:
    first_is_warm_up = [_row(0, 300, 200, 80), _row(1, 400, 250, 30), _row(2, 420, 250, 31), _row(3, 439, 274, 32.9)]
    assert long_run.growth(first_is_warm_up) == []  # +9.75 %, +9.6 %, +9.7 %: within 10 %
    grew = long_run.growth([*first_is_warm_up, _row(4, 441, 250, 30)])
    assert grew == ["RSS grew 10 % (400.0 -> 441.0, frames 1000-1999 -> 4000-4999)"]
    slower = long_run.growth([*first_is_warm_up, _row(4, 400, 250, 34)])
    assert slower == ["median ms/frame grew 13 % (30.0 -> 34.0, frames 1000-1999 -> 4000-4999)"]
    workers = long_run.growth([*first_is_warm_up, _row(4, 400, 300, 30)])
    assert workers == ["workers' RSS grew 20 % (250.0 -> 300.0, frames 1000-1999 -> 4000-4999)"]
    # A short last window (the run's remainder) is not compared; too few windows: no verdict.
    assert long_run.growth([*first_is_warm_up, _row(4, 900, 900, 90, n=10)]) == []
    assert long_run.growth(first_is_warm_up[:2]) == []
    table = long_run.table(first_is_warm_up).splitlines()
    assert len(table) == 6 and table[3].startswith("| 1000-1999 | 30.0 | 60.0 | 15.0 | 400 | 250 | 40 |")


def test_a_longer_cached_render_is_reused(long_run: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seq = tmp_path / long_run.SEQUENCE
    seq.mkdir()
    (seq / "sequence.json").write_text(json.dumps({"config": {"frames": 6000}}))
    monkeypatch.setattr(long_run, "render_sequence", lambda *a, **k: pytest.fail("rendered again"))
    assert long_run.cached_render(tmp_path, 3000) == (seq, 6000)
    rendered: list[int] = []

    def fake_render(cfg: Any, out: Path, progress: bool = False, resume: bool = False) -> Path:
        assert resume and (out / "sequence.json").is_file()  # the shorter render, to be extended
        rendered.append(cfg.frames)
        (out / "sequence.json").write_text(json.dumps({"config": {"frames": cfg.frames}}))
        return out

    monkeypatch.setattr(long_run, "render_sequence", fake_render)
    assert long_run.cached_render(tmp_path, 9000) == (seq, 9000)
    assert rendered == [9000] and not (tmp_path / f"{long_run.SEQUENCE}.partial").exists()
    assert json.loads((seq / "sequence.json").read_text())["config"]["frames"] == 9000
