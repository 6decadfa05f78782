"""Where a frame's tracking time went (semslam.thread_clock, RunTiming.thread_split): the
clock counts this thread's CPU work and not its sleep, and the split is the per-frame
arithmetic it says it is."""

from __future__ import annotations

import time

import numpy as np
import pytest

from semslam.core.types import TrackResult, TrackingState
from semslam.run_record import RunTiming
from semslam import thread_clock
from semslam.thread_clock import thread_times


def _spin(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_clock_counts_work_not_sleep() -> None:
    cpu0, runq0 = thread_times()
    time.sleep(0.2)
    cpu1, runq1 = thread_times()
    _spin(0.2)
    cpu2, runq2 = thread_times()
    assert cpu1 - cpu0 < 50.0, "a sleep is not CPU time"
    assert cpu2 - cpu1 >= 190.0, "0.2 s of spinning is ~200 ms of CPU"
    if thread_clock._has_schedstat:  # Linux: run-queue time only grows
        assert runq0 is not None and runq1 is not None and runq2 is not None
        assert 0.0 <= runq1 - runq0 and 0.0 <= runq2 - runq1


def test_clock_is_per_thread() -> None:
    """A thread's readings do not count another thread's spinning."""
    import threading

    cpu0, _ = thread_times()
    worker = threading.Thread(target=_spin, args=(0.3,))
    worker.start()
    worker.join()
    cpu1, _ = thread_times()
    assert cpu1 - cpu0 < 100.0


def test_thread_split_is_per_frame_wall_minus_cpu_minus_runqueue() -> None:
    timing = RunTiming()
    result = TrackResult(0.0, None, TrackingState.OK)
    # (wall ms, cpu ms, run-queue ms) of three frames
    frames = [(10.0, 6.0, 1.0), (20.0, 8.0, 2.0), (30.0, 10.0, 0.0)]
    t = 0.0
    for wall, cpu, runq in frames:
        timing.add(t, t + wall / 1e3, result, None, cpu, runq)
        t += 1.0
    split = timing.thread_split()
    assert split["cpu"] == pytest.approx(8.0)
    assert split["runqueue"] == pytest.approx(1.0)
    assert split["asleep"] == pytest.approx(np.median([3.0, 10.0, 20.0]))


def test_thread_split_without_run_queue_or_clock() -> None:
    result = TrackResult(0.0, None, TrackingState.OK)
    cpu_only = RunTiming()
    cpu_only.add(0.0, 0.01, result, None, 5.0, None)
    assert cpu_only.thread_split() == {"cpu": 5.0}
    unmeasured = RunTiming()
    unmeasured.add(0.0, 0.01, result, None)
    assert unmeasured.thread_split() == {}
