"""A real `semslam run` (threads, the BA worker process, the maps' worker process) stopped by
signals: Ctrl-C / SIGTERM write what exists and exit 130 / 143, a second Ctrl-C exits at once, and
no process of the run outlives it, not even when the main process is SIGKILLed."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

FRAMES = 90  # conftest.E2E_FRAMES


class Run:
    """``semslam run`` in a child process, its progress bar read from stderr."""

    def __init__(self, seq: Path, out: Path, *extra: str, preset: str = "default", frames: int = FRAMES) -> None:
        cmd = [sys.executable, "-m", "semslam.cli.main", "run", str(seq), "--out", str(out), "--preset", preset,
               "--realtime", *extra]
        self.frames = frames  # the sequence's length, as the progress bar shows it
        self.proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                     cwd=Path(__file__).resolve().parents[1])
        self.err = ""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        while chunk := self.proc.stderr.read1(4096):  # type: ignore[attr-defined]
            self.err += chunk.decode(errors="replace")

    def frames_done(self) -> int:
        done = re.findall(rf"(\d+)/{self.frames}\b", self.err)
        return int(done[-1]) if done else 0

    def wait_for_frames(self, n: int, timeout: float = 120.0) -> None:
        end = time.monotonic() + timeout
        while self.frames_done() < n:
            assert self.proc.poll() is None, f"the run ended early: {self.err[-2000:]}"
            assert time.monotonic() < end, f"no progress: {self.err[-2000:]}"
            time.sleep(0.05)

    def children(self) -> list[int]:
        """Pids of the run's child processes (the BA worker, the maps' worker, multiprocessing's
        resource tracker)."""
        kids = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == self.proc.pid:
                kids.append(int(stat.parent.name))
        return kids

    def wait(self, timeout: float = 60.0) -> tuple[int, float]:
        t0 = time.monotonic()
        rc = self.proc.wait(timeout=timeout)
        self._reader.join(timeout=5)
        return rc, time.monotonic() - t0


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has exited


def wait_gone(pids: list[int], timeout: float = 15.0) -> list[int]:
    end = time.monotonic() + timeout
    while (left := [p for p in pids if alive(p)]) and time.monotonic() < end:
        time.sleep(0.1)
    return left


pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc (Linux)")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_the_run_and_writes_what_exists(walking_render: Path, tmp_path: Path, sig: int) -> None:
    out = tmp_path / "run"
    run = Run(walking_render, out, "--save-map", str(tmp_path / "map.npz"))
    run.wait_for_frames(10)
    kids = run.children()
    assert kids, "a default run has worker processes"
    os.kill(run.proc.pid, sig)
    rc, seconds = run.wait()
    assert rc == 128 + sig, run.err[-2000:]  # as shells report it: SIGINT 130, SIGTERM 143
    assert "interrupted: stopped after" in run.err
    stats = json.loads((out / "stats.json").read_text())
    assert stats["interrupted"] is True
    assert 10 <= stats["frames"] < FRAMES
    poses = [ln for ln in (out / "trajectory.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(poses) == stats["tracked_frames"] > 0
    assert (out / "keyframes.txt").is_file() and (tmp_path / "map.npz").is_file()
    assert stats["ate"] is not None  # the frames so far are evaluated
    assert not wait_gone(kids), "a worker process outlived the run"
    print(f"{signal.Signals(sig).name}: stopped in {seconds:.1f} s after {stats['frames']} frames")


def test_a_second_interrupt_exits_at_once_and_leaves_no_worker(walking_render: Path, tmp_path: Path) -> None:
    run = Run(walking_render, tmp_path / "run")
    run.wait_for_frames(10)
    kids = run.children()
    os.kill(run.proc.pid, signal.SIGINT)
    # As a user does: again once the run said it is stopping (two signals before the main
    # thread runs its handler would count as one). Shutting down takes far longer than this.
    end = time.monotonic() + 30
    while "stopping after this frame" not in run.err and time.monotonic() < end:
        time.sleep(0.01)
    os.kill(run.proc.pid, signal.SIGINT)
    rc, _ = run.wait()
    assert rc == 130
    assert "stopped at once" in run.err
    assert not wait_gone(kids)


def test_workers_exit_when_the_run_is_killed(walking_render: Path, tmp_path: Path) -> None:
    run = Run(walking_render, tmp_path / "run")
    run.wait_for_frames(10)
    kids = run.children()
    assert len(kids) >= 2  # the BA worker and the maps' worker (+ the resource tracker)
    run.proc.kill()
    run.wait()
    t0 = time.monotonic()
    assert not wait_gone(kids), "orphaned worker processes"
    print(f"workers gone {time.monotonic() - t0:.1f} s after SIGKILL")


def _loaded(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def test_the_run_goes_on_when_its_ba_worker_is_killed(walking_render: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run = Run(walking_render, out)
    run.wait_for_frames(10)
    ba = [p for p in run.children() if _loaded(p, "gtsam") and not _loaded(p, "octomap")]
    assert len(ba) == 1, "the BA worker (GTSAM loaded, no OctoMap) is found"
    os.kill(ba[0], signal.SIGKILL)
    rc, _ = run.wait(timeout=300)
    assert rc == 0, run.err[-2000:]
    stats = json.loads((out / "stats.json").read_text())
    assert stats["frames"] == stats["tracked_frames"] == FRAMES
    assert stats["ba_worker_restarts"] in (0, 1)  # 1 if a pose graph was solved after the kill
