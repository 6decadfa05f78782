"""Room layouts of the synthetic sequences (``SynthConfig.layout``, ``semslam synth --layout``).

Layout 1 (the lounge) is the room no shipped network was trained in. Its renders are
checked against an independent ray cast of ``scene.json`` (slab test written here, not the
renderer's): depth and class at a spread of pixels must be those of the first box face the
pixel's ray meets. Every layout keeps the free zone of the camera, people and movers empty.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.core.labels import NYU40_CLASSES, SYNTH_STATIC_OFFSET, synth_static_id
from semslam.errors import ConfigError
from semslam.geometry.se3 import pose_from_tum
from semslam.synth import SEQUENCES, SynthConfig, render_sequence, writer
from semslam.synth.box_carry import carried_box
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.layouts import CAMERA_ZONE, FLOOR_ZONE, FREE_ZONES, MAX_LAYOUT, get_layout
from semslam.synth.people import make_tracks
from semslam.synth.scene import Box, mover_box, static_boxes
from semslam.synth.sequences import PEOPLE_MODES
from semslam.synth.static_geometry import scene_json

CFG = SynthConfig(motion="room_loop", frames=6, fps=1.0, people=0, noise=False, seed=0,
                  width=160, height=120, layout=1)


@pytest.fixture(scope="module")
def lounge(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return render_sequence(CFG, tmp_path_factory.mktemp("lounge") / "seq", workers=1)


def _aabb(box: Box) -> tuple[np.ndarray, np.ndarray]:
    c = box.corners()
    return c.min(0), c.max(0)


def _overlaps(lo: np.ndarray, hi: np.ndarray, zone: tuple) -> bool:
    zlo, zhi = np.array(zone[0]), np.array(zone[1])
    return bool(np.all(lo < zhi) and np.all(hi > zlo))


def test_layout_0_is_the_office() -> None:
    """Layout 0 is today's room, box for box (renders are byte-identical to before layouts)."""
    assert SynthConfig().layout == 0
    assert all(cfg.layout == 0 for cfg in SEQUENCES.values())
    office = json.dumps(scene_json(get_layout(0).boxes()), indent=2, sort_keys=True) + "\n"
    # the bytes of scene.json that renders wrote before layouts existed
    assert hashlib.sha256(office.encode()).hexdigest()[:16] == "2619f6825069c36c"
    assert writer.labels_for(static_boxes()) == writer.LABELS


@pytest.mark.parametrize("number", [0, 1, *range(2, 40, 3), MAX_LAYOUT])
def test_free_zone_and_room(number: int) -> None:
    """Furniture stays inside the room and out of the zone the camera, people and movers use."""
    boxes = get_layout(number).boxes()
    room = boxes[0]
    assert room.inside and room.name == "room" and not any(b.inside for b in boxes[1:])
    rlo, rhi = _aabb(room)
    for zone in FREE_ZONES:
        assert np.all(rlo <= np.array(zone[0])) and np.all(rhi >= np.array(zone[1]))
    for b in boxes[1:]:
        lo, hi = _aabb(b)
        assert np.all(lo >= rlo - 1e-9) and np.all(hi <= rhi + 1e-9), b.name
        assert not any(_overlaps(lo, hi, zone) for zone in FREE_ZONES), b.name
        assert len(b.classes) == 6, b.name


def test_cameras_and_movers_in_the_free_zones() -> None:
    """Every preset's camera eye stays 0.2 m inside the camera zone; the mover, the carried
    box and the people's paths stay on the free floor."""
    lo, hi = np.array(CAMERA_ZONE[0]), np.array(CAMERA_ZONE[1])
    for cfg in SEQUENCES.values():
        t = np.arange(0, cfg.duration, 0.1)
        eyes = camera_trajectory(cfg.motion, t, cfg.duration)[:, :3, 3]
        assert np.all(eyes >= lo + 0.2) and np.all(eyes <= hi - 0.2), cfg.motion
    lo, hi = np.array(FLOOR_ZONE[0]), np.array(FLOOR_ZONE[1])
    for t in np.arange(0.0, 10.0, 0.1):
        for box in (mover_box(t), carried_box(t)):
            blo, bhi = _aabb(box)
            assert np.all(blo >= lo - 0.021) and np.all(bhi <= hi), (box.name, t)
    for mode in PEOPLE_MODES:
        for track in make_tracks(8, mode, seed=3):
            feet = np.array([track.state(t)[0] for t in np.arange(0.0, 30.0, 0.5)])
            # people are billboards drawn in depth order: their feet, not their width, matter
            assert np.all(feet >= lo[:2]) and np.all(feet <= hi[:2] + 0.1), mode


def test_lounge_differs_from_the_office() -> None:
    """Another room size and another class set, so nothing of it is seen in training."""
    office, lounge = get_layout(0).boxes(), get_layout(1).boxes()
    assert not np.allclose(office[0].size, lounge[0].size)
    names = lambda bs: {NYU40_CLASSES[c - SYNTH_STATIC_OFFSET] for b in bs for c in b.classes}  # noqa: E731
    new = names(lounge) - names(office)
    assert {"sofa", "table", "whiteboard", "window", "curtain", "lamp", "pillow", "shelves"} <= new


def test_random_layouts_are_fixed_and_differ() -> None:
    """Layout n is the same room each time; rooms of other numbers differ in size and furniture."""
    a, b = get_layout(5).boxes(), get_layout(5).boxes()
    assert json.dumps(scene_json(a)) == json.dumps(scene_json(b))
    sizes = {tuple(np.round(get_layout(n).boxes()[0].size, 3)) for n in range(2, 12)}
    assert len(sizes) == 10
    counts = [len(get_layout(n).boxes()) for n in range(2, 12)]
    assert min(counts) >= 8 and len(set(counts)) > 3


def test_unknown_layout_refused() -> None:
    with pytest.raises(ConfigError, match="unknown layout"):
        SynthConfig(layout=MAX_LAYOUT + 1).validate()
    with pytest.raises(ConfigError, match="unknown layout"):
        SynthConfig(layout=-1).validate()


def _ray_box(origin: np.ndarray, d: np.ndarray, box: dict) -> tuple[float, int]:
    """Slab test: (distance along d, face index) of the first hit, or (inf, -1)."""
    rot = np.array(box["rotation"])
    o = rot.T @ (origin - np.array(box["center"]))
    v = rot.T @ d
    half = np.array(box["size"]) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / v, (half - o) / v
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    if box["inside"]:  # seen from within: the exit face
        t = float(far.min())
        axis = int(far.argmin())
        return t, 2 * axis + (0 if v[axis] > 0 else 1)
    tn, tf = float(near.max()), float(far.min())
    if tn > tf or tf <= 0 or tn <= 0:
        return np.inf, -1
    axis = int(near.argmax())
    return tn, 2 * axis + (0 if v[axis] < 0 else 1)


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img


def test_render_matches_scene_json(lounge: Path) -> None:
    """Depth and class at a grid of pixels = the first face of scene.json the ray meets."""
    scene = json.loads((lounge / "scene.json").read_text())
    fx, fy, cx, cy = CFG.intrinsics()
    rows = [ln.split() for ln in (lounge / "groundtruth.txt").read_text().splitlines() if ln[0] != "#"]
    poses = pose_from_tum(np.array([r[1:] for r in rows], float))
    rgb = [ln.split()[1] for ln in (lounge / "rgb.txt").read_text().splitlines() if ln[0] != "#"]
    dep = [ln.split()[1] for ln in (lounge / "depth.txt").read_text().splitlines() if ln[0] != "#"]
    checked = agree = 0
    seen: set[int] = set()
    for i in range(CFG.frames):
        depth = _read(lounge / dep[i]).astype(np.float64) / 5000.0
        sem = _read(lounge / "semantic" / Path(rgb[i]).name)
        pose = poses[i]
        for v in range(6, CFG.height, 12):
            for u in range(5, CFG.width, 10):
                d = pose[:3, :3] @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
                hits = [(*_ray_box(pose[:3, 3], d, b), b) for b in scene["boxes"]]
                t, face, box = min(hits, key=lambda h: h[0])
                z = t  # d has unit z in the camera frame, so t is the z-depth
                if not 0.4 <= z <= 4.5:
                    continue
                # leave out pixels next to an edge (a 1-px step changes the surface)
                if np.ptp(depth[max(v - 1, 0): v + 2, max(u - 1, 0): u + 2]) > 0.05 * z:
                    continue
                checked += 1
                seen.add(int(sem[v, u]))
                ok = abs(depth[v, u] - z) < 1e-3 and int(sem[v, u]) == box["face_classes"][face]
                agree += ok
    assert checked > 300
    assert agree / checked > 0.99, (agree, checked)
    assert {synth_static_id(n) for n in ("wall", "floor", "sofa")} <= seen


def test_labels_consistent_with_scene_json(lounge: Path) -> None:
    labels = json.loads((lounge / "semantic" / "labels.json").read_text())
    scene = json.loads((lounge / "scene.json").read_text())
    static = {k: v for k, v in labels.items() if int(k) >= SYNTH_STATIC_OFFSET}
    assert static == scene["labels"]
    assert labels == writer.labels_for(get_layout(1).boxes()) != writer.LABELS
    meta = json.loads((lounge / "sequence.json").read_text())
    assert meta["config"]["layout"] == 1 and meta["labels"] == labels
    present: set[int] = set()
    for f in (lounge / "semantic").glob("*.png"):
        present |= set(np.unique(_read(f)).tolist())
    assert present <= {int(k) for k in labels} and 0 not in present
    assert np.allclose(scene["room"]["min"], [-0.7, -0.4, 0.0])


def test_cli_layout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.cli.main import main

    out = tmp_path / "cli"
    args = ["synth", str(out), "-s", "static_xyz", "-n", "2", "--width", "80", "--height", "60", "-q"]
    assert main(args + ["--layout", "1"]) == 0
    assert "layout 1" in capsys.readouterr().out
    assert json.loads((out / "sequence.json").read_text())["config"]["layout"] == 1
    assert main(args + ["--layout", str(MAX_LAYOUT + 1)]) == 2
