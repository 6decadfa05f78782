"""Synthetic sequence parameters and the named presets.

A :class:`SynthConfig` fully determines a rendered sequence (together with the package
version and, for people, the person photos used), so it is written to ``sequence.json``
and the same config renders byte-identical images.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from semslam.errors import ConfigError
from semslam.synth.layouts import get_layout
from semslam.synth.occluder import OCCLUDER_KINDS

MOTIONS = ("static", "xyz", "rpy", "halfsphere", "loop", "room_loop", "room_revisit", "fast_turns",
           "jump_back", "room_path", "shake", "fast_rotations")
PEOPLE_MODES = ("walking", "idle")

#: TUM freiburg3 RGB intrinsics at 640x480 (fx, fy, cx, cy); fr3 images are undistorted.
FR3_INTRINSICS = (535.4, 539.2, 320.1, 247.6)
#: First timestamp, like the fr3 recordings of July 2012.
DEFAULT_START_TIME = 1341846647.0


@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines one synthetic TUM-style sequence.

    ``noise=False`` gives exact images and depth (no sensor noise, no depth holes) for
    tests that check that poses, depth and intrinsics agree exactly. ``box_carrier`` adds
    a person (beyond ``people``) who pushes a large unlabelled box along the floor, then
    carries it up to the camera (``synth/box_carry.py``). ``background`` also renders
    every frame without people and movers into ``background/rgb`` and
    ``background/depth`` (exact depth), the truth for inpainting; it costs about a
    second texture pass per frame, hence off by default.
    """

    motion: str = "xyz"
    frames: int = 300
    people: int = 2
    mover: bool = False
    box_carrier: bool = False
    seed: int = 0
    noise: bool = True
    fps: float = 30.0
    width: int = 640
    height: int = 480
    people_mode: str = "walking"
    people_dir: str | None = None
    start_time: float = DEFAULT_START_TIME
    background: bool = False
    # Hard imaging (issue 13; synth/imaging.py), all off by default. Exposure time: the RGB
    # image integrates the scene over it (motion blur).
    exposure_ms: float = 0.0
    # Rolling shutter: rows are read out top to bottom over this time.
    rolling_shutter_ms: float = 0.0
    # Auto-exposure: the gain swings smoothly by up to +- this share (0.4 = +-40 %).
    gain_swing: float = 0.0
    # Depth is captured this long after the RGB image at most (seeded per frame between
    # 35 % and 100 % of it: 20 gives 7-20 ms), the depth-colour offset of a Kinect.
    depth_delay_ms: float = 0.0
    # Blackout (issue 13's atlas): from blackout_start_s for blackout_s seconds the camera
    # is covered (black RGB, no depth) while it keeps moving. 0 = none.
    blackout_start_s: float = 0.0
    blackout_s: float = 0.0
    # Room layout (synth/layouts.py): 0 the office every preset uses, 1 the lounge that no
    # shipped network was trained in (held out for evaluation).
    layout: int = 0
    # Issue 38: something over the lens (synth/occluder.py: a hand or a card, no depth where
    # it covers) for occluder_s seconds, from the end of the blackout, or from
    # occluder_start_s when there is none; the camera keeps moving.
    occluder_s: float = 0.0
    occluder_start_s: float = 0.0
    occluder_kind: str = "hand"
    # Auto white balance hunting: per-channel gains swing by up to +- this share.
    white_balance_swing: float = 0.0
    # Issue 40: a folder of photographs laid on a seeded share of the surfaces
    # (synth/texture_atlas.py), renders for training SDFCNN; None = procedural textures only.
    photo_textures: str | None = None
    # Issue 41: a right camera this far (metres) along the left camera's x axis, a rectified
    # pair (same intrinsics and orientation; synth/stereo.py); 0 = none (RGB-D only).
    stereo_baseline: float = 0.0
    # Issue 42: the EuRoC layout (only) also holds a simulated 200 Hz IMU (mav0/imu0, EuRoC's
    # ADIS16448 noise; synth/imu.py) and, with euroc_depth, the Kinect-like depth registered
    # to cam0 (mav0/depth0) for RGB-D-inertial runs. render_sequence refuses them elsewhere.
    imu: bool = False
    euroc_depth: bool = False

    def validate(self) -> SynthConfig:
        """Raise :class:`ConfigError` naming the first bad field; return self."""
        if self.motion not in MOTIONS:
            raise ConfigError(
                f"synth: unknown motion {self.motion!r} (choose from {', '.join(MOTIONS)})"
            )
        if self.people_mode not in PEOPLE_MODES:
            raise ConfigError(
                f"synth: unknown people_mode {self.people_mode!r} "
                f"(choose from {', '.join(PEOPLE_MODES)})"
            )
        if self.frames < 1:
            raise ConfigError(f"synth: frames must be >= 1, got {self.frames}")
        if not 0 <= self.people <= 8:
            raise ConfigError(f"synth: people must be between 0 and 8, got {self.people}")
        if not 1.0 <= self.fps <= 120.0:
            raise ConfigError(f"synth: fps must be between 1 and 120, got {self.fps}")
        if not (32 <= self.width <= 4096 and 32 <= self.height <= 4096):
            raise ConfigError(f"synth: image size {self.width}x{self.height} out of range")
        if self.seed < 0:
            raise ConfigError(f"synth: seed must be >= 0, got {self.seed}")
        for name in ("exposure_ms", "rolling_shutter_ms", "depth_delay_ms"):
            if not 0.0 <= getattr(self, name) <= 1000.0 / self.fps:
                raise ConfigError(f"synth: {name} must be between 0 and one frame period "
                                  f"({1000.0 / self.fps:.1f} ms), got {getattr(self, name)}")
        if self.blackout_start_s < 0 or self.blackout_s < 0:
            raise ConfigError(f"synth: blackout_start_s and blackout_s must be >= 0, got "
                              f"{self.blackout_start_s} and {self.blackout_s}")
        get_layout(self.layout)  # raises ConfigError naming the layouts
        if self.occluder_s < 0 or self.occluder_start_s < 0:
            raise ConfigError(f"synth: occluder_s and occluder_start_s must be >= 0, got "
                              f"{self.occluder_s} and {self.occluder_start_s}")
        if self.occluder_kind not in OCCLUDER_KINDS:
            raise ConfigError(f"synth: unknown occluder_kind {self.occluder_kind!r} "
                              f"(choose from {', '.join(OCCLUDER_KINDS)})")
        if not 0.0 <= self.white_balance_swing < 1.0:
            raise ConfigError(f"synth: white_balance_swing must be in [0, 1), got "
                              f"{self.white_balance_swing}")
        if not 0.0 <= self.gain_swing < 1.0:
            raise ConfigError(f"synth: gain_swing must be in [0, 1), got {self.gain_swing}")
        if not 0.0 <= self.stereo_baseline <= 2.0:
            raise ConfigError(f"synth: stereo_baseline must be between 0 and 2 m, got {self.stereo_baseline}")
        return self

    def intrinsics(self) -> tuple[float, float, float, float]:
        """fr3 intrinsics scaled to this image size (exact for 640x480)."""
        sx, sy = self.width / 640.0, self.height / 480.0
        fx, fy, cx, cy = FR3_INTRINSICS
        return (fx * sx, fy * sy, cx * sx, cy * sy)

    def occluder_window(self) -> tuple[float, float]:
        """(start, end) seconds of the occluder; empty when there is none."""
        start = self.blackout_start_s + self.blackout_s if self.blackout_s > 0 else self.occluder_start_s
        return start, start + self.occluder_s

    @property
    def duration(self) -> float:
        """Seconds from the first to one period after the last frame."""
        return self.frames / self.fps

    def to_dict(self) -> dict[str, Any]:
        """The fields, as ``sequence.json`` holds them; ``stereo_baseline``, ``imu`` and
        ``euroc_depth`` only when set, so that renders without them stay byte-identical to
        those made before they existed."""
        out = dataclasses.asdict(self)
        for name in ("stereo_baseline", "imu", "euroc_depth"):
            if not getattr(self, name):
                del out[name]
        return out

    def replace(self, **changes: Any) -> SynthConfig:
        """A copy with some fields changed (``None`` values are ignored, for CLI overrides)."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})


#: Named presets, modelled on the TUM fr3 sitting/walking sequences the methods are
#: evaluated on. ``demo`` is what ``semslam demo`` and the README use.
SEQUENCES: dict[str, SynthConfig] = {
    "demo": SynthConfig(motion="xyz", frames=300, people=2),
    "walking_xyz": SynthConfig(motion="xyz", frames=450, people=2, seed=1),
    "walking_static": SynthConfig(motion="static", frames=450, people=2, seed=2),
    "walking_rpy": SynthConfig(motion="rpy", frames=450, people=2, seed=3),
    "walking_halfsphere": SynthConfig(motion="halfsphere", frames=450, people=2, seed=4),
    "sitting_static": SynthConfig(
        motion="static", frames=300, people=1, people_mode="idle", seed=5
    ),
    "sitting_xyz": SynthConfig(motion="xyz", frames=300, people=1, people_mode="idle", seed=6),
    "static_xyz": SynthConfig(motion="xyz", frames=300, people=0, seed=7),
    "loop": SynthConfig(motion="loop", frames=600, people=0, seed=8),
    # 1.25 turns looking at every wall (~15 deg/s): the start is out of view for ~300 deg.
    "room_loop": SynthConfig(motion="room_loop", frames=1080, people=0, seed=10),
    # Issue 13's long runs: 20 minutes of turns round the room, one every 30 s
    # (benchmarks/long_run.py renders it once into a cache; any length is the start of this).
    "long_revisit": SynthConfig(motion="room_revisit", frames=36000, people=0, seed=15),
    "mover_xyz": SynthConfig(motion="xyz", frames=300, people=0, mover=True, seed=9),
    # A person pushes a large carton (no person, label 21) across the view, lifts it and
    # carries it up to the camera (up to ~60 % of the image); 10 s period.
    "walking_box": SynthConfig(motion="xyz", frames=450, people=0, box_carrier=True, seed=11),
    # Issue 13's hard imaging: two people walking, fast glances up to ~200 deg/s, 16 ms
    # exposure (motion blur), 30 ms rolling-shutter readout, +-40 % auto-exposure swings and
    # a 7-20 ms depth-colour offset. `walking_turns` is the same scene and motion, clean.
    "walking_hard": SynthConfig(motion="fast_turns", frames=744, people=2, seed=12, exposure_ms=16.0,
                                rolling_shutter_ms=30.0, gain_swing=0.4, depth_delay_ms=20.0),
    "walking_turns": SynthConfig(motion="fast_turns", frames=744, people=2, seed=12),
    # Issue 13's atlas: the camera is covered for 2 s (black, no depth) while it keeps moving;
    # and a cut into an unmapped part of the room (90 deg to the side) that stays there for
    # 2 s, then turns back to the first part (camera_motion.JUMP_*).
    "blackout_xyz": SynthConfig(motion="xyz", frames=180, people=0, seed=13, blackout_start_s=2.0, blackout_s=2.0),
    "jump_back": SynthConfig(motion="jump_back", frames=240, people=0, seed=14),
}


def get_sequence(name: str) -> SynthConfig:
    """The preset called ``name``; :class:`ConfigError` listing the names otherwise."""
    try:
        return SEQUENCES[name]
    except KeyError:
        raise ConfigError(
            f"synth: unknown sequence {name!r} (choose from {', '.join(sorted(SEQUENCES))})"
        ) from None
