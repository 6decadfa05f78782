"""A BA worker process that dies (killed, out of memory) is replaced and the solve redone;
the pose graph solved after the restart equals the one solved in this process."""

from __future__ import annotations

import os
import signal
import time

import numpy as np

from semslam.backend.pose_graph import optimize_pose_graph
from semslam.backend.worker import BundleAdjustmentRunner
from tests.test_backend import loop_graph


def _kill(pid: int) -> None:
    os.kill(pid, signal.SIGKILL)
    end = time.monotonic() + 10
    while time.monotonic() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)


def test_a_killed_ba_worker_is_restarted_and_the_solve_redone() -> None:
    _, init, edges, meas = loop_graph()
    reference = optimize_pose_graph(init, edges, meas, fixed=[0])
    runner = BundleAdjustmentRunner()
    runner.start(use_process=True)
    try:
        first = runner.run_pose_graph(init, edges, meas, fixed=[0])
        np.testing.assert_allclose(first, reference, atol=1e-9)
        (pid,) = runner.worker_pids()
        _kill(pid)  # while idle: the next solve finds the pool broken
        again = runner.run_pose_graph(init, edges, meas, fixed=[0])
        np.testing.assert_allclose(again, reference, atol=1e-9)
        assert runner.restarts == 1
        (new_pid,) = runner.worker_pids()
        assert new_pid != pid
    finally:
        runner.close()
    assert runner.worker_pids() == []
