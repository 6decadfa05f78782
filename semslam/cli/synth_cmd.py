"""``semslam synth OUT``: render a synthetic TUM RGB-D sequence with exact ground truth.

Real TUM data cannot be downloaded everywhere; the tests, the demo and the benchmarks run
on these sequences. ``--sequence NAME`` picks a preset; options given explicitly override
the preset's values.
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from semslam.errors import ConfigError
from semslam.synth.sequences import MOTIONS, SEQUENCES, SynthConfig, get_sequence


def synth_command(
    out: Path = typer.Argument(
        ..., help="Output folder (created; earlier PNGs in it are replaced)."
    ),
    sequence: str | None = typer.Option(
        None,
        "--sequence",
        "-s",
        help=f"Preset: {', '.join(sorted(SEQUENCES))}. Other options override it.",
    ),
    motion: str | None = typer.Option(
        None, "--motion", help=f"Camera motion: {'|'.join(MOTIONS)} (default: xyz)."
    ),
    frames: int | None = typer.Option(
        None, "--frames", "-n", help="Number of frames (default: 300)."
    ),
    people: int | None = typer.Option(
        None, "--people", help="People walking through the view, 0-8 (default: 2)."
    ),
    people_mode: str | None = typer.Option(
        None, "--people-mode", help="walking|idle (default: walking)."
    ),
    mover: bool | None = typer.Option(
        None,
        "--mover/--no-mover",
        help="Add an unlabelled moving cabinet (class 21) (default: off).",
    ),
    seed: int | None = typer.Option(
        None, "--seed", help="Seed of textures, paths and noise (default: 0)."
    ),
    noise: bool | None = typer.Option(
        None, "--noise/--no-noise", help="Sensor noise and depth holes (default: on)."
    ),
    fps: float | None = typer.Option(None, "--fps", help="Frame rate (default: 30)."),
    width: int | None = typer.Option(
        None, "--width", help="Image width; intrinsics scale with it (default: 640)."
    ),
    height: int | None = typer.Option(None, "--height", help="Image height (default: 480)."),
    people_dir: Path | None = typer.Option(
        None,
        "--people-dir",
        help="Folder with the TUM person photos "
        "(default: $SEMSLAM_PEOPLE_DIR or ../shared/data/images_people).",
    ),
    background: bool | None = typer.Option(
        None,
        "--background/--no-background",
        help="Also render every frame without people and movers into background/rgb and "
        "background/depth (exact depth), the truth for inpainting (default: off).",
    ),
    exposure_ms: float | None = typer.Option(
        None, "--exposure-ms", help="Exposure time: motion blur (default: 0, sharp)."
    ),
    rolling_shutter_ms: float | None = typer.Option(
        None, "--rolling-shutter-ms", help="Row readout time, top to bottom (default: 0, global shutter)."
    ),
    gain_swing: float | None = typer.Option(
        None, "--gain-swing", help="Auto-exposure swings of up to +- this share, e.g. 0.4 (default: 0)."
    ),
    depth_delay_ms: float | None = typer.Option(
        None, "--depth-delay-ms", help="Depth captured up to this long after RGB, 35-100 %% of it per frame "
        "(default: 0)."
    ),
    layout: int | None = typer.Option(
        None, "--layout", help="Room layout: 0 the office (every preset), 1 the lounge, held out "
        "of the shipped networks' training (default: 0)."
    ),
    blackout_start_s: float | None = typer.Option(
        None, "--blackout-start-s", help="When the lens goes black (seconds; default: 0)."
    ),
    blackout_s: float | None = typer.Option(
        None, "--blackout-s", help="Seconds of black frames with no depth while the camera moves (default: 0)."
    ),
    occluder_s: float | None = typer.Option(
        None, "--occluder-s", help="Seconds of a hand or card over the lens (no depth where it covers), "
        "from the end of the blackout, or from --occluder-start-s without one (default: 0)."
    ),
    occluder_start_s: float | None = typer.Option(
        None, "--occluder-start-s", help="When the occluder comes if there is no blackout (default: 0)."
    ),
    occluder_kind: str | None = typer.Option(
        None, "--occluder-kind", help="hand|object (a flat printed card) (default: hand)."
    ),
    white_balance_swing: float | None = typer.Option(
        None, "--white-balance-swing", help="Per-channel white-balance swings of up to +- this share "
        "(default: 0)."
    ),
    photo_textures: Path | None = typer.Option(
        None, "--photo-textures", help="Folder of photographs laid on a seeded share of the surfaces "
        "(renders for training; fill one with `python -m semslam.synth.textures DIR`)."
    ),
    stereo_baseline: float | None = typer.Option(
        None, "--stereo-baseline", help="Also render a right camera this far (metres) along the left "
        "camera's x axis, a rectified pair: rgb_right/, rgb_right.txt and camera.yaml (ORB-SLAM3 "
        "settings) (default: 0, none)."
    ),
    imu: bool | None = typer.Option(
        None, "--imu/--no-imu", help="EuRoC layout only: also simulate a 200 Hz IMU on the body frame "
        "(mav0/imu0: EuRoC's ADIS16448 noise and seeded biases, exact with --no-noise; the true biases go "
        "to the ground truth) (default: off)."
    ),
    depth: bool | None = typer.Option(
        None, "--depth/--no-depth", help="EuRoC layout only: also write the Kinect-like depth registered "
        "to cam0 (mav0/depth0: 16-bit PNGs, metres x 5000, as the tum layout's depth/) (default: off)."
    ),
    layout_format: str = typer.Option(
        "tum", "--layout-format", help="tum (the TUM RGB-D folder), euroc (EuRoC ASL: mav0/cam0, "
        "mav0/cam1, the body's ground truth in mav0/state_groundtruth_estimate0; with --imu mav0/imu0, with "
        "--depth mav0/depth0) or kitti (KITTI odometry, "
        "needs --stereo-baseline: grey image_0/ and image_1/, calib.txt, times.txt and poses.txt, the left "
        "camera's poses relative to the first)."
    ),
    workers: int = typer.Option(2, "--workers", help="Frames rendered in parallel (threads)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Render a synthetic TUM RGB-D sequence (rgb, depth, semantic, exact ground truth).

    Static surfaces are labelled with NYU-40 classes (id 100 + NYU id); ``scene.json`` and
    ``movers.json`` hold the static boxes and the movers' boxes for map metrics."""
    from semslam.synth.render import render_sequence

    base = get_sequence(sequence) if sequence else SynthConfig()
    if people_dir is not None and not people_dir.is_dir():
        raise ConfigError(f"--people-dir {people_dir}: folder not found")
    if photo_textures is not None and not photo_textures.is_dir():
        raise ConfigError(f"--photo-textures {photo_textures}: folder not found")
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    cfg = base.replace(
        motion=motion,
        frames=frames,
        people=people,
        people_mode=people_mode,
        mover=mover,
        seed=seed,
        noise=noise,
        fps=fps,
        width=width,
        height=height,
        people_dir=str(people_dir) if people_dir is not None else None,
        background=background,
        exposure_ms=exposure_ms,
        rolling_shutter_ms=rolling_shutter_ms,
        gain_swing=gain_swing,
        depth_delay_ms=depth_delay_ms,
        layout=layout,
        blackout_start_s=blackout_start_s,
        blackout_s=blackout_s,
        occluder_s=occluder_s,
        occluder_start_s=occluder_start_s,
        occluder_kind=occluder_kind,
        white_balance_swing=white_balance_swing,
        photo_textures=str(photo_textures) if photo_textures is not None else None,
        stereo_baseline=stereo_baseline,
        imu=imu,
        euroc_depth=depth,
    ).validate()
    start = time.perf_counter()
    path = render_sequence(cfg, out, progress=not quiet, workers=workers, layout_format=layout_format)
    secs = time.perf_counter() - start
    mover_note = (", mover" if cfg.mover else "") + (", background" if cfg.background else "")
    mover_note += f", layout {cfg.layout}" if cfg.layout else ""
    mover_note += f", stereo {cfg.stereo_baseline:g} m" if cfg.stereo_baseline else ""
    mover_note += {"euroc": ", EuRoC layout", "kitti": ", KITTI layout"}.get(layout_format, "")
    mover_note += " + IMU 200 Hz" if cfg.imu else ""
    mover_note += " + depth" if cfg.euroc_depth else ""
    typer.echo(
        f"synth: {cfg.frames} frames ({cfg.motion}, {cfg.people} people{mover_note}) "
        f"in {secs:.1f} s ({secs / cfg.frames:.3f} s/frame) -> {path}"
    )


def register(app: typer.Typer) -> None:
    """Add the ``synth`` command to the semslam CLI."""
    app.command("synth")(synth_command)
