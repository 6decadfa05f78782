"""What ``semslam run`` writes and how it ends (issue 38): output paths refused before the
first frame, an earlier run's outputs refused unless ``--overwrite``, the run's record
(trajectory, keyframes, stats.json) written before the maps / --save-map / report, frame
counts that add up, exit codes of signals (SIGINT 130, SIGTERM 143), ``-q``, the presets
in ``--help``.

One 40-frame 320x240 render of two people walking, made once for the module; runs are
``orb`` without maps (sequential where the outcome must not depend on timing).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import shutil
import signal
import sys
from pathlib import Path

import pytest

from semslam.cli import run_cmd
from semslam.config.load import available_presets
from tests.cli_outcome import cli
from tests.test_interrupt import Run

FRAMES = 40
W, H = 320, 240
FAST = ("--preset", "orb", "--sequential", "--map", "none", "--no-report")






def stats_of(out: Path) -> dict:
    return json.loads((out / "stats.json").read_text())


def adds_up(stats: dict) -> bool:
    """The identity stats.json states: every frame given is tracked, lost, before
    initialisation, skipped or not reached."""
    parts = ("tracked_frames", "lost_frames", "uninitialized_frames", "skipped_frames", "frames_not_reached")
    return stats["frames_total"] == sum(stats[k] for k in parts) and \
        stats["frames"] == stats["tracked_frames"] + stats["lost_frames"] + stats["uninitialized_frames"]


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["walking_xyz"].replace(frames=FRAMES, width=W, height=H),
                           tmp_path_factory.mktemp("outputs") / "walking")


@pytest.fixture()
def a_file(tmp_path: Path) -> Path:
    """A regular file, for output paths under it."""
    path = tmp_path / "notes.txt"
    path.write_text("not a folder\n")
    return path


# --- 1. output paths that cannot be written: one line, exit 2, before the first frame ---------

BAD_PATHS = {
    "out_under_a_file": (lambda f: ["-o", f / "run"], "--out: cannot be created: {f} is a file"),
    "out_is_a_file": (lambda f: ["-o", f], "--out: exists and is not a folder"),
    "save_map_under_a_file": (lambda f: ["--save-map", f / "map.npz"], "--save-map: cannot be created: {f} is a file"),
    "save_map_is_a_folder": (lambda f: ["--save-map", f.parent], "--save-map: is a folder"),
    "rerun_under_a_file": (lambda f: ["--rerun", f / "run.rrd"], "--rerun: cannot be created: {f} is a file"),
    "save_inpainted_under_a_file": (lambda f: ["--save-inpainted", f / "inp"],
                                    "--save-inpainted: cannot be created: {f} is a file"),
}


@pytest.mark.parametrize("case", sorted(BAD_PATHS))
def test_unwritable_output_path_is_one_line_before_any_frame(case: str, base: Path, a_file: Path, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    def no_run(*args: object, **kwargs: object) -> None:
        raise AssertionError("the run started")

    monkeypatch.setattr(run_cmd, "run_slam", no_run)
    args, problem = BAD_PATHS[case]
    extra = args(a_file)
    if "-o" not in extra:
        extra = ["-o", tmp_path / "run", *extra]
    r = cli(capsys, "run", base, "-q", *FAST, *extra)
    assert r.rc == 2
    assert problem.format(f=a_file) in r.error_line
    assert not (tmp_path / "run").exists()  # nothing created, nothing read
    assert r.out == ""


def test_error_line_comes_alone_without_rolling_shutter_note(base: Path, a_file: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """A sequence that states a readout: the note is not printed before a refusal (nor with -q)."""
    seq = Path(shutil.copytree(base, tmp_path / "seq"))
    meta = json.loads((seq / "sequence.json").read_text())
    meta.setdefault("config", {})["rolling_shutter_ms"] = 25.0
    (seq / "sequence.json").write_text(json.dumps(meta))
    r = cli(capsys, "run", seq, *FAST, "-o", tmp_path / "run", "--save-map", a_file / "map.npz")
    assert r.rc == 2 and "--save-map" in r.error_line and r.out == ""


# --- 2. an earlier run's outputs: refused, or replaced with --overwrite ------------------------

def test_earlier_run_is_refused_then_replaced_by_overwrite(base: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    first = cli(capsys, "run", base, "-o", out, "-q", "--preset", "orb", "--sequential", "--map", "keyframe_cloud",
                "--save-map", out / "map" / "sparse.npz", "--rerun", out / "first.rrd")
    assert first.rc == 0 and first.out == "" and first.err == ""  # -q: nothing but errors
    assert (out / "report.html").is_file() and (out / "map").is_dir() and (out / "first.rrd").is_file()
    (out / "notes.txt").write_text("the user's own file\n")
    before = (out / "trajectory.txt").read_text()

    again = cli(capsys, "run", base, "-o", out, "-q", *FAST)
    line = again.error_line
    assert again.rc == 2 and "another run's outputs" in line and "--overwrite" in line and "report.html" in line
    assert (out / "trajectory.txt").read_text() == before and (out / "report.html").is_file()

    # --overwrite never deletes what the new run reads
    keep = cli(capsys, "run", base, "-o", out, "-q", *FAST, "--overwrite", "--load-map", out / "map" / "sparse.npz")
    assert keep.rc == 2 and "which this run reads" in keep.error_line
    assert (out / "map" / "sparse.npz").is_file()

    last = cli(capsys, "run", base, "-o", out, "-q", *FAST, "--max-frames", "12", "--overwrite")
    assert last.rc == 0
    assert not (out / "report.html").exists() and not (out / "map").exists() and not (out / "first.rrd").exists()
    assert (out / "notes.txt").read_text() == "the user's own file\n"  # not semslam's: left alone
    assert stats_of(out)["frames_total"] == 12


def test_interrupted_run_leftovers_are_refused_too(tmp_path: Path, base: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """What a Ctrl-C leaves (trajectory and stats.json, no report) counts as an earlier run."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "stats.json").write_text('{"interrupted": true}')
    (out / "unrelated.csv").write_text("1,2\n")
    r = cli(capsys, "run", base, "-o", out, "-q", *FAST)
    assert r.rc == 2 and "stats.json" in r.error_line and "unrelated" not in r.error_line


def test_folder_with_only_other_files_is_used(tmp_path: Path, base: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "README").write_text("my notes\n")
    assert cli(capsys, "run", base, "-o", out, "-q", *FAST, "--max-frames", "8").rc == 0
    assert (out / "README").is_file() and (out / "trajectory.txt").is_file()


# --- 3. the run's record is written before what may fail ---------------------------------------

def _enospc(path: str) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)


FAILURES = {
    "save_map": ("semslam.slam.orb.tracker.OrbTracker.save_map", "map.npz"),
    "maps": ("semslam.reconstruction.mapping_worker.MappingWorker.finish", "map"),
    "report": ("semslam.eval.report.write_report", "report.html"),
}


@pytest.mark.parametrize("what", sorted(FAILURES))
def test_failed_map_or_report_keeps_trajectory_and_stats(what: str, base: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str],
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    target, name = FAILURES[what]
    out = tmp_path / "run"

    def full_disk(*args: object, **kwargs: object) -> None:
        raise _enospc(str(out / name))

    monkeypatch.setattr(target, full_disk)
    extra = ["--save-map", out / "map.npz"] if what == "save_map" else []
    maps = ["--map", "keyframe_cloud"] if what == "maps" else ["--map", "none"]
    report = [] if what == "report" else ["--no-report"]  # the report needs > 1 s of poses: all 40 frames
    frames = [] if what == "report" else ["--max-frames", "15"]
    r = cli(capsys, "run", base, "-o", out, "-q", "--preset", "orb", "--sequential", *maps, *report, *frames, *extra)
    assert r.rc == 2
    assert f"{out / name}: cannot write (No space left on device)" in r.error_line
    assert "trajectory.txt and stats.json were written" in r.error_line
    stats = stats_of(out)
    assert "No space left on device" in stats["error"] and adds_up(stats)
    poses = [x for x in (out / "trajectory.txt").read_text().splitlines() if x and not x.startswith("#")]
    assert len(poses) == stats["tracked_frames"] > 0 and (out / "keyframes.txt").is_file()


# --- 4. counts that add up -------------------------------------------------------------------

def _listed(seq: Path, kind: str) -> list[Path]:
    lines = [x for x in (seq / f"{kind}.txt").read_text().splitlines() if x and not x.startswith("#")]
    return [seq / x.split()[1] for x in lines]


def test_missing_listed_files_are_each_named_and_counted(base: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str],
                                                         caplog: pytest.LogCaptureFixture) -> None:
    seq = Path(shutil.copytree(base, tmp_path / "seq"))
    rgb, depth = _listed(seq, "rgb"), _listed(seq, "depth")
    gone = [rgb[0], rgb[11], depth[23]]  # the first frame's too: a missing first file is skipped
    for path in gone:
        path.unlink()
    with caplog.at_level(logging.WARNING):
        r = cli(capsys, "run", seq, "-o", tmp_path / "run", *FAST)
    assert r.rc == 0, r.err
    stats = stats_of(tmp_path / "run")
    assert stats["skipped"] == [f"{p}: file not found" for p in gone]
    assert stats["frames_total"] == FRAMES and stats["skipped_frames"] == 3 and stats["frames"] == FRAMES - 3
    assert stats["frames_not_reached"] == 0 and adds_up(stats)
    warned = [rec.getMessage() for rec in caplog.records if "skipping frame" in rec.getMessage()]
    assert [w.split(": ", 1)[1] for w in warned] == stats["skipped"]  # each names its own file
    assert re.search(rf"frames \(tracked / total\)\s*│\s*{stats['tracked_frames']} / {FRAMES}\b", r.out), r.out
    assert "rolling shutter" not in r.out  # the render states 0 ms: nothing to say

    r = cli(capsys, "run", seq, "-o", tmp_path / "first15", "-q", *FAST, "--max-frames", "15")
    stats = stats_of(tmp_path / "first15")
    assert r.rc == 0 and stats["frames_total"] == 15 and stats["skipped_frames"] == 2 and adds_up(stats)


def test_counts_add_up_on_a_clean_run(base: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    r = cli(capsys, "run", base, "-o", tmp_path / "run", "-q", *FAST, "--max-frames", "10")
    stats = stats_of(tmp_path / "run")
    assert r.rc == 0 and stats["frames_total"] == stats["frames"] == 10 and adds_up(stats)


# --- 5. conventions: --help, signals -----------------------------------------------------------

def test_help_lists_every_preset_with_a_line(capsys: pytest.CaptureFixture[str]) -> None:
    r = cli(capsys, "run", "--help")
    assert r.rc == 0
    for name in available_presets():
        assert re.search(rf"^\W*{name}: \w", r.out, re.MULTILINE), name
    assert "--overwrite" in r.out




@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_exit_codes_and_outputs(sig: int, base: Path, tmp_path: Path) -> None:
    """At the camera's rate (40 frames: 1.3 s), stopped once tracking has begun."""
    out = tmp_path / "run"
    child = Run(base, out, "--map", "none", "--no-report", preset="orb", frames=FRAMES)
    child.wait_for_frames(4)
    os.kill(child.proc.pid, sig)
    rc, _ = child.wait()
    assert rc == {signal.SIGTERM: 143, signal.SIGINT: 130}[sig], child.err[-2000:]
    assert "Traceback" not in child.err and "interrupted: stopped after" in child.err
    stats = stats_of(out)
    assert stats["interrupted"] is True and adds_up(stats) and stats["frames_total"] == FRAMES
    assert stats["frames_not_reached"] > 0  # stopped early: the rest is counted as such
    poses = [x for x in (out / "trajectory.txt").read_text().splitlines() if x and not x.startswith("#")]
    assert len(poses) == stats["tracked_frames"] > 0
