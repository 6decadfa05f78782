"""The recipes that made the shipped SDF-SLAM weights, as data: renders, training, export.

``semslam train reproduce sdfcnn|fpfdcnn --work DIR`` runs one (``cli/train_reproduce_cmd``),
so the shipped ``semslam/data/sdfcnn.pt`` and ``fpfdcnn.pt`` are remade by one command.
``semslam/data/NETS.md`` explains each choice and the results; the checkpoints record their
own data and training commands (``meta``), which the tests compare with these recipes.

Training stops on a time budget (``--minutes``) on a shared CPU, so a rerun sees the same
data and settings but not the same number of steps: it remakes weights of the same kind,
not the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from semslam.synth.sequences import SynthConfig, get_sequence

__all__ = ["RECIPES", "Recipe", "Render", "TrainStep"]

# SynthConfig field -> `semslam synth` flag (the fields the recipes set).
_SYNTH_FLAGS = {"motion": "--motion", "frames": "-n", "people": "--people", "seed": "--seed", "fps": "--fps",
                "width": "--width", "height": "--height", "layout": "--layout", "exposure_ms": "--exposure-ms",
                "rolling_shutter_ms": "--rolling-shutter-ms", "gain_swing": "--gain-swing",
                "white_balance_swing": "--white-balance-swing", "photo_textures": "--photo-textures"}
#: Folder (under the recipe's data folder) of the photographs for photo-textured renders,
#: written by ``python -m semslam.synth.textures DIR`` (needs the ``train`` extra and opencv-doc).
PHOTOS = "photos"


@dataclass(frozen=True)
class Render:
    """One ``semslam synth`` folder: a preset (or the defaults) with overrides."""

    name: str
    overrides: dict[str, Any]
    sequence: str | None = None

    def config(self, data: Path | None = None) -> SynthConfig:
        """The render's configuration; ``data``: the recipe's data folder (where its photos are)."""
        base = get_sequence(self.sequence) if self.sequence else SynthConfig()
        return base.replace(**self._resolved(data))

    def _resolved(self, data: Path | None) -> dict[str, Any]:
        photos = self.overrides.get("photo_textures")
        if photos is None:
            return dict(self.overrides)
        return {**self.overrides, "photo_textures": str((data or Path()) / photos)}

    def argv(self, data: Path) -> list[str]:
        args = ["synth", str(data / self.name)] + (["--sequence", self.sequence] if self.sequence else [])
        for key, value in self._resolved(data).items():
            if key == "mover":
                args.append("--mover" if value else "--no-mover")
            else:
                args += [_SYNTH_FLAGS[key], str(value)]
        return args + ["--quiet"]


@dataclass(frozen=True)
class TrainStep:
    """One ``semslam`` command after the renders; ``{data}`` and ``{work}`` are filled in."""

    argv: tuple[str, ...]
    output: str  # file under the work folder this step writes (skipped when it exists)

    def resolve(self, data: Path, work: Path) -> list[str]:
        return [a.format(data=data, work=work) for a in self.argv]


@dataclass(frozen=True)
class Recipe:
    name: str
    renders: tuple[Render, ...]
    steps: tuple[TrainStep, ...]
    shipped: tuple[str, ...]  # files under the work folder that go to semslam/data/
    note: str = ""  # what it costs, for the command's first line
    photos: str | None = None  # folder under the data folder its photo-textured renders read


def _data_flags(flag: str, names: list[str]) -> list[str]:
    return [x for n in names for x in (flag, "{data}/" + n)]


def _sdfcnn() -> Recipe:
    """SDFCNN of 2026-11-29 (evening): the office and 94 random rooms, 10 epochs from scratch."""
    small = {"fps": 3.0, "width": 320, "height": 240}
    office = [
        Render("train_room_loop_s301", {"seed": 301, "frames": 120, **small, "people": 2}, "room_loop"),
        Render("train_loop_s302", {"seed": 302, "frames": 90, **small, "people": 1}, "loop"),
        Render("train_rpy_s303", {"seed": 303, "frames": 90, **small}, "walking_rpy"),
        Render("train_halfsphere_s305", {"seed": 305, "frames": 90, **small, "mover": True}, "walking_halfsphere"),
        Render("train_xyz_s306", {"seed": 306, "frames": 90, **small, "people": 3}, "walking_xyz"),
        Render("train_box_s308", {"seed": 308, "frames": 90, **small}, "walking_box"),
    ]
    val = [Render("val_xyz_s304", {"seed": 304, "frames": 60, **small}, "walking_xyz"),
           Render("val_l50_xyz_s450", {"motion": "xyz", "layout": 50, "seed": 450, "frames": 40, **small,
                                       "people": 1})]
    rooms = []
    motions = ("room_loop", "xyz", "halfsphere", "loop", "rpy", "xyz", "room_loop", "halfsphere", "xyz", "loop",
               "rpy", "xyz")
    for i in range(2, 12):
        layout, m = i + 2, motions[i]
        rooms.append(Render(f"train_l{layout}_{m}_s{410 + i}", {"motion": m, "layout": layout, "seed": 410 + i,
                                                                "frames": 60, **small, "people": i % 3}))
    motions = ("xyz", "rpy", "halfsphere", "loop", "room_loop", "room_revisit", "fast_turns", "xyz", "room_loop")
    for layout in range(14, 100):
        if layout == 50:  # validation only
            continue
        m = motions[layout % 9]
        rooms.append(Render(f"train_l{layout}_{m}_s{500 + layout}", {"motion": m, "layout": layout,
                                                                     "seed": 500 + layout, "frames": 45, **small,
                                                                     "people": layout % 4}))
    renders = office + val + rooms
    # As trained: the office twice, then the shell glob train_l*, which also matched
    # train_loop_s302 (so that office sequence counts three times), in the glob's order.
    office_names = [r.name for r in office]
    train = office_names * 2 + sorted(r.name for r in renders if r.name.startswith("train_l"))
    step = TrainStep(("train", "sdfcnn", "--out", "{work}/sdfcnn.pt", *_data_flags("--data", train),
                      *_data_flags("--val", [r.name for r in val]), "--epochs", "10", "--batch", "8",
                      "--size", "192x144", "--width", "0.5", "--lr", "0.003", "--lambda", "0.4", "--seed", "0",
                      "--threads", "2", "--minutes", "55"), "sdfcnn.pt")
    export = TrainStep(("export-onnx", "{work}/sdfcnn.pt"), "sdfcnn.onnx")
    return Recipe("sdfcnn", tuple(renders), (step, export), ("sdfcnn.pt", "sdfcnn.onnx"),
                  note="103 renders (~4 min), then ~53 min of training on 2 CPU threads")


def _sdfcnn_photo(base: Recipe) -> Recipe:
    """SDFCNN fine-tuned on renders that look more like camera images (issue 40, item 4): the
    rooms with real photographs on 60 % of their surfaces and the hard-imaging effects on half
    of them, mixed with the base recipe's renders so the rooms' look is not forgotten, and a
    real camera's defects on half the samples (``--camera``); from ``base``'s weights."""
    small = {"fps": 3.0, "width": 320, "height": 240}
    hard = ({}, {"exposure_ms": 12.0, "gain_swing": 0.3, "white_balance_swing": 0.1},
            {"rolling_shutter_ms": 25.0, "exposure_ms": 6.0})
    motions = ("xyz", "rpy", "halfsphere", "loop", "room_loop", "room_revisit", "fast_turns", "xyz", "room_loop")
    photo = []
    for k, layout in enumerate(range(4, 100, 6)):  # 16 rooms, never the held-out 1-3 nor the validation 50
        m = motions[k % 9]
        photo.append(Render(f"photo_l{layout}_{m}_s{700 + layout}",
                            {"motion": m, "layout": layout, "seed": 700 + layout, "frames": 40, **small,
                             "people": k % 3, "photo_textures": PHOTOS, **hard[k % 3]}))
    office = [r.name for r in base.renders if r.name.startswith("train_") and not r.name.startswith("train_l")]
    rooms = sorted(r.name for r in base.renders if r.name.startswith("train_l"))[::4]
    train = [r.name for r in photo] + office + rooms
    step = TrainStep(("train", "sdfcnn", "--init", "{work}/sdfcnn_base.pt", "--out", "{work}/sdfcnn.pt",
                      *_data_flags("--data", train), "--val", "{data}/val_xyz_s304", "--val",
                      "{data}/val_l50_xyz_s450", "--epochs", "8", "--batch", "8", "--size", "192x144",
                      "--width", "0.5", "--lr", "0.001", "--lambda", "0.4", "--camera", "0.5", "--seed", "1",
                      "--threads", "1", "--minutes", "25"), "sdfcnn.pt")
    first = base.steps[0]
    base_step = TrainStep(tuple(a.replace("{work}/sdfcnn.pt", "{work}/sdfcnn_base.pt") for a in first.argv),
                          "sdfcnn_base.pt")
    export = TrainStep(("export-onnx", "{work}/sdfcnn.pt"), "sdfcnn.onnx")
    return Recipe("sdfcnn_photo", (*base.renders, *photo), (base_step, step, export), ("sdfcnn.pt", "sdfcnn.onnx"),
                  note=f"{len(base.renders) + len(photo)} renders (~8 min; first `python -m "
                       f"semslam.synth.textures DATA/{PHOTOS}`), ~53 + 25 min of training", photos=PHOTOS)


def _fpfdcnn() -> Recipe:
    """FPFDCNN of 2026-11-29: dense-Harris stage, then two cell-softmax stages."""
    train = [Render(f"train_{m}_s{s}", {"motion": m, "people": 0, "seed": s, "frames": 60, "fps": 10.0})
             for m, s in (("xyz", 301), ("rpy", 302), ("loop", 303), ("halfsphere", 306), ("xyz", 307),
                          ("loop", 309))]
    val = Render("val_halfsphere_s305", {"motion": "halfsphere", "people": 0, "seed": 305, "frames": 40,
                                         "fps": 10.0})
    common = (*_data_flags("--data", [r.name for r in train]), "--val", "{data}/" + val.name, "--width", "0.5",
              "--batch", "4", "--crop", "256x192", "--gaps", "1,2,3,4")
    stage1 = TrainStep(("train", "fpfdcnn", *common, "--out", "{work}/fpfdcnn_stage1.pt", "--minutes", "13",
                        "--lr", "0.002", "--target", "harris", "--pos-weight", "5.0", "--seed", "0",
                        "--threads", "2"), "fpfdcnn_stage1.pt")
    stage2 = TrainStep(("train", "fpfdcnn", *common, "--init", "{work}/fpfdcnn_stage1.pt", "--out",
                        "{work}/fpfdcnn_stage2.pt", "--minutes", "25", "--lr", "0.001", "--target", "cells",
                        "--seed", "1", "--threads", "1"), "fpfdcnn_stage2.pt")
    stage3 = TrainStep(("train", "fpfdcnn", *common, "--init", "{work}/fpfdcnn_stage2.pt", "--out",
                        "{work}/fpfdcnn.pt", "--minutes", "35", "--lr", "0.001", "--target", "cells",
                        "--repeat-weight", "0.25", "--repeat-patch", "8", "--seed", "2", "--threads", "2"),
                       "fpfdcnn.pt")
    export = TrainStep(("export-onnx", "{work}/fpfdcnn.pt"), "fpfdcnn.onnx")
    return Recipe("fpfdcnn", (*train, val), (stage1, stage2, stage3, export), ("fpfdcnn.pt", "fpfdcnn.onnx"),
                  note="7 renders (~1 min), then 13 + 25 + 35 min of training")


RECIPES: dict[str, Recipe] = {r.name: r for r in (_sdfcnn(), _sdfcnn_photo(_sdfcnn()), _fpfdcnn())}
