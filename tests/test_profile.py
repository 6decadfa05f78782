"""``semslam bench --profile``: py-spy's raw stacks are turned into CPU seconds per thread,
per stage and per function, exactly (hand-made stacks), and a real profiled run reports
the threads a threaded SLAM run has."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from semslam.cli.main import main
from semslam.experiments.profile import parse_raw

RAW = "\n".join([
    # tracking: 30 samples in extraction, 10 in the local map, 5 in importing
    'process 1:"";thread (1): MainThread;run_slam (semslam/pipeline.py:81);track (semslam/slam/orb/tracking.py:90);'
    'extract (semslam/features/orb_slam2.py:120);fast_points (semslam/features/orb/detection.py:40) 30',
    'process 1:"";thread (1): MainThread;run_slam (semslam/pipeline.py:81);track (semslam/slam/orb/tracking.py:90);'
    '_track_local_map (semslam/slam/orb/tracking.py:300);search_by_projection (semslam/slam/orb/search.py:50) 10',
    'process 1:"";thread (1): MainThread;<module> (semslam:6);_find_and_load (<frozen importlib._bootstrap>:1176);'
    'exec_module (<frozen importlib._bootstrap_external>:940) 5',
    # local mapping: 20 samples fusing
    'process 1:"";thread (7): local-mapping;_run (semslam/slam/orb/keyframe_worker.py:110);'
    '_search_in_neighbours (semslam/slam/orb/local_mapping.py:230);fuse (semslam/slam/orb/fusion.py:40) 20',
    # the BA worker process (its command line has a ';' inside the quotes): 25 samples in GTSAM
    'process 1:"";process 9:"python -c from multiprocessing.spawn import spawn_main; spawn_main(tracker_fd=8)";'
    'thread (9): MainThread;bundle_adjust (semslam/backend/bundle_adjustment.py:270);'
    '_optimize (semslam/backend/bundle_adjustment.py:230) 25',
    "not a stack line",
])


def test_raw_stacks_become_cpu_per_thread_stage_and_function() -> None:
    p = parse_raw(RAW, rate_hz=100.0)
    assert p.thread_s == {"tracking (main)": 0.45, "BA worker process": 0.25, "local-mapping": 0.20}
    assert p.stage_s[("tracking (main)", "extract")] == pytest.approx(0.30)
    assert p.stage_s[("tracking (main)", "local map")] == pytest.approx(0.10)
    assert p.stage_s[("tracking (main)", "imports")] == pytest.approx(0.05)
    assert p.stage_s[("local-mapping", "fusion")] == pytest.approx(0.20)
    assert p.stage_s[("BA worker process", "bundle adjustment (GTSAM)")] == pytest.approx(0.25)
    assert p.self_s[0] == ("fast_points (semslam/features/orb/detection.py)", pytest.approx(0.30))
    total = dict(p.total_s)
    assert total["extract (semslam/features/orb_slam2.py)"] == pytest.approx(0.30)
    assert "run_slam (semslam/pipeline.py)" not in total  # the entry chain is left out


def test_a_worker_seen_with_its_parents_command_line_is_named_by_its_stacks() -> None:
    """py-spy reads a child's command line once; caught between fork and exec it is the
    parent's (seen on CI). multiprocessing's spawn entry on its stacks still names it."""
    parent_cmd = 'process 1:"";process 9:"python -m semslam.cli.main run data --preset orb";thread (9): MainThread'
    raw = "\n".join([
        f"{parent_cmd} 3",  # the first samples: no frame yet
        f"{parent_cmd};<module> (<string>:1);spawn_main (multiprocessing/spawn.py:122);"
        "_main (multiprocessing/spawn.py:131);bundle_adjust (semslam/backend/bundle_adjustment.py:270) 7",
        'process 1:"";process 5:"python -c from multiprocessing.resource_tracker import main;main(7)";'
        "thread (5): MainThread;main (multiprocessing/resource_tracker.py:200) 2",
    ])
    p = parse_raw(raw, rate_hz=100.0)
    assert p.thread_s == {"BA worker process": pytest.approx(0.10), "other process": pytest.approx(0.02)}


@pytest.mark.slow
def test_bench_profile_reports_every_thread_of_a_threaded_run(tmp_path: Path) -> None:
    js = tmp_path / "profile.json"
    code = main(["bench", "--profile", "--presets", "orb", "--sequences", "static_xyz", "--frames", "40",
                 "--data", str(tmp_path / "data"), "--out", str(tmp_path / "runs"), "--json", str(js)])
    assert code == 0
    doc = json.loads(js.read_text())
    threads = doc[0]["cpu_s_per_thread"]
    assert {"tracking (main)", "local-mapping", "BA worker process"} <= set(threads)
    stages = {(r["thread"], r["stage"]) for r in doc[0]["cpu_s_per_stage"]}
    # local BA solves (compiled Schur LM) in local mapping's thread; the GTSAM worker starts
    # but solves only loop closing's problems (none here)
    assert ("tracking (main)", "extract") in stages and ("local-mapping", "local BA (build/apply)") in stages
    assert doc[0]["ms_per_frame"]["median"] > 0 and (tmp_path / "runs/orb/static_xyz/profile.raw.txt").is_file()
