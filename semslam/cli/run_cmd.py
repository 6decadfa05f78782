"""``semslam run`` (SLAM on a sequence folder) and ``semslam demo`` (render + run + report)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from semslam.config import load_config
from semslam.io.sequence import open_sequence
from semslam.pipeline import RunSummary, run_slam

console = Console()


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")


def print_summary(summary: RunSummary) -> None:
    s = summary.stats
    table = Table(title=f"semslam {s['preset']} on {Path(s['sequence']).name}", show_header=False)
    table.add_row("frames (tracked / total)", f"{s['tracked_frames']} / {s['frames']}")
    if s.get("skipped_frames"):
        table.add_row("skipped unreadable frames", str(s["skipped_frames"]))
    table.add_row("keyframes", str(s["keyframes"]))
    for key, label in (("map_points", "map points"), ("loops", "loops closed"), ("relocalisations", "relocalisations")):
        if key in s:
            table.add_row(label, str(s[key]))
    if "ate" in s:
        table.add_row(f"ATE RMSE ({s['ate_alignment']})", f"{s['ate']['rmse'] * 100:.2f} cm")
        table.add_row("RPE trans RMSE (1 s)", f"{s['rpe_trans_1s']['rmse'] * 100:.2f} cm")
        table.add_row("RPE rot RMSE (1 s)", f"{s['rpe_rot_deg_1s']['rmse']:.3f} deg")
    ms = s["ms_per_frame"]
    table.add_row("ms/frame (median / p95)", f"{ms['median']:.1f} / {ms['p95']:.1f}")
    table.add_row("fps (tracking / wall incl. I/O)", f"{s['tracking_fps']:.1f} / {s['fps']:.1f}")
    console.print(table)
    outputs = ["trajectory.txt", "stats.json"] + (["report.html"] if (summary.out_dir / "report.html").exists() else [])
    console.print(f"wrote {', '.join(outputs)} to {summary.out_dir}")


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        sequence: Path = typer.Argument(..., help="TUM-layout RGB-D folder (rgb.txt, depth.txt[, groundtruth.txt])"),
        out: Path = typer.Option(..., "--out", "-o", help="output folder"),
        preset: str = typer.Option("default", "--preset", "-p", help="preset name or YAML file"),
        max_frames: Optional[int] = typer.Option(None, "--max-frames", min=1, help="stop after N frames"),
        camera: Optional[str] = typer.Option(None, "--camera", help="fx,fy,cx,cy[,k1,k2,p1,p2,k3]"),
        depth_scale: Optional[float] = typer.Option(None, "--depth-scale", help="depth units per metre (TUM 5000)"),
        set_: list[str] = typer.Option([], "--set", help="override a config field: section.key=value"),
        no_report: bool = typer.Option(False, "--no-report", help="skip the HTML report"),
        save_map: Optional[Path] = typer.Option(None, "--save-map", help="write the map here (.npz) at the end"),
        load_map: Optional[Path] = typer.Option(None, "--load-map", help="start from a saved map (relocalise in it)"),
        localization_only: bool = typer.Option(False, "--localization-only", help="track against the map without extending it"),
        sequential: bool = typer.Option(False, "--sequential", help="run local mapping and loop closing inline (deterministic)"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
        verbose: bool = typer.Option(False, "--verbose", "-v"),
    ) -> None:
        """Run SLAM on a sequence; write trajectory.txt, stats.json and report.html."""
        _setup_logging(verbose)
        cfg = load_config(preset, set_)
        if depth_scale is not None:
            cfg.depth_scale = depth_scale
        if sequential:
            cfg.slam.sequential = True
        if localization_only:
            cfg.slam.localization_only = True
        seq = open_sequence(sequence, camera=camera, depth_scale=cfg.depth_scale)
        summary = run_slam(seq, cfg, out, max_frames=max_frames, progress=not quiet, report=not no_report,
                           save_map=save_map, load_map=load_map)
        print_summary(summary)

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

        from semslam.synth import SEQUENCES, render_sequence

        _setup_logging(False)
        if sequence_name not in SEQUENCES:
            raise typer.BadParameter(f"unknown sequence {sequence_name!r} (known: {', '.join(SEQUENCES)})")
        synth_cfg = SEQUENCES[sequence_name]
        if frames is not None:
            synth_cfg = replace(synth_cfg, frames=frames)
        seq_dir = out / sequence_name
        if _needs_render(seq_dir, synth_cfg):
            console.print(f"rendering synthetic sequence {sequence_name!r} ({synth_cfg.frames} frames) to {seq_dir}")
            render_sequence(synth_cfg, seq_dir, progress=not quiet)
        else:
            console.print(f"reusing rendered sequence {seq_dir}")
        cfg = load_config(preset)
        summary = run_slam(open_sequence(seq_dir), cfg, out / "run", progress=not quiet)
        print_summary(summary)
        s = summary.stats
        if "ate" in s:
            console.print(f"[bold]ATE RMSE {s['ate']['rmse'] * 100:.2f} cm, {s['tracking_fps']:.1f} fps tracking "
                          f"({s['fps']:.1f} fps wall)[/bold]; report: {summary.out_dir / 'report.html'}")


def _needs_render(seq_dir: Path, synth_cfg: object) -> bool:
    """Re-render unless the folder holds the same configuration, complete."""
    from dataclasses import asdict

    meta = seq_dir / "sequence.json"
    if not meta.is_file() or not (seq_dir / "groundtruth.txt").is_file():
        return True
    try:
        saved = json.loads(meta.read_text())
    except (OSError, json.JSONDecodeError):
        return True
    wanted = json.loads(json.dumps(asdict(synth_cfg)))  # type: ignore[call-overload]
    return saved.get("config", saved) != wanted
