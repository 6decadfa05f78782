"""Synthetic sequences: layout, determinism, exact geometry, texture, people, motions."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from semslam.errors import ConfigError
from semslam.geometry.se3 import invert, pose_from_tum, rotation_angle
from semslam.synth import SEQUENCES, Renderer, SynthConfig, render_sequence
from semslam.synth.camera_motion import MAX_ANGULAR_SPEED, MAX_SPEED, camera_trajectory
from semslam.synth.depth_noise import kinect_depth
from semslam.synth.sequences import get_sequence

SMALL = {"width": 320, "height": 240}


def _read_list(path: Path) -> list[tuple[float, str]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, name = line.split()
        rows.append((float(t), name))
    return rows


def _read_gt(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    data = np.array([[float(v) for v in ln.split()] for ln in lines])
    return data[:, 0], pose_from_tum(data[:, 1:8])


@pytest.fixture(scope="module")
def small_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = SynthConfig(motion="xyz", frames=6, people=2, seed=3, **SMALL)
    return render_sequence(cfg, tmp_path_factory.mktemp("synth") / "seq")


def test_layout(small_seq: Path) -> None:
    for name in (
        "rgb.txt",
        "depth.txt",
        "groundtruth.txt",
        "calib.txt",
        "sequence.json",
        "semantic/labels.json",
    ):
        assert (small_seq / name).is_file(), name
    rgb, depth = _read_list(small_seq / "rgb.txt"), _read_list(small_seq / "depth.txt")
    assert len(rgb) == len(depth) == 6
    for sub in ("rgb", "depth", "semantic"):
        assert len(list((small_seq / sub).glob("*.png"))) == 6
    for (tr, nr), (td, nd) in zip(rgb, depth):
        assert 0.004 < td - tr < 0.016  # Kinect-like offset, still associable within 0.02 s
        assert nr == f"rgb/{tr:.6f}.png" and nd == f"depth/{td:.6f}.png"
        assert (small_seq / "semantic" / Path(nr).name).is_file()
    assert np.allclose(np.diff([t for t, _ in rgb]), 1 / 30, atol=2e-6)
    times, poses = _read_gt(small_seq / "groundtruth.txt")
    assert np.allclose(times, [t for t, _ in rgb])
    assert poses.shape == (6, 4, 4)
    d = cv2.imread(str(small_seq / depth[0][1]), cv2.IMREAD_UNCHANGED)
    assert d.dtype == np.uint16 and d.shape == (240, 320)
    assert 0.5 < (d > 0).mean() <= 1.0
    c = cv2.imread(str(small_seq / rgb[0][1]), cv2.IMREAD_UNCHANGED)
    assert c.dtype == np.uint8 and c.shape == (240, 320, 3)
    s = cv2.imread(str(small_seq / "semantic" / Path(rgb[0][1]).name), cv2.IMREAD_UNCHANGED)
    labels = {
        int(k): v for k, v in json.loads((small_seq / "semantic/labels.json").read_text()).items()
    }
    assert s.dtype == np.uint8 and s.shape == (240, 320) and set(np.unique(s)) <= set(labels)
    calib = [float(v) for v in (small_seq / "calib.txt").read_text().split()]
    assert calib == pytest.approx([535.4 / 2, 539.2 / 2, 320.1 / 2, 247.6 / 2])
    meta = json.loads((small_seq / "sequence.json").read_text())
    assert meta["config"]["seed"] == 3 and meta["config"]["frames"] == 6
    # dynamic ids as ever; the static scene's NYU-40 classes at 100 + NYU id
    assert {k: v for k, v in labels.items() if k < 100} == {
        0: "background",
        15: "person",
        21: "moving_object",
    }
    assert labels[101] == "wall" and labels[102] == "floor" and labels[122] == "ceiling"


def test_project_loader_reads_it(small_seq: Path) -> None:
    from semslam.io.sequence import open_sequence

    seq = open_sequence(small_seq)
    assert len(seq) == 6
    frame = seq.load(0)
    assert frame.rgb.shape == (240, 320, 3)
    assert seq.camera.fx == pytest.approx(535.4 / 2)


def test_deterministic(tmp_path: Path, small_seq: Path) -> None:
    cfg = SynthConfig(motion="xyz", frames=6, people=2, seed=3, **SMALL)
    again = render_sequence(cfg, tmp_path / "again", workers=1)  # other thread count too
    for sub in ("rgb", "depth", "semantic"):
        for f in sorted((small_seq / sub).glob("*.png")):
            assert (again / sub / f.name).read_bytes() == f.read_bytes(), f

    def body(p: Path) -> list[str]:
        return [ln for ln in p.read_text().splitlines() if not ln.startswith("#")]

    assert body(again / "groundtruth.txt") == body(small_seq / "groundtruth.txt")
    other = Renderer(cfg.replace(seed=4)).render(0)
    first = cv2.imread(str(min((small_seq / "rgb").glob("*.png"))))[..., ::-1]
    assert np.mean(np.abs(other.rgb.astype(int) - first.astype(int))) > 5


def test_geometry_is_exact() -> None:
    """Back-project frame i with gt pose, depth and intrinsics; it must land on frame j."""
    cfg = SynthConfig(motion="halfsphere", frames=90, people=0, noise=False, seed=0, **SMALL)
    r = Renderer(cfg)
    fx, fy, cx, cy = cfg.intrinsics()
    i, j = 30, 60  # the camera moves ~15 cm and turns in between
    fi, fj = r.render(i), r.render(j)
    zi = fi.depth.astype(np.float64) / 5000.0
    v, u = np.nonzero(zi > 0)
    z = zi[v, u]
    pc = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z, np.ones_like(z)])
    rel = invert(r.poses[j]) @ r.poses[i]
    q = rel @ pc
    uj, vj = fx * q[0] / q[2] + cx, fy * q[1] / q[2] + cy
    ui, vi = np.round(uj).astype(int), np.round(vj).astype(int)
    inside = (ui >= 1) & (ui < cfg.width - 1) & (vi >= 1) & (vi < cfg.height - 1)
    assert inside.mean() > 0.6
    # compare with exact depth of frame j at the (sub-pixel) reprojection: bilinear on z
    at = np.stack([vj[inside], uj[inside]])
    zj_at = map_coordinates(fj.z.astype(np.float64), at, order=1)
    err = np.abs(q[2][inside] - zj_at)
    smooth = err < 0.05  # leave out occlusion boundaries
    assert smooth.mean() > 0.9
    assert np.median(err[smooth]) < 0.001
    assert np.percentile(err[smooth], 90) < 0.003
    # photometric: the static colour of a point is the same in both frames
    ci = fi.rgb[v[inside], u[inside]].astype(np.float32)
    cj = np.stack(
        [map_coordinates(fj.rgb[..., k].astype(np.float64), at, order=1) for k in range(3)], 1
    )
    diff = np.abs(ci - cj).mean(axis=1)[smooth]
    assert np.median(diff) < 8.0


def test_orb_features_everywhere() -> None:
    for motion in ("xyz", "rpy"):
        r = Renderer(SynthConfig(motion=motion, frames=240, people=0, seed=0))
        for i in (0, 120, 239):
            img = cv2.cvtColor(r.render(i).rgb, cv2.COLOR_RGB2GRAY)
            kps = cv2.ORB_create(1000).detect(img)
            assert len(kps) >= 300
            cells = {(min(3, int(k.pt[1] / 120)), min(3, int(k.pt[0] / 160))) for k in kps}
            assert len(cells) >= 10, (motion, i, len(cells))


def test_people_visible_and_in_front() -> None:
    cfg = SynthConfig(motion="static", frames=150, people=2, noise=False, seed=1, **SMALL)
    r = Renderer(cfg)
    empty = Renderer(cfg.replace(people=0))
    fractions = []
    for i in range(0, 150, 10):
        fr = r.render(i)
        person = fr.semantic == 15
        fractions.append(person.mean())
        if person.mean() > 0.02:
            bg = empty.render(i).z
            assert np.mean(fr.z[person] < bg[person]) > 0.97
            d = fr.depth[person]
            assert np.mean(d > 0) > 0.9  # people have depth
    assert max(fractions) > 0.05
    assert max(fractions) < 0.7


def test_mover_labelled() -> None:
    r = Renderer(SynthConfig(motion="static", frames=60, people=0, mover=True, seed=0, **SMALL))
    assert max((r.render(i).semantic == 21).mean() for i in (0, 30, 59)) > 0.05


@pytest.mark.parametrize("motion", ["static", "xyz", "rpy", "halfsphere", "loop", "room_revisit"])
def test_motion_speed_bounded(motion: str) -> None:
    t = np.arange(600) / 30.0
    poses = camera_trajectory(motion, t, 20.0)
    rel = invert(poses[:-1]) @ poses[1:]
    speed = np.linalg.norm(rel[:, :3, 3], axis=1) * 30.0
    ang = rotation_angle(rel[:, :3, :3]) * 30.0
    assert speed.max() <= MAX_SPEED and ang.max() <= MAX_ANGULAR_SPEED
    # smooth start from rest
    assert speed[0] < 0.02 and ang[0] < np.deg2rad(2.0)
    moved = np.linalg.norm(poses[:, :3, 3] - poses[0, :3, 3], axis=1).max()
    turned = np.rad2deg(
        rotation_angle(np.swapaxes(poses[:, :3, :3], 1, 2) @ poses[0, :3, :3])
    ).max()
    if motion in ("xyz", "halfsphere", "loop"):
        assert moved > 0.2
    if motion in ("rpy", "halfsphere"):
        assert turned > 15.0


def test_static_and_loop_endpoints() -> None:
    t = np.arange(300) / 30.0
    st = camera_trajectory("static", t, 10.0)
    assert np.linalg.norm(st[:, :3, 3] - st[0, :3, 3], axis=1).max() < 0.001
    assert np.rad2deg(rotation_angle(np.swapaxes(st[:, :3, :3], 1, 2) @ st[0, :3, :3])).max() < 0.1
    for frames in (90, 600):
        t = np.arange(frames) / 30.0
        lp = camera_trajectory("loop", t, frames / 30.0)
        # last frame is one period before the end of the loop: within 2 cm and 1 degree
        assert np.linalg.norm(lp[-1, :3, 3] - lp[0, :3, 3]) < 0.02
        assert np.rad2deg(rotation_angle(lp[-1, :3, :3].T @ lp[0, :3, :3])) < 1.0
        if frames == 600:
            assert np.ptp(lp[:, 0, 3]) > 1.5  # a real loop through the room


def test_room_revisit_repeats_its_turn() -> None:
    """The long-run benchmark's motion: one full turn every 30 s at a steady 12 deg/s, so
    the same views come back exactly; a short render's poses are the start of a long one's."""
    from semslam.synth.camera_motion import ROOM_REVISIT_PERIOD_S

    t = np.arange(0.0, 100.0, 1 / 30.0)
    long = camera_trajectory("room_revisit", t, 1200.0)
    assert np.array_equal(camera_trajectory("room_revisit", t[:300], 10.0), long[:300])
    k = int(round(ROOM_REVISIT_PERIOD_S * 30))  # frames per turn
    late = slice(90, len(t) - k)  # after the smooth start
    assert np.abs(long[late] - long[late.start + k:]).max() < 1e-9  # the same poses a turn later
    rel = invert(long[:-1]) @ long[1:]
    rate = np.rad2deg(rotation_angle(rel[:, :3, :3])) * 30.0
    assert np.allclose(rate[90:], 360.0 / ROOM_REVISIT_PERIOD_S, atol=0.01)
    half = long[90 + k // 2]  # half a turn later it looks the other way
    assert half[:2, 2] @ long[90][:2, 2] < -0.97  # horizontal headings opposite (both tilted down)


def test_depth_noise_model() -> None:
    z = np.full((120, 160), 2.0, np.float32)
    z[:, 80:] = 3.5
    cos = np.ones_like(z)
    exact = kinect_depth(z, cos, None)
    assert np.all(exact[:, :80] == 10000) and np.all(exact[:, 80:] == 17500)
    noisy = kinect_depth(z, cos, np.random.default_rng(0)).astype(np.float64) / 5000
    near, far = noisy[:, 5:70], noisy[:, 90:155]
    assert 0.8 < (near > 0).mean() and 0.8 < (far > 0).mean()
    assert np.std(near[near > 0]) < np.std(far[far > 0])  # noise grows with distance
    assert abs(np.median(far[far > 0]) - 3.5) < 0.02
    assert np.all(noisy[:, 79:81] == 0)  # hole at the depth edge
    out = kinect_depth(np.array([[0.3, 5.0]], np.float32), np.ones((1, 2), np.float32), None)
    assert np.all(out == 0)


def test_presets_and_validation() -> None:
    assert {
        "demo",
        "walking_xyz",
        "walking_static",
        "walking_rpy",
        "walking_halfsphere",
        "sitting_static",
        "static_xyz",
        "loop",
        "mover_xyz",
    } <= set(SEQUENCES)
    for cfg in SEQUENCES.values():
        cfg.validate()
    assert get_sequence("static_xyz").people == 0
    with pytest.raises(ConfigError):
        get_sequence("nope")
    with pytest.raises(ConfigError):
        SynthConfig(motion="spin").validate()
    with pytest.raises(ConfigError):
        SynthConfig(frames=0).validate()


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from semslam.cli.main import main

    out = tmp_path / "cli"
    code = main(
        [
            "synth",
            str(out),
            "--sequence",
            "static_xyz",
            "--frames",
            "3",
            "--width",
            "160",
            "--height",
            "120",
            "--quiet",
            "--seed",
            "5",
        ]
    )
    assert code == 0
    assert "3 frames" in capsys.readouterr().out
    assert len(list((out / "rgb").glob("*.png"))) == 3
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["config"]["seed"] == 5 and meta["config"]["people"] == 0
    assert main(["synth", str(out), "--motion", "spin"]) == 2


def test_resumed_render_equals_a_whole_one(tmp_path: Path) -> None:
    """An interrupted render resumed (and a shorter one extended) gives the bytes of one done
    in one go: a long benchmark render is not lost to one interruption."""
    cfg = SEQUENCES["walking_xyz"].replace(frames=6, **SMALL)
    whole = render_sequence(cfg, tmp_path / "whole")
    part = render_sequence(cfg.replace(frames=4), tmp_path / "part")
    rgb = sorted((part / "rgb").glob("*.png"))
    rgb[-1].unlink()  # frame 3 interrupted after its depth, before its colour and labels
    (part / "semantic" / rgb[-1].name).unlink()
    (part / "depth" / sorted((part / "depth").glob("*.png"))[2].name).write_bytes(b"\x89PNG cut")  # frame 2 cut short
    (part / "sequence.json").unlink()  # as an interrupted render leaves it: only its in-progress note
    (part / ".rendering.json").write_text(json.dumps({"config": cfg.to_dict()}))
    kept = rgb[0].stat().st_mtime_ns
    render_sequence(cfg, part, resume=True)
    assert rgb[0].stat().st_mtime_ns == kept  # frame 0 was kept, not rendered again
    assert not (part / ".rendering.json").exists()
    for sub in ("rgb", "depth", "semantic"):
        names = sorted(p.name for p in (whole / sub).glob("*.png"))
        assert names == sorted(p.name for p in (part / sub).glob("*.png"))
        for name in names:
            assert (whole / sub / name).read_bytes() == (part / sub / name).read_bytes(), f"{sub}/{name}"
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "sequence.json"):  # the lists name their folder
        assert (whole / name).read_text().replace("'whole'", "") == (part / name).read_text().replace("'part'", "")
    other = render_sequence(cfg.replace(seed=cfg.seed + 1), part, resume=True)  # another config: all new
    assert (other / "rgb" / names[0]).read_bytes() != (whole / "rgb" / names[0]).read_bytes()
