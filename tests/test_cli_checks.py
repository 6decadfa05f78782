"""Values checked before the first frame (issue 38, items 4, 7, 8): every config field has a
range, `semslam run`'s --depth-scale / --camera and the image size are refused in one line
(exit 2, no traceback); `semslam eval` takes evo's flags with evo's numbers; `semslam
dataset list` prints whole names when piped; a person-only segmenter is named, and the
maps' legends say which classes were possible.

Runs are in-process (``semslam.cli.main.main``) on one 5-frame 320x240 render.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.config import SystemConfig, load_config
from semslam.config.checks import RULES, Num
from semslam.errors import ConfigError
from semslam.eval import rpe
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import read_tum, write_tum
from tests.cli_outcome import Outcome, cli

FRAMES = 5
W, H = 320, 240






@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["walking_xyz"].replace(frames=FRAMES, width=W, height=H),
                           tmp_path_factory.mktemp("checks") / "walking")


def run(capsys: pytest.CaptureFixture[str], sequence: Path, out: Path, *extra: object, preset: str = "orb") -> Outcome:
    return cli(capsys, "run", sequence, "--out", out, "--quiet", "--no-report", "--map", "none", "--sequential",
               "--preset", preset, *extra)


# --- 1. every config field has a rule; absurd values are refused naming the key -----------

def _fields(section: object, where: str = "") -> list[tuple[str, type, dataclasses.Field]]:
    """(key, section type, field) of every leaf field of the config tree."""
    out = []
    for f in dataclasses.fields(section):  # type: ignore[arg-type]
        key = f"{where}.{f.name}" if where else f.name
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(value):
            out += _fields(value, key)
        else:
            out.append((key, type(section), f))
    return out


LEAVES = _fields(SystemConfig())


def test_every_field_but_booleans_has_a_rule() -> None:
    missing = [key for key, cls, f in LEAVES if f.type not in ("bool", bool) and f.name not in RULES.get(cls, {})]
    assert missing == []


def _absurd(rule: Num, integer: bool) -> list[float]:
    """Values just outside the rule's range, and non-finite ones for floats."""
    step = 1 if integer else max(1e-6, 1e-3 * max(abs(rule.lo), abs(rule.hi)) if math.isfinite(rule.hi) else 1e-3)
    values: list[float] = []
    if math.isfinite(rule.lo):
        values.append(rule.lo if rule.lo_open else rule.lo - step)
    if math.isfinite(rule.hi):
        values.append(rule.hi if rule.hi_open else rule.hi + step)
    if not integer:
        values += [math.nan, math.inf, -math.inf]
    return [int(v) if integer else v for v in values]


def _yaml(value: float) -> str:
    return {math.inf: ".inf", -math.inf: "-.inf"}.get(value, ".nan" if value != value else repr(value))


NUMERIC = [(key, cls, f) for key, cls, f in LEAVES if isinstance(RULES[cls].get(f.name), Num)]


@pytest.mark.parametrize("key,cls,f", NUMERIC, ids=[key for key, _, _ in NUMERIC])
def test_absurd_numbers_are_refused_naming_the_key(key: str, cls: type, f: dataclasses.Field) -> None:
    rule = RULES[cls][f.name]
    assert isinstance(rule, Num)
    integer = f.type in ("int", int)
    values = _absurd(rule, integer)
    assert values, f"{key}: its rule refuses nothing"
    for value in values:
        with pytest.raises(ConfigError) as exc:
            load_config("orb", [f"{key}={_yaml(value)}"])
        message = str(exc.value)
        assert key in message and "\n" not in message, message


def test_every_preset_passes_its_checks() -> None:
    from semslam.config import available_presets

    for preset in available_presets():
        load_config(preset)


@pytest.mark.parametrize("override,expected", [
    ("features.n_features=-10", "features.n_features: expected an integer in [1, 100000], got -10"),
    ("features.n_levels=0", "features.n_levels: expected an integer in [1, 32], got 0"),
    ("maps.octree_resolution_m=0", "maps.octree_resolution_m: expected a number in [0.001, 10], got 0.0"),
    ("features.fast_min_threshold=30", "features.fast_min_threshold / features.fast_threshold: expected"),
    ("tracking.method=nope", "tracking.method: unknown tracker 'nope'"),
    ("semantics.input_width=16", "semantics.input_width: expected 0 or >= 32"),
    ("depth_scale=-5000", "depth_scale: expected a number > 0, got -5000"),
])
def test_reported_cases_refused_before_the_first_frame(override: str, expected: str, seq: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    r = run(capsys, seq, tmp_path / "out", "--set", override, "--map", "octree")
    assert expected in r.error_line
    assert not (tmp_path / "out" / "trajectory.txt").exists()


# --- 2. semslam run's flags -------------------------------------------------------------

@pytest.mark.parametrize("flags,expected", [
    (["--depth-scale", "0"], "--depth-scale: expected depth units per metre, a number > 0"),
    (["--depth-scale", "-5000"], "got -5000"),
    (["--depth-scale", "nan"], "got nan"),
    (["--camera", "a,b,c,d"], "--camera 'a,b,c,d': not a list of numbers"),
    (["--camera", "500,500,160"], "--camera: expected 4 numbers (fx fy cx cy) or 9"),
    (["--camera", "0,500,160,120"], "--camera: focal lengths must be positive"),
    (["--camera", "500,500,inf,120"], "--camera: every value must be a finite number"),
    (["--camera", "500,500,900,120"], "--camera: principal point cx=900 cy=120 lies outside the 320x240 image"),
    (["--camera", "500,500,160,-5"], "lies outside the 320x240 image"),
])
def test_bad_flags_are_one_line(flags: list[str], expected: str, seq: Path, tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    assert expected in run(capsys, seq, tmp_path / "out", *flags).error_line


# --- 3. images the extractor cannot use ---------------------------------------------------

@pytest.fixture(scope="module")
def tiny(seq: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """Copies of the render at 1x1 and 8x8 px (with a calib.txt for that size)."""
    copies = {}
    for side in (1, 8):
        root = Path(shutil.copytree(seq, tmp_path_factory.mktemp("tiny") / f"seq{side}"))
        for kind in ("rgb", "depth", "semantic"):
            for p in (root / kind).glob("*.png"):
                img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
                cv2.imwrite(str(p), cv2.resize(img, (side, side), interpolation=cv2.INTER_NEAREST))
        (root / "calib.txt").write_text(f"10 10 {side / 2} {side / 2}\n")
        copies[side] = root
    return copies


@pytest.mark.parametrize("side", [1, 8])
@pytest.mark.parametrize("preset,extractor,minimum", [("orb", "orb_slam2", 39), ("f2kf", "orb_opencv", 31)])
def test_tiny_images_are_refused_naming_file_size_and_minimum(side: int, preset: str, extractor: str, minimum: int,
                                                              tiny: dict[int, Path], tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    line = run(capsys, tiny[side], tmp_path / "out", preset=preset).error_line
    first = sorted((tiny[side] / "rgb").glob("*.png"))[0]
    assert str(first) in line and f"image is {side}x{side} px" in line
    assert f"features.extractor {extractor} needs at least {minimum}x{minimum}" in line


def test_pyramid_levels_without_room_are_named(seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                               caplog: pytest.LogCaptureFixture) -> None:
    """12 levels of 1.2 on 240 px: level 11 is 240 / 1.2^11 = 32 px, under 39 (2 x EDGE_THRESHOLD + 1);
    14 levels: 11-13 (level 10 rounds to 39)."""
    with caplog.at_level(logging.WARNING):
        r = run(capsys, seq, tmp_path / "out", "--set", "features.n_levels=12", "--max-frames", "2")
        r14 = run(capsys, seq, tmp_path / "out14", "--set", "features.n_levels=14", "--max-frames", "2")
    assert r.rc == 0 and r14.rc == 0, r.err + r14.err
    said = [rec.getMessage() for rec in caplog.records if "pyramid level" in rec.getMessage()]
    assert said == ["320x240 px images: pyramid level 11 of features.n_levels=12 (scale_factor 1.2) under 39 px "
                    "find no keypoints; features.n_levels=11 fits",
                    "320x240 px images: pyramid levels 11-13 of features.n_levels=14 (scale_factor 1.2) under 39 px "
                    "find no keypoints; features.n_levels=11 fits"]


# --- 4. semslam eval: evo's flags, evo's numbers ----------------------------------------

@pytest.fixture(scope="module")
def trajectories(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """10 s at 30 Hz; the estimate is the ground truth moved, scaled by 0.8 and noisy."""
    rng = np.random.default_rng(3)
    n = 300
    t = 100.0 + np.arange(n) / 30.0
    s = np.linspace(0, 4 * np.pi, n)
    pos = np.stack([np.cos(s), np.sin(s), 0.05 * s], axis=1)
    gt = Trajectory(t, make_pose(np.stack([so3_exp([0.0, 0.1 * a, a]) for a in s]), pos))
    est = make_pose(so3_exp([0.2, 0.0, -0.1]), [0.5, 0.0, 1.0]) @ gt.poses
    est[:, :3, 3] = 0.8 * est[:, :3, 3] + rng.normal(scale=0.02, size=(n, 3))
    root = tmp_path_factory.mktemp("eval")
    write_tum(root / "gt.txt", gt)
    write_tum(root / "est.txt", Trajectory(t + 0.003, est))
    return root / "gt.txt", root / "est.txt"


def _evo(gt: Path, est: Path, align: bool, correct_scale: bool, delta: float, unit: str,
         all_pairs: bool = False) -> dict[str, float]:
    """evo_ape / evo_rpe's rmse for the same files and flags, through evo's own API."""
    from evo import main_ape, main_rpe
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref, traj = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt)),
                                            file_interface.read_tum_trajectory_file(str(est)), max_diff=0.02)
    rel = metrics.PoseRelation
    kw = {"align": align, "correct_scale": correct_scale}
    rpe_kw = {**kw, "delta": delta, "delta_unit": metrics.Unit(unit), "all_pairs": all_pairs}
    return {
        "ate": main_ape.ape(copy.deepcopy(ref), copy.deepcopy(traj), rel.translation_part, **kw).stats["rmse"],
        "rpe_t": main_rpe.rpe(copy.deepcopy(ref), copy.deepcopy(traj), rel.translation_part, **rpe_kw).stats["rmse"],
        "rpe_r": main_rpe.rpe(copy.deepcopy(ref), copy.deepcopy(traj), rel.rotation_angle_deg,
                              **rpe_kw).stats["rmse"],
    }


def _ours(capsys: pytest.CaptureFixture[str], gt: Path, est: Path, tmp_path: Path, *flags: str) -> dict:
    out = tmp_path / "eval.json"
    r = cli(capsys, "eval", gt, est, *flags, "--json", out)
    assert r.rc == 0, r.err
    return json.loads(out.read_text())


@pytest.mark.parametrize("flags,align,scale,delta,unit,all_pairs", [
    (["-a", "--delta", "10"], True, False, 10, "frames", False),
    (["-a", "-s", "--delta", "5", "--delta_unit", "f"], True, True, 5, "frames", False),
    (["--correct_scale", "--delta_unit", "m", "--delta", "0.5"], False, True, 0.5, "m", False),
    (["--align", "--delta", "3", "--all_pairs"], True, False, 3, "frames", True),
    (["--align", "none", "--delta", "2"], False, False, 2, "frames", False),
])
def test_eval_with_evo_flags_gives_evo_numbers(flags: list[str], align: bool, scale: bool, delta: float, unit: str,
                                               all_pairs: bool, trajectories: tuple[Path, Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = trajectories
    ours = _ours(capsys, gt, est, tmp_path, *flags)
    evo = _evo(gt, est, align, scale, delta, unit, all_pairs)
    assert ours["ate"]["rmse"] == pytest.approx(evo["ate"], rel=1e-9)
    assert ours["rpe"]["trans"]["rmse"] == pytest.approx(evo["rpe_t"], rel=1e-9)
    assert ours["rpe"]["rot"]["rmse"] == pytest.approx(evo["rpe_r"], rel=1e-9)


def test_eval_default_is_what_run_reports(trajectories: tuple[Path, Path], tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """SE(3) ATE (evo -a) and RPE over 1 s, as run_record.evaluate computes them."""
    gt, est = trajectories
    ours = _ours(capsys, gt, est, tmp_path)
    run_rpe = rpe(read_tum(gt), read_tum(est), delta=1.0, delta_unit="seconds", align="none")
    assert ours["align"] == "se3" and ours["rpe"]["delta"] == 1.0 and ours["rpe"]["delta_unit"] == "seconds"
    assert ours["rpe"]["trans"]["rmse"] == pytest.approx(run_rpe.trans_stats["rmse"], rel=1e-12)
    assert ours["ate"]["rmse"] == pytest.approx(_evo(gt, est, True, False, 1, "frames")["ate"], rel=1e-9)


@pytest.mark.parametrize("flags,expected", [
    (["--delta_unit", "d"], "--delta-unit d: pairs by rotation angle"),
    (["--delta-unit", "hours"], "--delta-unit 'hours'"),
    (["--delta", "-1"], "--delta: expected a number > 0"),
    (["--align", "affine"], "--align 'affine'"),
])
def test_eval_bad_flags_are_one_line(flags: list[str], expected: str, trajectories: tuple[Path, Path],
                                     capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = trajectories
    assert expected in cli(capsys, "eval", gt, est, *flags).error_line


# --- 5. dataset list piped ------------------------------------------------------------------

def test_dataset_list_piped_prints_whole_names(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from semslam.datasets import CATALOGUE

    monkeypatch.setenv("COLUMNS", "40")
    r = cli(capsys, "dataset", "list", "--data-dir", tmp_path)
    assert r.rc == 0
    names = [line.split("\t")[0] for line in r.out.splitlines()]
    assert names == [entry.name for entry in CATALOGUE.values()]
    assert "tum/fr2_360_hemisphere" in names


# --- 6. a person-only segmenter is named; the legend says what was possible ----------------

def test_person_segmenter_is_named_once_and_legend_says_what_was_possible(
        seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    from semslam.semantics import base

    monkeypatch.setattr(base, "_TOLD_FEW_CLASSES", set())  # another test may have built it already
    with caplog.at_level(logging.WARNING):
        r = run(capsys, seq, tmp_path / "out", "--map", "cloud", preset="default")
    assert r.rc == 0, r.err
    told = [rec.getMessage() for rec in caplog.records if "knows only" in rec.getMessage()]
    assert told == ["segmenter mediapipe_person knows only: person; the maps will label everything else 'unknown'"]
    legend = json.loads((tmp_path / "out" / "map" / "semantic_cloud_classes.json").read_text())
    assert {row["name"] for row in legend.values() if row["possible"]} == {"unknown", "person"}
