"""Scene classes, background renders and ground-truth files of the synthetic sequences.

One short, small render with everything that moves (a walking person, the rolling mover,
the carried box) and background frames. The classes are checked against the geometry:
every static pixel, back-projected with its (exact) background depth and the pose of
``groundtruth.txt``, must lie on a surface of the class it is labelled with, as
``scene.json`` describes the scene.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.core.labels import NYU40_CLASSES, SYNTH_STATIC_OFFSET, synth_static_id
from semslam.geometry.se3 import pose_from_tum
from semslam.nets.datasets import ClassSet
from semslam.synth import Renderer, SynthConfig, needs_render, render_sequence
from semslam.synth import writer
from semslam.synth.box_carry import carried_box
from semslam.synth.scene import mover_box, static_boxes
from semslam.synth.static_geometry import load_movers, load_static_geometry

PERSON, MOVER = 15, 21
CFG = SynthConfig(
    motion="xyz",
    frames=4,
    fps=2.0,
    people=1,
    mover=True,
    box_carrier=True,
    seed=0,
    width=160,
    height=120,
    background=True,
)


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return render_sequence(CFG, tmp_path_factory.mktemp("classes") / "seq", workers=1)


def _listing(path: Path) -> list[str]:
    return [ln.split()[1] for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]


def _poses(seq: Path) -> np.ndarray:
    rows = [
        ln.split()[1:] for ln in (seq / "groundtruth.txt").read_text().splitlines() if ln[0] != "#"
    ]
    return pose_from_tum(np.array(rows, float))


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img


def test_labels_json_names_every_id(seq: Path) -> None:
    names = {int(k): v for k, v in json.loads((seq / "semantic/labels.json").read_text()).items()}
    assert names == {int(k): v for k, v in writer.LABELS.items()}
    assert {0: "background", PERSON: "person", MOVER: "moving_object"}.items() <= names.items()
    for k, v in names.items():
        if k >= SYNTH_STATIC_OFFSET:
            assert NYU40_CLASSES[k - SYNTH_STATIC_OFFSET] == v
    present: set[int] = set()
    for name in _listing(seq / "rgb.txt"):
        present |= set(np.unique(_read(seq / "semantic" / Path(name).name)).tolist())
    assert present <= set(names), present - set(names)
    assert {PERSON, MOVER, synth_static_id("wall"), synth_static_id("floor")} <= present
    assert 0 not in present  # every ray meets the room
    meta = json.loads((seq / "sequence.json").read_text())
    assert meta["labels"] == writer.LABELS and meta["config"]["background"] is True


def test_room_and_furniture_classes() -> None:
    by_name = {b.name: b for b in static_boxes()}
    wall, floor, ceiling = (synth_static_id(n) for n in ("wall", "floor", "ceiling"))
    assert by_name["room"].classes == (wall, wall, wall, wall, ceiling, floor)
    expect = {
        "desk0_top": "desk",
        "chair_seat": "chair",
        "monitor": "television",
        "door": "door",
        "shelf": "bookshelf",
        "filing0": "cabinet",
        "parcel": "box",
        "books_stack": "books",
    }
    for name, cls in expect.items():
        assert by_name[name].classes == (synth_static_id(cls),) * 6, name
    assert all(len(b.classes) == 6 for b in static_boxes())
    assert not mover_box(0.0).classes and not carried_box(0.0).classes  # movers keep 21


def test_static_pixels_lie_on_a_surface_of_their_class(seq: Path) -> None:
    geo = load_static_geometry(seq)
    fx, fy, cx, cy = (float(v) for v in (seq / "calib.txt").read_text().split())
    poses = _poses(seq)
    rgb_names, depth_names = _listing(seq / "rgb.txt"), _listing(seq / "depth.txt")
    n_checked = 0
    for i, (rgb_name, depth_name) in enumerate(zip(rgb_names, depth_names)):
        sem = _read(seq / "semantic" / Path(rgb_name).name)
        z = _read(seq / "background" / depth_name).astype(np.float64) / 5000.0  # exact depth
        v, u = np.nonzero((sem >= SYNTH_STATIC_OFFSET) & (z > 0))
        zz = z[v, u]
        pc = np.stack([(u - cx) / fx * zz, (v - cy) / fy * zz, zz], axis=1)
        pw = pc @ poses[i][:3, :3].T + poses[i][:3, 3]
        label = sem[v, u].astype(np.int64)
        _, nearest = geo.distance(pw)
        assert (nearest == label).mean() > 0.999  # only pixels on edges may differ
        for k in np.unique(label):
            d, _ = geo.distance(pw[label == k], classes=[int(k)])
            assert d.max() < 0.001, (i, int(k), d.max())  # measured 0.11 mm (PNG steps)
        n_checked += len(pw)
    assert n_checked > 0.5 * 4 * 160 * 120


def test_background_frames(seq: Path) -> None:
    r = Renderer(CFG)
    rgb_names, depth_names = _listing(seq / "rgb.txt"), _listing(seq / "depth.txt")
    moving_px = 0
    for i in range(CFG.frames):
        fr, bg = r.render_with_background(i)
        assert bg is not None
        assert not np.isin(bg.semantic, [PERSON, MOVER]).any()
        moving = np.isin(fr.semantic, [PERSON, MOVER])
        moving_px += int(moving.sum())
        static = fr.semantic >= SYNTH_STATIC_OFFSET
        assert np.array_equal(bg.semantic[static], fr.semantic[static])
        assert np.array_equal(bg.z[static], fr.z[static]) and (bg.z[moving] > fr.z[moving]).all()
        # the same RGB wherever no mover is near (blur and sprite fringes reach 3 px)
        near = cv2.dilate(moving.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        assert np.array_equal(bg.rgb[~near], fr.rgb[~near]) and (~near).mean() > 0.3
        # what is written: this RGB and exact depth (noise only in depth/)
        assert np.array_equal(_read(seq / "background" / rgb_names[i])[..., ::-1], bg.rgb)
        bg_depth = _read(seq / "background" / depth_names[i])
        assert np.array_equal(bg_depth, bg.depth)
        exact = np.where(np.isfinite(bg.z) & (bg.z >= 0.4) & (bg.z <= 4.5), bg.z, 0.0)
        assert np.abs(bg_depth / 5000.0 - exact).max() < 1e-4 + 1e-6
        noisy = _read(seq / depth_names[i]).astype(np.float64) / 5000.0
        both = (noisy > 0) & (bg_depth > 0) & ~near
        assert np.median(np.abs(noisy[both] / exact[both] - 1.0)) < 0.01  # Kinect noise
    assert moving_px > 0.1 * CFG.frames * 160 * 120  # the movers really are in view


def test_in_any_mover(seq: Path) -> None:
    movers = load_movers(seq)
    assert len(movers.stamps) == CFG.frames and set(movers.label.tolist()) == {PERSON, MOVER}
    r = Renderer(CFG)
    inside = []
    for i, t in enumerate(r.times):
        inside += [carried_box(float(t)).center, mover_box(float(t)).center]
        for bb in r.people.billboards(float(t), r.poses[i][:3, 3]):
            inside += [bb.foot + np.array([0.0, 0.0, 0.5 * bb.height])]
    assert movers.in_any_mover(np.array(inside)).all()
    geo = load_static_geometry(seq)
    pts, cls = geo.sample_surface(0.05)
    walls = pts[np.isin(cls, [synth_static_id("wall"), synth_static_id("ceiling")])]
    assert len(walls) > 10000 and not movers.in_any_mover(walls).any()
    furniture = pts[cls == synth_static_id("desk")]
    assert movers.in_any_mover(furniture).mean() < 0.01


def test_render_cache_and_cli(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from semslam.cli.main import main

    assert not needs_render(seq, CFG)
    assert needs_render(seq, CFG.replace(background=False))
    out = tmp_path / "cli"
    args = ["synth", str(out), "--sequence", "walking_box", "--seed", "0", "--frames", "2"]
    args += ["--width", "64", "--height", "48", "--quiet"]
    assert main(args + ["--background"]) == 0
    assert "background" in capsys.readouterr().out
    assert len(list((out / "background" / "rgb").glob("*.png"))) == 2
    assert len(list((out / "background" / "depth").glob("*.png"))) == 2
    assert (out / "scene.json").is_file() and (out / "movers.json").is_file()
    assert main(args) == 0  # without: no background frames left behind
    assert not list((out / "background").rglob("*.png"))
    (out / "scene.json").unlink()  # a render from before scene.json (and NYU-40 labels)
    assert needs_render(
        out, SynthConfig(**json.loads((out / "sequence.json").read_text())["config"])
    )


def test_person_nets_see_the_static_scene_as_background() -> None:
    """The static scene was id 0; at 100 + NYU id it must stay background for a person
    net whatever ``--other`` says, unless a class set names it."""
    wall = synth_static_id("wall")
    for other in ("background", "ignore"):
        lut = ClassSet.parse("person", other=other).lut()
        assert lut[wall] == 0 and lut[synth_static_id("otherprop")] == 0 and lut[PERSON] == 1
    assert ClassSet.parse("person", other="ignore").lut()[MOVER] == 255
    assert ClassSet.parse(f"0:background,15:person,{wall}:wall").lut()[wall] == 2
