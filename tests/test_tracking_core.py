"""``runtime.tracking_core``: the tracking thread alone on one CPU, background threads and
worker processes on the others, one CPU per concurrent run, everything restored after."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from semslam.runtime import (
    BACKGROUND_CPUS_VARIABLE,
    _claim_cpu,
    lower_thread_priority,
    move_off_tracking_core,
    tracking_core,
)

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                                reason="needs Linux affinity and two or more CPUs")


def _in_thread(fn) -> set[int]:  # type: ignore[no-untyped-def]
    """The CPUs a fresh thread may run on after calling ``fn``."""
    seen: list[set[int]] = []

    def body() -> None:
        fn()
        seen.append(set(os.sched_getaffinity(0)))

    t = threading.Thread(target=body)
    t.start()
    t.join()
    return seen[0]


def test_tracking_thread_alone_background_elsewhere_and_restored() -> None:
    allowed = set(os.sched_getaffinity(0))
    with tracking_core() as core:
        if core.cpu is None:  # every CPU claimed by runs on this machine right now
            pytest.skip("every CPU is claimed by another run")
        assert core.cpu in allowed
        assert set(os.sched_getaffinity(0)) == {core.cpu}
        rest = allowed - {core.cpu}
        assert os.environ[BACKGROUND_CPUS_VARIABLE] == ",".join(map(str, sorted(rest)))
        # Threads start on the tracking CPU (inherited) and move off when they say so.
        assert _in_thread(lambda: None) == {core.cpu}
        assert _in_thread(move_off_tracking_core) == rest
        assert _in_thread(lower_thread_priority) == rest
        with tracking_core() as inner:  # one pinned run per process: a nested one is not pinned
            assert inner.cpu is None
        assert set(os.sched_getaffinity(0)) == {core.cpu}
    assert set(os.sched_getaffinity(0)) == allowed
    assert BACKGROUND_CPUS_VARIABLE not in os.environ
    assert _in_thread(move_off_tracking_core) == allowed  # no pinned run: nothing moves


def test_concurrent_runs_take_different_cpus_or_none() -> None:
    allowed = sorted(os.sched_getaffinity(0))
    held = _claim_cpu(allowed[0])  # as another run's lock would
    if held is None:
        pytest.skip("the first CPU is claimed by another run")
    try:
        with tracking_core() as core:
            assert core.cpu != allowed[0]
        claims = [fd for fd in (_claim_cpu(c) for c in allowed[1:]) if fd is not None]
        try:
            if len(claims) == len(allowed) - 1:  # every CPU taken: the run is not pinned
                with tracking_core() as none:
                    assert none.cpu is None
                    assert set(os.sched_getaffinity(0)) == set(allowed)
                    assert BACKGROUND_CPUS_VARIABLE not in os.environ
        finally:
            for fd in claims:
                os.close(fd)
    finally:
        os.close(held)
    with tracking_core(enabled=False) as off:
        assert off.cpu is None and set(os.sched_getaffinity(0)) == set(allowed)


def test_run_slam_pins_only_when_asked_and_tracking_waits_for_no_mask(monkeypatch: pytest.MonkeyPatch,
                                                                      tmp_path: Path) -> None:
    """``slam.pin_tracking`` reaches ``tracking_core``, except with ``semantics.schedule:
    every`` (tracking's CPU would idle while it waits for each mask)."""
    import semslam.pipeline as pipeline
    from semslam.config import load_config

    asked: list[bool] = []

    class Stop(Exception):
        pass

    class Recorder:
        def __init__(self, enabled: bool = True) -> None:
            asked.append(enabled)

        def __enter__(self) -> None:
            raise Stop  # nothing runs: only the decision is checked

        def __exit__(self, *exc: object) -> None:
            pass

    class Sequence:
        has_depth = True

    monkeypatch.setattr(pipeline, "tracking_core", Recorder)
    for preset, overrides in (("orb", []), ("orb", ["slam.pin_tracking=true"]), ("default", ["slam.pin_tracking=true"]),
                              ("ddl", ["slam.pin_tracking=true"])):
        with pytest.raises(Stop):
            pipeline.run_slam(Sequence(), load_config(preset, overrides), tmp_path)  # type: ignore[arg-type]
    assert asked == [False, True, True, False]
