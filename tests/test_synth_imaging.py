"""Hard imaging in the synthetic sequences (issue 13): the fast-turn motion's rates, rolling
shutter rows against global-shutter renders at each row's capture time, motion blur against
the turn rate, the exposure gain, the depth-colour offset, and the config's checks."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import ConfigError
from semslam.geometry.se3 import invert, rotation_angle
from semslam.synth import imaging
from semslam.synth.camera_motion import FAST_TURN_PERIOD_S, FAST_TURN_S, camera_trajectory
from semslam.synth.render import Renderer
from semslam.synth.sequences import SynthConfig

SMALL = {"width": 320, "height": 240, "people": 0, "noise": False, "motion": "fast_turns", "frames": 200}
#: Mid-way through the first glance: the camera turns at its fastest (~200 deg/s).
T_FAST = 0.25 * FAST_TURN_PERIOD_S + FAST_TURN_S / 2
I_FAST = round(T_FAST * 30)


def _global_rgb(r: Renderer, t: float) -> np.ndarray:
    """A global-shutter, zero-exposure image at any time (same optics, no noise)."""
    pose = camera_trajectory(r.cfg.motion, np.array([t]), r.cfg.duration)[0]
    return r._sensor_rgb(r._scene(t, pose, False)[1], 0)[0].astype(np.float32)


def test_fast_turns_peak_near_200_deg_per_s() -> None:
    t = np.arange(0, 8.0, 1e-3)
    poses = camera_trajectory("fast_turns", t, 8.0)
    rel = invert(poses[:-1]) @ poses[1:]
    rate = np.degrees(rotation_angle(rel[:, :3, :3])) / 1e-3
    assert 180 < rate.max() < 215
    assert rate[:100].max() < 5  # starts at rest


def test_row_weights_sum_to_one_and_follow_the_readout() -> None:
    offsets = imaging.sub_frame_offsets(0.0, 0.03)
    w = imaging.row_weights(offsets, 240, 0.0, 0.03)
    np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-6)
    assert w[0, 0] == 1.0 and w[-1, -1] == 1.0  # top row first sub-frame, bottom row last
    blur = imaging.row_weights(imaging.sub_frame_offsets(0.016, 0.0), 10, 0.016, 0.0)
    assert np.allclose(blur, blur[:, :1])  # no readout: every row the same mix
    assert (blur > 0).sum(0).min() >= 8  # 16 ms over 2 ms sub-frames


def test_rolling_shutter_rows_are_captured_at_their_own_time() -> None:
    r = Renderer(SynthConfig(rolling_shutter_ms=30.0, **SMALL))
    rs = r.render(I_FAST).rgb.astype(np.float32)
    t = float(r.times[I_FAST])
    def row_time(row: int) -> float:  # the module's rule, written out: readout top to bottom
        return t + (row / 239 - 0.5) * 0.030

    bands = {"top": (slice(4, 12), row_time(8)), "bottom": (slice(228, 236), row_time(232))}
    centre = _global_rgb(r, t)
    for name, (rows, t_row) in bands.items():
        own = np.abs(rs[rows] - _global_rgb(r, t_row)[rows]).mean()
        mid = np.abs(rs[rows] - centre[rows]).mean()
        assert own < 0.35 * mid, f"{name} rows: {own:.2f} vs centre-time {mid:.2f}"
    # The middle rows are captured at the frame's timestamp (the ground truth's pose).
    assert np.abs(rs[116:124] - centre[116:124]).mean() < 1.5


def test_motion_blur_grows_with_the_turn_rate() -> None:
    sharp = Renderer(SynthConfig(**SMALL))
    blurred = Renderer(SynthConfig(exposure_ms=16.0, **SMALL))

    def sharpness(img: np.ndarray) -> float:
        return float(np.abs(np.diff(img.astype(np.float32).mean(2), axis=1)).mean())

    # At rest (the first frame) the exposure changes nothing; mid-turn it smears the view by
    # ~200 deg/s x 16 ms = 3.2 deg (~17 px at fx 268): edges lose most of their contrast.
    np.testing.assert_allclose(blurred.render(0).rgb.astype(float), sharp.render(0).rgb.astype(float), atol=1.0)
    ratio = sharpness(blurred.render(I_FAST).rgb) / sharpness(sharp.render(I_FAST).rgb)
    assert ratio < 0.6


def test_exposure_gain_scales_the_image() -> None:
    cfg = SynthConfig(gain_swing=0.4, **{**SMALL, "motion": "static"})
    gains = [imaging.exposure_gain(cfg.seed, t, 0.4) for t in np.arange(0, 20, 0.05)]
    assert 0.6 - 1e-9 <= min(gains) < 0.75 and 1.25 < max(gains) <= 1.4 + 1e-9
    plain = Renderer(SynthConfig(**{**SMALL, "motion": "static"}))
    swung = Renderer(cfg)
    for i in (30, 90, 150):
        g = imaging.exposure_gain(cfg.seed, float(swung.times[i]), 0.4)
        a, b = plain.render(i).rgb.astype(float), swung.render(i).rgb.astype(float)
        ok = (a > 5) & (a * g < 250)  # neither black nor clipped
        assert abs(np.median(b[ok] / a[ok]) - g) < 0.02


def test_depth_is_captured_after_the_colour_image() -> None:
    r = Renderer(SynthConfig(depth_delay_ms=20.0, **SMALL))
    frame = r.render(I_FAST)
    t = float(r.times[I_FAST])
    delay = imaging.depth_delay_s(r.cfg.seed, I_FAST, 0.020)
    assert 0.007 <= delay <= 0.020
    later = camera_trajectory(r.cfg.motion, np.array([t + delay]), r.cfg.duration)[0]
    np.testing.assert_array_equal(frame.z, r._scene(t + delay, later, False)[0].z)
    assert not np.array_equal(frame.z, r._scene(t, r.poses[I_FAST], False)[0].z)


@pytest.mark.parametrize("field,value", [("exposure_ms", 40.0), ("rolling_shutter_ms", -1.0), ("gain_swing", 1.0)])
def test_bad_imaging_values_are_refused(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=field):
        SynthConfig(**{field: value}).validate()
