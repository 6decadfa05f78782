"""``RunResult``'s typed counter blocks: every counter a component reports lands in its
block's field, none is lost, and ``stats.json`` keeps its layout byte for byte (written,
read back, written again)."""

from __future__ import annotations

import json
from dataclasses import FrozenInstanceError, fields, replace
from pathlib import Path

import pytest

from semslam.core.results import BLOCKS, STATS_LAYOUT, MapBuildingCounters, TrackingCounters
from semslam.core.types import RunResult

# The counters each component reports, in the order it reports them, and the block each
# belongs to (read from the components' ``stats()``).
ORB_TRACKER = {  # slam/orb/tracker.py OrbTracker.stats
    "map_points": "mapping", "loops": "loop_closing", "loop_pairs": "loop_closing", "relocalisations": "tracking",
    "depth_odometry_frames": "tracking", "coasted_frames": "tracking", "coast_keyframes": "tracking",
    "coasted_on_shift_only": "tracking", "depth_odometry_runs": "tracking", "local_ba": "mapping",
    "local_ba_failed": "mapping", "local_ba_ms_median": "mapping", "local_mapping_cpu_ms": "mapping",
    "global_ba": "loop_closing", "global_ba_failed": "loop_closing", "pose_graph_failed": "loop_closing",
    "loops_dropped": "loop_closing", "ba_worker_restarts": "mapping", "culled_keyframes": "mapping",
    "triangulated_points": "mapping", "culled_dynamic_points": "tracking", "threaded": "mapping",
}
ATLAS = {  # slam/orb/atlas.py Atlas.stats, at the end of the ORB tracker's
    "maps": "atlas", "merges": "atlas", "maps_unmerged": "atlas", "trajectory_frames_by_map": "atlas",
    "frames_outside_first_map": "atlas", "trajectory_map_runs": "atlas", "merges_rejected": "atlas",
    "merge_checks": "atlas",
}
SDF_TRACKER = {  # slam/trackers/sdf_slam.py SdfSlamTracker.stats
    "map_points": "mapping", "tracking_edges": "tracking", "reanchors": "tracking", "fallback_reference": "tracking",
    "global_rounds": "loop_closing", "global_pairs_tried": "loop_closing", "global_constraints": "loop_closing",
    "pose_graph_failed": "loop_closing", "alignment_kept": "tracking", "depth_alignment_fits": "tracking",
    "depth_alignment_power_p5_p50_p95": "tracking", "depth_alignment_ratio_p5_p50_p95": "tracking",
}
SEMANTIC_THREAD = dict.fromkeys((  # dynamics/semantic_thread.py SemanticThread.stats
    "segmented_frames", "segment_ms_median", "segment_ms_p95", "srm_ms_median", "semantic_wait_ms_median",
    "semantic_wait_ms_p95", "warped_frames", "warp_ms_median", "warp_ms_p95", "frames_without_own_mask",
    "resized_label_maps"), "dynamics")
MAPPING_WORKER = dict.fromkeys((  # reconstruction/mapping_worker.py _finish, queue_profile, finish
    "map_keyframes", "map_segmented_keyframes", "map_keyframe_ms_median", "map_finish_s", "inpaint_ms_median",
    "inpaint_dynamic_px", "inpaint_filled_share", "inpaint_synthesized_share", "inpainted_frames_written",
    "map_queue_first_third_max", "map_queue_last_third_max", "map_queue_end", "map_queue_max"), "map_building")
INPUT_HEALTH = dict.fromkeys(("frames_all_dynamic", "frames_featureless", "frames_without_depth"),
                             "input_health")  # io/input_health.py InputHealth.stats
SYSTEM = {"jit_warmup_s": "tracking"}  # the numba warm-up before the first frame
AFTER_TRACKER = {**SEMANTIC_THREAD, **MAPPING_WORKER, **INPUT_HEALTH, **SYSTEM}



def _run_with(counters: dict[str, object]) -> RunResult:
    result = RunResult("seq", "p", Path("out"))
    result.set_counters(counters)
    return result

@pytest.mark.parametrize("reported", [{**ORB_TRACKER, **ATLAS, **AFTER_TRACKER}, {**SDF_TRACKER, **AFTER_TRACKER}],
                         ids=["orb", "sdf"])
def test_every_reported_counter_lands_in_its_block_in_the_layout_order(reported: dict[str, str]) -> None:
    counters = {key: i for i, key in enumerate(reported)}  # distinct values: each must land in its own field
    result = _run_with(counters)
    assert result.other_counters == {}
    for key, block in reported.items():
        assert getattr(getattr(result, block), key) == counters[key], key
    written = result.to_dict()
    assert list(written)[-len(counters):] == list(counters)  # stats.json's order: as the components report
    assert result.counters() == counters


def test_layout_names_each_block_field_once_and_none_shadows_a_run_field() -> None:
    block_keys = [key for cls in BLOCKS.values() for key in cls.keys()]
    assert sorted(STATS_LAYOUT) == sorted(block_keys) and len(set(block_keys)) == len(block_keys)
    run_fields = {f.name for f in fields(RunResult)}
    assert not run_fields & set(STATS_LAYOUT)
    assert set(BLOCKS) <= run_fields


def test_unknown_counters_are_kept_in_place_of_dropped() -> None:
    result = _run_with({"loops": 2, "new_counter": [1, 2]})
    assert result.loop_closing.loops == 2 and result.other_counters == {"new_counter": [1, 2]}
    again = RunResult.from_dict(json.loads(json.dumps(result.to_dict())))
    assert again.other_counters == {"new_counter": [1, 2]} and again.to_dict() == result.to_dict()


def test_blocks_are_values() -> None:
    block = TrackingCounters.from_counters({"coasted_frames": 3, "loops": 1})
    assert block == TrackingCounters(coasted_frames=3) and block.to_dict() == {"coasted_frames": 3}
    with pytest.raises(FrozenInstanceError):
        block.coasted_frames = 4  # type: ignore[misc]
    assert MapBuildingCounters().to_dict() == {}


def test_counters_set_after_the_run_replace_every_block() -> None:
    """The maps' counters come once the maps are written: setting the counters again
    replaces every block, and a counter not reported again is gone."""
    result = _run_with({"map_points": 5, "coasted_frames": 1})
    later = {"map_points": 6, "map_keyframes": 3}
    result.set_counters(later)
    assert result.mapping.map_points == 6 and result.map_building.map_keyframes == 3
    assert result.tracking.coasted_frames is None
    assert result.to_dict()["map_keyframes"] == 3 and "coasted_frames" not in result.to_dict()
    copy = replace(result, preset="q")
    assert copy.to_dict() == {**result.to_dict(), "preset": "q"}


def test_real_run_stats_json_round_trips_byte_for_byte(tum_folder: Path, tmp_path: Path) -> None:
    """A default run (tracker, atlas, dynamic stage, map builders, input checks): every
    counter it wrote is in a typed field, and writing it back gives the same file."""
    from tests.conftest import run_cli

    out = tmp_path / "run"
    run_cli(tum_folder, out, "--preset", "default", "--sequential", "--no-report", "--map", "cloud")
    text = (out / "stats.json").read_text()
    result = RunResult.from_dict(json.loads(text))
    assert result.other_counters == {}
    assert json.dumps(result.to_dict(), indent=2) == text
    assert result.mapping.map_points is not None and result.atlas.maps == 1
    assert result.dynamics.segmented_frames is not None and result.map_building.map_keyframes is not None
    assert result.input_health.frames_featureless is not None and result.tracking.jit_warmup_s is not None
