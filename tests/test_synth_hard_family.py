"""Issue 38's held-out synthetic family: the hand or card over the lens, white-balance
swings, and the seeded motions (room_path, shake, fast_rotations)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import ConfigError
from semslam.geometry.se3 import invert, rotation_angle
from semslam.synth import imaging
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.layouts import CAMERA_ZONE
from semslam.synth.render import Renderer
from semslam.synth.sequences import SynthConfig

TINY = {"width": 160, "height": 120, "people": 0, "frames": 20, "motion": "room_path"}
SEEDED = ("room_path", "shake", "fast_rotations")


def _rates(motion: str, seed: int, seconds: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """Frame-to-frame angular (deg/s) and linear (m/s) speeds at 30 fps."""
    t = np.arange(int(seconds * 30)) / 30.0
    poses = camera_trajectory(motion, t, seconds, seed)
    rel = invert(poses[:-1]) @ poses[1:]
    return np.degrees(rotation_angle(rel[:, :3, :3])) * 30, np.linalg.norm(rel[:, :3, 3], axis=1) * 30


def _skin_share(rgb: np.ndarray) -> float:
    """Share of pixels with a skin-like colour: red over green over blue, not dark."""
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return float(((r > g + 8) & (g >= b - 4) & (r > 50)).mean())


@pytest.mark.parametrize("kind", ["hand", "object"])
def test_occluder_after_blackout_has_no_depth(kind: str) -> None:
    cfg = SynthConfig(**TINY, seed=3, blackout_start_s=0.1, blackout_s=0.2, occluder_s=0.3,
                      occluder_kind=kind)
    r = Renderer(cfg)
    assert cfg.occluder_window() == pytest.approx((0.3, 0.6))
    clear = r.render(1)
    assert (clear.depth > 0).mean() > 0.6
    black = r.render(6)
    assert black.rgb.max() == 0 and black.depth.max() == 0
    for i in (10, 14, 17):  # covered: at most the half of the image the cover leaves free
        fr = r.render(i)
        assert (fr.depth > 0).mean() < 0.5, i
        assert fr.rgb.mean() > 30, i  # not black: something is there
        if kind == "hand":
            assert _skin_share(fr.rgb) > 0.5, i
    assert (r.render(19).depth > 0).mean() > 0.6  # gone again


def test_occluder_moves_and_starts_without_blackout() -> None:
    r = Renderer(SynthConfig(**TINY, seed=5, occluder_start_s=0.2, occluder_s=0.5))
    assert (r.render(3).depth > 0).mean() > 0.6
    a, b = r.render(7).rgb.astype(float), r.render(16).rgb.astype(float)
    assert (r.render(7).depth > 0).mean() < 0.5
    assert np.abs(a - b).mean() > 2.0  # the hand moved (and the camera did)


def test_white_balance_swings_per_channel() -> None:
    g = np.array([imaging.white_balance_gains(4, t, 0.2) for t in np.arange(0, 10, 0.1)])
    assert np.all(g > 0.79) and np.all(g < 1.21)
    assert np.ptp(g, axis=0).min() > 0.1  # every channel swings
    assert np.abs(g[:, 0] - g[:, 2]).max() > 0.05  # and not together (a colour cast)
    assert np.array_equal(imaging.white_balance_gains(4, 1.0, 0.0), np.ones(3, np.float32))
    plain = Renderer(SynthConfig(**TINY, seed=2, noise=False)).render(12).rgb.astype(float)
    wb = Renderer(SynthConfig(**TINY, seed=2, noise=False, white_balance_swing=0.3)).render(12).rgb
    ratio = wb.reshape(-1, 3).mean(0) / plain.reshape(-1, 3).mean(0)
    assert np.ptp(ratio) > 0.03


def test_new_fields_are_checked() -> None:
    for bad in ({"occluder_s": -1.0}, {"occluder_kind": "cat"}, {"white_balance_swing": 1.0},
                {"motion": "wobble"}):
        with pytest.raises(ConfigError):
            SynthConfig(**bad).validate()


@pytest.mark.parametrize("motion", SEEDED)
def test_seeded_motions_are_smooth_seeded_and_in_the_camera_zone(motion: str) -> None:
    t = np.arange(450) / 30.0
    lo, hi = np.array(CAMERA_ZONE[0]) + 0.2, np.array(CAMERA_ZONE[1]) - 0.2
    paths = []
    for seed in range(4):
        poses = camera_trajectory(motion, t, 15.0, seed)
        assert np.array_equal(poses, camera_trajectory(motion, t, 15.0, seed))
        eyes = poses[:, :3, 3]
        assert np.all(eyes >= lo) and np.all(eyes <= hi), seed
        ang, speed = _rates(motion, seed)
        assert ang[0] < 3.0 and speed[0] < 0.03  # starts at rest
        assert speed.max() < 0.8
        acc = np.abs(np.diff(ang)) * 30  # no jumps between frames (deg/s^2)
        assert acc.max() < 4000, seed
        paths.append(poses)
    for a in range(4):
        for b in range(a + 1, 4):
            assert np.abs(paths[a][:, :3, 3] - paths[b][:, :3, 3]).max() > 0.02


def test_room_path_looks_at_every_wall() -> None:
    for seed in range(4):
        ang, speed = _rates("room_path", seed)
        assert 15 <= np.median(ang) <= 32, seed
        t = np.arange(450) / 30.0
        poses = camera_trajectory("room_path", t, 15.0, seed)
        heading = np.unwrap(np.arctan2(poses[:, 1, 2], poses[:, 0, 2]))
        assert np.degrees(np.ptp(heading)) > 270, seed  # turned to see all four walls
        eyes = poses[:, :3, 3]
        assert np.ptp(eyes[:, 0]) > 1.0, seed  # walked


def test_shake_has_tremor_bands() -> None:
    t = np.arange(0, 10, 1 / 120)
    eye = camera_trajectory("shake", t, 10.0, 1)[:, :3, 3]
    spec = np.abs(np.fft.rfft(eye[240:] - eye[240:].mean(0), axis=0)).sum(1)
    freq = np.fft.rfftfreq(len(eye) - 240, 1 / 120)
    power = {lo: spec[(freq >= lo) & (freq <= hi)].max() for lo, hi in ((1, 3), (8, 12), (20, 40))}
    assert power[1] > 5 * power[20] and power[8] > 3 * power[20]
    ang, _ = _rates("shake", 1)
    assert np.median(ang) < 15


def test_fast_rotations_statistics() -> None:
    medians, peaks = [], []
    for seed in range(6):
        ang, _ = _rates("fast_rotations", seed)
        medians.append(np.median(ang))
        peaks.append(ang.max())
        t = np.arange(450) / 30.0
        rv = camera_trajectory("fast_rotations", t, 15.0, seed)
        rel = invert(rv[:1]) @ rv
        axes = np.abs(np.array([rel[:, 2, 1], rel[:, 0, 2], rel[:, 1, 0]]))
        assert np.all(np.degrees(axes.max(1)) > 5), seed  # all three axes turn
    assert 30 <= np.median(medians) <= 50
    assert 170 <= max(peaks) <= 240 and min(peaks) > 140
