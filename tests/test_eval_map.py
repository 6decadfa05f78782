"""Maps end to end against the renderer's true scene (``semslam eval-map``).

With the ground-truth segmenter (every frame labelled) on the static render, the octree's
fused classes match the true surfaces' classes and the semantic cloud lies on them; on the
walking render, masking people keeps their ghosts out of the semantic cloud, while mapping
every pixel leaves many. Measured (90 frames): octree MPA 0.96 (cloud 0.97), octree
precision / recall 0.86 / 0.83, cloud point accuracy 0.94 within 5 cm (0.98 with the
ground-truth poses: the rest is the trajectory's error, amplified at 3-4 m). Bounds leave
room for run-to-run noise.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from semslam.cli.main import main
from tests.conftest import run_cli

GT_SEG = ["--preset", "default", "--sequential", "--no-report", "--map", "octree,cloud",
          "--set", "semantics.backend=ground_truth", "--set", "semantics.stride=1",
          "--set", "maps.inpainting.enabled=false"]


def _eval(out: Path, seq: Path) -> dict:
    assert main(["eval-map", str(out), str(seq), "--json", str(out / "eval_map.json")]) == 0
    return json.loads((out / "eval_map.json").read_text())


@pytest.mark.slow
def test_octree_classes_and_cloud_match_the_true_static_scene(static_render: Path, tmp_path: Path) -> None:
    out = tmp_path / "static"
    run_cli(static_render, out, *GT_SEG)
    ev = _eval(out, static_render)
    assert ev["octree_mpa"] >= 0.85, ev["octree_class_accuracy"]
    assert ev["cloud_mpa"] >= 0.85, ev["cloud_class_accuracy"]
    assert ev["octree_precision"] >= 0.8 and ev["octree_recall"] >= 0.7
    assert ev["cloud_point_accuracy"] >= 0.9
    assert ev["octree_ghost_voxels"] == 0 and ev["cloud_ghost_points"] == 0  # nobody walks here


@pytest.mark.slow
def test_masking_keeps_people_out_of_the_maps(walking_render: Path, tmp_path: Path) -> None:
    masked = _eval_run(walking_render, tmp_path / "masked", [])
    unmasked = _eval_run(walking_render, tmp_path / "unmasked", ["--set", "maps.mask_dynamic=false"])
    assert masked["cloud_ghost_share"] < 0.01
    assert unmasked["cloud_ghost_share"] > 0.05
    assert unmasked["cloud_ghost_points"] > 20 * max(1, masked["cloud_ghost_points"])


def _eval_run(seq: Path, out: Path, extra: list[str]) -> dict:
    run_cli(seq, out, *GT_SEG, *extra)
    return _eval(out, seq)


def test_eval_map_names_what_is_missing(tmp_path: Path, tum_folder: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    assert main(["eval-map", str(run), str(tum_folder)]) == 2  # no trajectory.txt
    for name in ("trajectory.txt", "keyframes.txt"):
        (run / name).write_text((tum_folder / "groundtruth.txt").read_text())
    assert main(["eval-map", str(run), str(tum_folder)]) == 2  # no maps
    (run / "map").mkdir()
    (run / "map" / "mesh.ply").write_bytes(b"ply\n")
    assert main(["eval-map", str(run), str(tum_folder)]) == 2  # not a synthetic sequence: no scene.json
