"""``semslam train reproduce``: the recipes equal what the shipped checkpoints record about
their own making (data, renders, every training stage's options), and the command runs a
recipe end to end (a tiny one here; the real ones take an hour)."""

from __future__ import annotations

import json
import re
import shlex
from dataclasses import asdict
from pathlib import Path

import pytest
import torch

from semslam.cli.main import main
from semslam.nets.recipes import RECIPES, Recipe, Render, TrainStep

DATA = Path(__file__).resolve().parents[1] / "semslam" / "data"
# Options the recorded commands spell out at their CLI defaults, which the recipes leave out.
DEFAULTS = {"--steps": "2000", "--blur-p": "0.5", "--pos-weight": "20.0", "--every": "1"}
PATHS = {"--out", "--init"}  # where files went on the machine that trained: not part of the recipe


def _options(argv: list[str]) -> dict[str, list[str]]:
    """Flag -> values; folders reduced to their names, numbers to floats' text."""
    out: dict[str, list[str]] = {}
    for flag, value in zip(argv, argv[1:]):
        if not flag.startswith("--") or flag in PATHS or value.startswith("--"):
            continue
        if flag in ("--data", "--val"):
            value = Path(value).name
        else:
            try:
                value = repr(float(value))
            except ValueError:
                pass
        out.setdefault(flag, []).append(value)
    for flag, value in DEFAULTS.items():
        if out.get(flag) == [repr(float(value))]:
            del out[flag]
    return out


def _recorded(command: str) -> dict[str, list[str]]:
    return _options(shlex.split(command)[3:])  # after "semslam train NAME"


def _step(recipe: Recipe, output: str) -> dict[str, list[str]]:
    step = next(s for s in recipe.steps if s.output == output)
    return _options(step.resolve(Path("/d"), Path("/w"))[2:])


def _meta(name: str) -> dict:
    return torch.load(DATA / f"{name}.pt", weights_only=True)["meta"]


def test_sdfcnn_recipe_is_what_the_shipped_weights_record():
    recipe, meta = RECIPES["sdfcnn"], _meta("sdfcnn")
    assert _step(recipe, "sdfcnn.pt") == _recorded(meta["command"])
    renders = {r.name: r.config() for r in recipe.renders}
    pattern = re.compile(r"tum:(\S+) \(motion=(\w+), frames=(\d+), people=(\d+), mover=(\w+), seed=(\d+), "
                         r"fps=([\d.]+)\)")
    recorded = [pattern.fullmatch(s) for s in meta["train_data"] + meta["val_data"]]
    assert all(recorded) and len(recorded) == len(meta["train_data"]) + len(meta["val_data"]) == 6 + 6 + 96 + 2
    for m in recorded:
        cfg = renders[Path(m[1]).name]
        assert (cfg.motion, cfg.frames, cfg.people, cfg.mover, cfg.seed, cfg.fps) == (
            m[2], int(m[3]), int(m[4]), m[5] == "True", int(m[6]), float(m[7])), m[1]
    assert len(recipe.renders) == 103 and sum(renders[Path(m[1]).name].frames
                                              for m in recorded[:len(meta["train_data"])]) == meta["n_train_frames"]
    held_out = {cfg.layout for cfg in renders.values()}
    assert not held_out & {1, 2, 3} and 50 in held_out  # the lounge and rooms 2, 3 never rendered; 50 validates


def test_fpfdcnn_recipe_is_every_stage_the_shipped_weights_record():
    recipe, meta = RECIPES["fpfdcnn"], _meta("fpfdcnn")
    stage2 = meta["init"]
    stage1 = stage2["init"]
    assert stage1["init"] is None  # three stages, the first from random weights
    assert _step(recipe, "fpfdcnn.pt") == _recorded(meta["command"])
    assert _step(recipe, "fpfdcnn_stage2.pt") == _recorded(stage2["command"])
    assert _step(recipe, "fpfdcnn_stage1.pt") == _recorded(stage1["command"])
    # each stage starts from the one before
    inits = [s.resolve(Path("/d"), Path("/w")) for s in recipe.steps[:3]]
    assert "--init" not in inits[0] and inits[1][inits[1].index("--init") + 1] == "/w/fpfdcnn_stage1.pt"
    assert inits[2][inits[2].index("--init") + 1] == "/w/fpfdcnn_stage2.pt"


def test_dry_run_lists_every_command_and_marks_finished_renders(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    first = RECIPES["fpfdcnn"].renders[0]
    done = tmp_path / "data" / first.name
    done.mkdir(parents=True)  # what a finished render of that configuration leaves (synth.needs_render)
    for name in ("groundtruth.txt", "scene.json", "movers.json"):
        (done / name).write_text("{}")
    (done / "sequence.json").write_text(json.dumps({"config": asdict(first.config())}))
    assert main(["train", "reproduce", "fpfdcnn", "--work", str(tmp_path), "--dry-run"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 7 + 4 and lines[0].startswith(f"# done: semslam synth {done}")
    assert not any(ln.startswith("#") for ln in lines[1:]) and lines[-1] == f"semslam export-onnx {tmp_path}/fpfdcnn.pt"
    assert main(["train", "reproduce", "nope", "--work", str(tmp_path)]) == 2


def test_a_tiny_recipe_runs_end_to_end_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]):
    render = Render("tiny", {"motion": "xyz", "people": 0, "seed": 5, "frames": 4, "fps": 10.0, "width": 160,
                             "height": 120})
    train = TrainStep(("train", "fpfdcnn", "--data", "{data}/tiny", "--out", "{work}/tiny.pt", "--width", "0.25",
                       "--steps", "2", "--batch", "1", "--crop", "64x48", "--gaps", "1", "--threads", "1",
                       "--quiet"), "tiny.pt")
    export = TrainStep(("export-onnx", "{work}/tiny.pt"), "tiny.onnx")
    monkeypatch.setitem(RECIPES, "tiny", Recipe("tiny", (render,), (train, export), ("tiny.pt", "tiny.onnx")))
    assert main(["train", "reproduce", "tiny", "--work", str(tmp_path)]) == 0
    assert (tmp_path / "data" / "tiny" / "rgb.txt").is_file()
    assert (tmp_path / "tiny.pt").is_file() and (tmp_path / "tiny.onnx").is_file()
    capsys.readouterr()
    assert main(["train", "reproduce", "tiny", "--work", str(tmp_path), "--dry-run"]) == 0
    assert all(ln.startswith("# done: ") for ln in capsys.readouterr().out.strip().splitlines())
