"""Camera-rate runs (``slam.realtime`` / ``semslam run --realtime``): frames arrive at their
timestamps' spacing, as a live camera delivers them, and the run reports each frame's
latency and the frames that arrived while the previous one was still being tracked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import semslam.pipeline
from semslam.cli.main import main
from semslam.core.types import Frame
from semslam.pipeline import at_camera_rate
from semslam.synth import SEQUENCES, render_sequence


def _frames(stamps: list[float]) -> list[Frame]:
    img = np.zeros((4, 4, 3), np.uint8)
    return [Frame(i, t, img, None) for i, t in enumerate(stamps)]


class FakeClock:
    """Stands in for the pipeline's ``time``: ``perf_counter`` reads it, ``sleep`` advances it
    and is recorded. The pacing is then checked exactly, with no wall-clock bound that a busy
    machine could break."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(semslam.pipeline, "time", fake)
    return fake


def test_frames_arrive_at_their_timestamps_spacing(clock: FakeClock) -> None:
    stamps = [100.0, 100.05, 100.10, 100.25]
    arrivals = []
    for i, (_, t) in enumerate(at_camera_rate(iter(_frames(stamps)), realtime=True)):
        arrivals.append(t)
        if i == 1:
            clock.now += 0.08  # tracking frame 1 took longer than the frames' spacing
    # Never early; the schedule is kept from the first frame, so a late frame (the third,
    # due at 0.10 s, asked for at 0.13 s) comes at once and the next one is not late.
    assert np.allclose(np.subtract(arrivals, arrivals[0]), [0.0, 0.05, 0.13, 0.25])
    assert np.allclose(clock.sleeps, [0.05, 0.12])


def test_a_late_consumer_gets_frames_at_once_without_waiting_again(clock: FakeClock) -> None:
    """A frame already due when asked for (tracking fell behind) is not delayed further."""
    gen = at_camera_rate(iter(_frames([0.0, 0.5, 1.0])), realtime=True)
    next(gen)
    clock.now += 1.1  # both later frames are overdue now
    rest = [t for _, t in gen]
    assert rest == [clock.now, clock.now] and clock.sleeps == []


def test_without_realtime_frames_come_as_soon_as_asked(clock: FakeClock) -> None:
    out = list(at_camera_rate(iter(_frames([0.0, 5.0, 10.0])), realtime=False))
    assert len(out) == 3 and clock.sleeps == []  # at camera rate it would sleep 5 s twice


@pytest.mark.slow
def test_realtime_run_reports_latency(tmp_path: Path) -> None:
    seq = render_sequence(SEQUENCES["static_xyz"].replace(frames=30), tmp_path / "seq")
    out = tmp_path / "run"
    main(["run", str(seq), "-o", str(out), "-p", "orb", "--realtime", "--sequential", "--no-report", "-q"])
    stats = json.loads((out / "stats.json").read_text())
    assert stats["realtime"] is True and stats["tracked_frames"] == 30
    lat, ms = stats["latency_ms"], stats["ms_per_frame"]
    # Latency = time from arrival to pose: at least the tracking time of the frame.
    assert lat["median"] >= ms["median"] - 1e-6 and lat["max"] >= ms["max"] - 1e-6
    stamps = [float(line.split()[0]) for line in (seq / "rgb.txt").read_text().splitlines()
              if line and not line.startswith("#")][:30]
    assert stats["wall_s"] >= stamps[-1] - stamps[0]  # paced: no faster than the camera
