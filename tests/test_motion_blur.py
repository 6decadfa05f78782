"""Motion blur (issue 13): the dense rotation alignment (``backend/depth_odometry.py``) on a
blurred fast-turn pair, tracking through a blurred glance with and without
``slam.depth_odometry`` and coasting (``slam.blur_coast_sharp_ratio``, on in ``default``),
and the rolling-shutter readout read from the sequence.

Frames come from the renderer in memory at 320x240 (no people, Kinect-like noise), the first
glance of ``walking_turns`` (up to ~200 deg/s) with a 16 ms exposure.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.backend.depth_odometry import RotationOdometry, rotation_angle_deg
from semslam.frontend.sharpness import sharpness
from semslam.api import System
from semslam.cli.main import main
from semslam.cli.run_cmd import rolling_shutter_flags
from semslam.config import load_config
from semslam.core.protocols import FramePacket
from semslam.core.types import Frame, TrackingState
from semslam.errors import ConfigError, DataError
from semslam.eval.metrics import ate
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rotation_about_centre import RotationFit
from semslam.geometry.se3 import invert
from semslam.io.calibration import rolling_shutter_ms_from_folder
from semslam.core.trajectory import Trajectory
from semslam.slam.orb.motion_priors import blur_coast, sharpness_history
from semslam.slam.orb.motion_priors.blur_coast import BlurCoast
from semslam.slam.orb.tracking import Tracking
from semslam.synth import SEQUENCES, Renderer
from tests.conftest import rendered_frames, write_tum_folder

#: Frames 22-45: at rest, then the first glance (frames ~30-38, 1.4-6.9 deg a frame), at rest.
FIRST, LAST = 22, 46


@pytest.fixture(scope="module")
def blurred() -> tuple[list[Frame], np.ndarray, PinholeCamera]:
    cfg = SEQUENCES["walking_turns"].replace(frames=60, exposure_ms=16.0, people=0, width=320, height=240)
    r = Renderer(cfg)
    return rendered_frames(r, range(FIRST, LAST)), r.poses.copy(), PinholeCamera(*cfg.intrinsics())


def _ate_cm(frames: list[Frame], poses: np.ndarray, cam: PinholeCamera, *overrides: str) -> tuple[float, int, dict]:
    system = System(load_config("orb", ["slam.sequential=true", *overrides]), cam)
    states = [system.track_frame(system.prepare(f)).state for f in frames]
    system.close()
    times = np.array([f.timestamp for f in frames])
    e = ate(Trajectory(times, poses[[f.index for f in frames]]), system.trajectory(), align="se3").stats["rmse"]
    return e * 100, states.count(TrackingState.OK), system.tracker.stats()


@pytest.mark.slow
def test_rotation_alignment_recovers_the_turn_on_blurred_frames(
        blurred: tuple[list[Frame], np.ndarray, PinholeCamera]) -> None:
    frames, poses, cam = blurred
    odo = RotationOdometry(cam.K, "rgbd")
    errors, start = [], []
    for i in range(34, 38):  # the fastest frames: 5.9-6.9 deg each, streaks of ~10 px here
        a, b = frames[i - 1 - FIRST], frames[i - FIRST]
        true = invert(poses[i - 1]) @ poses[i]  # T_prev_cur (poses are camera-to-world)
        guess = invert(poses[i - 2]) @ poses[i - 1]  # the motion model: the previous interval
        rel = odo.relative(a.gray, a.depth, b.gray, b.depth, guess)
        assert rel is not None
        np.testing.assert_array_equal(rel[:3, 3], guess[:3, 3])  # only the rotation is solved
        errors.append(rotation_angle_deg(invert(true) @ rel))
        start.append(rotation_angle_deg(invert(true) @ guess))
    assert max(start) > 0.9  # the motion model is a degree off while the turn speeds up and slows
    assert max(errors) < 0.25, errors  # measured 0.01-0.11 deg at 640x480


def test_sharpness_drops_with_blur_not_with_gain() -> None:
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(40, 200, (480, 640), dtype=np.uint8), (0, 0), 1.5)  # texture of a few px
    streak = cv2.blur(img, (12, 1))  # a 12-px horizontal streak
    s = sharpness(img)
    assert sharpness(streak) < 0.6 * s  # measured 0.43
    assert sharpness(np.clip(img * 1.3, 0, 255).astype(np.uint8)) == pytest.approx(s, rel=0.05)
    assert sharpness(np.zeros((48, 64), np.uint8)) == 0.0


def test_unknown_method_is_refused() -> None:
    with pytest.raises(ValueError):
        RotationOdometry(np.eye(3), "sift")
    with pytest.raises(ConfigError):
        load_config("orb", ["slam.depth_odometry=flow"])


@pytest.mark.slow
def test_blurred_glance_tracks_closer_with_the_alignment(
        blurred: tuple[list[Frame], np.ndarray, PinholeCamera]) -> None:
    frames, poses, cam = blurred
    without, n_without, stats0 = _ate_cm(frames, poses, cam)
    with_odo, n_with, stats = _ate_cm(frames, poses, cam, "slam.depth_odometry=rgbd")
    assert stats0["depth_odometry_frames"] == 0
    assert n_with == len(frames) and stats["depth_odometry_frames"] >= 3
    # Measured 16.7 cm without, 5.7 cm with (24 frames, 320x240).
    assert with_odo < 0.5 * without and with_odo < 10.0, (with_odo, without, n_without)


# ---------------------------------------------------------------- rolling shutter from the sequence
def test_rolling_shutter_read_from_sequence_json(tmp_path: Path) -> None:
    assert rolling_shutter_ms_from_folder(tmp_path) is None
    (tmp_path / "sequence.json").write_text(json.dumps({"config": {"rolling_shutter_ms": 30.0}}))
    assert rolling_shutter_ms_from_folder(tmp_path) == 30.0
    (tmp_path / "sequence.json").write_text(json.dumps({"rolling_shutter_ms": 12}))
    assert rolling_shutter_ms_from_folder(tmp_path) == 12.0
    (tmp_path / "sequence.json").write_text(json.dumps({"config": {"exposure_ms": 16.0}}))
    assert rolling_shutter_ms_from_folder(tmp_path) is None
    for bad in ('{"rolling_shutter_ms": -3}', '{"rolling_shutter_ms": "fast"}', "{not json"):
        (tmp_path / "sequence.json").write_text(bad)
        with pytest.raises(DataError):
            rolling_shutter_ms_from_folder(tmp_path)


def test_user_set_wins_over_the_sequence(tmp_path: Path) -> None:
    (tmp_path / "sequence.json").write_text(json.dumps({"config": {"rolling_shutter_ms": 30.0}}))
    flags, note = rolling_shutter_flags(tmp_path, [])
    assert flags == ["slam.rolling_shutter_ms=30.0"] and "sequence.json" in (note or "")
    flags, note = rolling_shutter_flags(tmp_path, ["slam.rolling_shutter_ms=0"])
    assert flags == [] and "--set" in (note or "") and "30 ms" in (note or "")
    assert rolling_shutter_flags(tmp_path / "missing", []) == ([], None)


def test_run_takes_the_readout_from_the_sequence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = write_tum_folder(tmp_path / "seq", n=3)
    (seq / "sequence.json").write_text(json.dumps({"config": {"rolling_shutter_ms": 25.0}}))
    out = tmp_path / "run"
    main(["run", str(seq), "-o", str(out), "-p", "orb", "--sequential", "--no-report", "--map", "none"])
    assert json.loads((out / "config.json").read_text())["slam"]["rolling_shutter_ms"] == 25.0
    assert "25 ms readout from" in capsys.readouterr().out
    out2 = tmp_path / "run2"
    main(["run", str(seq), "-o", str(out2), "-p", "orb", "--sequential", "--no-report", "-q", "--map", "none",
          "--set", "slam.rolling_shutter_ms=5"])
    assert json.loads((out2 / "config.json").read_text())["slam"]["rolling_shutter_ms"] == 5.0
    assert capsys.readouterr().out == ""  # -q: nothing but errors, the note neither


@pytest.mark.slow
def test_blurred_glance_coasts_on_the_images_shift(
        blurred: tuple[list[Frame], np.ndarray, PinholeCamera]) -> None:
    """``slam.blur_coast_sharp_ratio``: the blurred turning frames keep the steady motion's
    centre and a rotation fitted about it, seeded by the images' shift, and make no keyframe."""
    frames, poses, cam = blurred
    without, _n, stats0 = _ate_cm(frames, poses, cam)
    coast, n_coast, stats = _ate_cm(frames, poses, cam, "slam.blur_coast_sharp_ratio=0.6")
    assert stats0["coasted_frames"] == 0
    assert n_coast == len(frames) and 3 <= stats["coasted_frames"] <= 12
    # Measured 16.7 cm without, 6.2 cm with (2026-11-28): the view the turn ends on holds only
    # the points of this 24-frame, 320x240 clip. The full-size renders: README, "Hard imaging".
    assert coast < 0.5 * without and coast < 9.0, (coast, without)


def _not_again(gray: np.ndarray) -> float:
    raise AssertionError("sharpness measured again on the tracking thread")


def test_sharpness_measured_ahead_by_the_reader_tracks_the_same(
        blurred: tuple[list[Frame], np.ndarray, PinholeCamera], monkeypatch: pytest.MonkeyPatch) -> None:
    """``System.prepare`` (the reader thread of a run) measures each frame's sharpness where
    tracking compares it, off the tracking thread: the same value, and the blurred glance
    coasts to the same poses, to the byte, as when tracking measures it itself."""
    frames, _poses, cam = blurred
    off = System(load_config("orb", ["slam.sequential=true"]), cam)
    assert off.prepare(frames[0]).sharpness is None  # nothing compares it: not measured
    off.close()
    runs = []
    for ahead in (False, True):
        system = System(load_config("orb", ["slam.sequential=true", "slam.blur_coast_sharp_ratio=0.6"]), cam)
        for f in frames:
            f = Frame(f.index, f.timestamp, f.rgb, f.depth)  # no grey image cached from the other run
            if ahead:
                packet = system.prepare(f)
                assert packet.sharpness == sharpness(f.gray)
                with monkeypatch.context() as m:  # tracking takes the packet's value
                    m.setattr(sharpness_history, "sharpness", _not_again)
                    system.tracker.track(packet)
            else:
                system.tracker.track(FramePacket(f))
        system.close()
        runs.append((system.trajectory().poses, system.tracker.stats()["coasted_frames"]))
    assert runs[0][1] >= 3 and runs[1][1] == runs[0][1]
    assert np.array_equal(runs[0][0], runs[1][0])


@pytest.mark.slow
def test_coasting_leaves_a_sharp_glance_to_the_byte() -> None:
    """The same glance without blur: no frame is blurred, so turning coasting on (``default``
    has it) changes nothing, exactly."""
    cfg = SEQUENCES["walking_turns"].replace(frames=60, people=0, width=320, height=240)
    r = Renderer(cfg)
    frames, cam = rendered_frames(r, range(FIRST, LAST)), PinholeCamera(*cfg.intrinsics())
    trajectories = []
    for overrides in ([], ["slam.blur_coast_sharp_ratio=0.6"]):
        system = System(load_config("orb", ["slam.sequential=true", *overrides]), cam)
        for f in frames:
            system.track_frame(system.prepare(f))
        system.close()
        assert system.tracker.stats()["coasted_frames"] == 0
        trajectories.append(system.trajectory().poses)
    assert len(trajectories[0]) == len(frames)
    assert np.array_equal(trajectories[0], trajectories[1])


@pytest.fixture(scope="module")
def late_glance() -> tuple[list[Frame], np.ndarray, PinholeCamera]:
    """Frames 440-479 of the blurred walking_turns at 320x240: at rest, the glance of frames
    451-458, at rest."""
    cfg = SEQUENCES["walking_turns"].replace(exposure_ms=16.0, people=0, width=320, height=240)
    r = Renderer(cfg)
    return rendered_frames(r, range(440, 480)), r.poses.copy(), PinholeCamera(*cfg.intrinsics())


@pytest.mark.slow
def test_glance_ending_in_a_thin_view_makes_a_keyframe(
        late_glance: tuple[list[Frame], np.ndarray, PinholeCamera], monkeypatch: pytest.MonkeyPatch) -> None:
    """A glance can end in a view the map barely covers, where the features find no pose
    from the coasted frame before (threaded runs, with local mapping behind: 30 frames lost
    on walking_hard). Simulated here, deterministically, by failing the features' own
    tracking of every frame that follows a coasted frame without a keyframe. Without the
    settled keyframe the coast runs out (15 frames) and frames are lost; with it the third
    sharp, slowly turning coasted frame makes a keyframe and the next frame tracks from it."""
    frames, poses, cam = late_glance
    features_own = Tracking._track_frame

    def lost_after_a_coast(self: Tracking, cur: object, prediction: object, timings: dict[str, float]) -> bool:
        last = self.last
        coasting = any(p.coasting for p in self.priors if isinstance(p, BlurCoast))
        if self.state is TrackingState.OK and coasting and last is not None and self.last_kf_frame != last.index:
            return False
        return features_own(self, cur, prediction, timings)  # type: ignore[arg-type]

    monkeypatch.setattr(Tracking, "_track_frame", lost_after_a_coast)
    with_kf, n_ok, stats = _ate_cm(frames, poses, cam, "slam.blur_coast_sharp_ratio=0.6")
    monkeypatch.setattr(blur_coast, "COAST_SETTLED_FRAMES", 10**6)
    _, n_ok0, stats0 = _ate_cm(frames, poses, cam, "slam.blur_coast_sharp_ratio=0.6")
    assert stats0["coast_keyframes"] == 0 and n_ok0 < len(frames), (n_ok0, stats0["coasted_frames"])
    assert stats["coast_keyframes"] == 1 and n_ok == len(frames), (n_ok, stats["coasted_frames"])
    # Measured 2026-11-29: 3.0 cm with the keyframe (10 coasted), 10.7 cm on the 39 frames
    # left without it (15 coasted, then lost). Unpatched, the clip gives 5-7 cm frame errors.
    assert with_kf < 5.0, with_kf


@pytest.mark.slow
def test_coast_whose_matches_run_out_keeps_the_shifts_rotation(
        late_glance: tuple[list[Frame], np.ndarray, PinholeCamera], monkeypatch: pytest.MonkeyPatch) -> None:
    """A glance into a view the map does not cover yet: a frame that continues a coast can
    find too few matches to fit its rotation (walking_hard seed 21: 12, 8, 7, then 5, and 7
    frames were lost). It keeps the images' shift's rotation instead. Simulated here by
    refusing every fit of a continuing coast: every frame is still tracked, and no frame's
    rotation is more than 1 deg further from the truth than with the fits."""
    frames, poses, cam = late_glance
    fit = blur_coast.fit_rotation_about_centre

    def none_left_when_continuing(*args: object, **kwargs: object) -> RotationFit:
        res = fit(*args, **kwargs)  # type: ignore[arg-type]
        if kwargs.get("min_inliers") == blur_coast.COAST_CONTINUE_MIN_INLIERS:
            return RotationFit(res.R_cw, np.zeros_like(res.inliers), False)
        return res

    def run() -> tuple[list[TrackingState], dict, list[float]]:
        system = System(load_config("orb", ["slam.sequential=true", "slam.blur_coast_sharp_ratio=0.6"]), cam)
        states = [system.track_frame(system.prepare(f)).state for f in frames]
        system.close()
        R0 = poses[frames[0].index][:3, :3]
        err = [rotation_angle_deg(T[:3, :3].T @ (R0.T @ poses[f.index][:3, :3]))
               for T, f in zip(system.trajectory().poses, frames)]
        return states, system.tracker.stats(), err

    _, _, err_fitted = run()
    monkeypatch.setattr(blur_coast, "fit_rotation_about_centre", none_left_when_continuing)
    states, stats, err = run()
    assert states.count(TrackingState.OK) == len(frames), states
    assert stats["coasted_on_shift_only"] >= 3, stats["coasted_on_shift_only"]
    # Measured 2026-11-29: 5 frames on the shift alone; per frame at most 0.4 deg further from
    # the truth than with the fits (the glance's first frame is ~3 deg off in both runs).
    assert max(np.subtract(err, err_fitted)) < 1.0, np.subtract(err, err_fitted)
