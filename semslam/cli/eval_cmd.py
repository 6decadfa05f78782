"""``semslam eval GT EST``: ATE and RPE of a trajectory file against ground truth.

Numbers match ``evo_ape`` / ``evo_rpe`` for the same settings (see semslam.eval.metrics),
so results can be compared with published evo numbers.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

import typer
from rich.console import Console
from rich.table import Table

from semslam.errors import ConfigError, EvalError
from semslam.eval.metrics import (
    ALIGN_MODES,
    STAT_NAMES,
    AteResult,
    RpeResult,
    ate,
    rpe,
)
from semslam.core.trajectory import Trajectory
from semslam.io.trajectory import detect_format, read_trajectory


def _read_pair(
    gt_path: Path, est_path: Path, gt_times: Path | None, est_times: Path | None
) -> tuple[Trajectory, Trajectory, list[str]]:
    """Read both files; a KITTI estimate without times borrows the ground-truth times.

    KITTI pose files carry no stamps; an estimate written for a KITTI sequence has one pose
    per ground-truth pose, so when only ``--gt-times`` is given the same times apply.
    """
    notes: list[str] = []
    gt = read_trajectory(gt_path, times_path=gt_times)
    est_fmt = detect_format(est_path)
    times = est_times
    if est_fmt == "kitti" and est_times is None and gt_times is not None:
        times = gt_times
        notes.append(f"estimate is a KITTI file without --est-times: using {gt_times}")
    est = read_trajectory(est_path, fmt=est_fmt, times_path=times)
    return gt, est, notes


def _stats_table(ate_res: AteResult, rpe_res: RpeResult | None) -> Table:
    table = Table(title="trajectory error")
    table.add_column("statistic", justify="left")
    table.add_column("ATE (m)", justify="right")
    if rpe_res is not None:
        unit = rpe_res.delta_unit
        table.add_column(f"RPE trans (m)\n(delta {rpe_res.delta:g} {unit})", justify="right")
        table.add_column(f"RPE rot (deg)\n(delta {rpe_res.delta:g} {unit})", justify="right")
    for name in STAT_NAMES:
        row = [name, f"{ate_res.stats[name]:.6f}"]
        if rpe_res is not None:
            row += [f"{rpe_res.trans_stats[name]:.6f}", f"{rpe_res.rot_stats[name]:.6f}"]
        table.add_row(*row)
    n_row = ["poses / pairs", str(ate_res.n_associated)]
    if rpe_res is not None:
        n_row += [str(len(rpe_res.pairs))] * 2
    table.add_row(*n_row)
    return table


def _json_payload(
    gt: Trajectory, est: Trajectory, ate_res: AteResult, rpe_res: RpeResult | None, max_diff: float
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "ground_truth": gt.name,
        "estimate": est.name,
        "max_diff": max_diff,
        "align": ate_res.align,
        "alignment": {
            "rotation": ate_res.rotation.tolist(),
            "translation": ate_res.translation.tolist(),
            "scale": ate_res.scale,
        },
        "ate": {"unit": "m", "n_associated": ate_res.n_associated, **ate_res.stats},
    }
    if rpe_res is not None:
        out["rpe"] = {
            "delta": rpe_res.delta,
            "delta_unit": rpe_res.delta_unit,
            "pairs": len(rpe_res.pairs),
            "trans": {"unit": "m", **rpe_res.trans_stats},
            "rot": {"unit": "deg", **rpe_res.rot_stats},
        }
    return out


#: ``--delta-unit`` words (evo's one-letter units too) -> semslam.eval.metrics' units.
UNIT_WORDS = {"f": "frames", "frames": "frames", "m": "meters", "meters": "meters", "metres": "meters",
              "s": "seconds", "seconds": "seconds"}
#: evo's angle units, which pick pairs by rotation; not implemented here.
ANGLE_UNITS = ("d", "r", "degrees", "radians")
#: ``semslam run``'s RPE: pairs 1 s apart.
RUN_DELTA = (1.0, "seconds")


def alignment_mode(align: bool, correct_scale: bool, word: str | None) -> str:
    """se3, sim3, none or scale (evo's ``-s`` alone: the Umeyama scale only) from evo's
    ``-a`` / ``-s`` flags and semslam's ``--align MODE`` word. Neither: se3, as semslam run."""
    if word is not None and word not in ALIGN_MODES:
        raise ConfigError(f"--align {word!r}: use one of {', '.join(ALIGN_MODES)} (or -a / -s as evo)")
    base = word if word is not None else ("se3" if align else None)
    if correct_scale:
        return "sim3" if base in ("se3", "sim3") else "scale"
    return base or "se3"


def rpe_delta(delta: float | None, delta_unit: str | None) -> tuple[float, str]:
    """The RPE pair spacing: semslam run's 1 s when neither is given, else evo's defaults
    (delta 1, unit frames) for the one left out."""
    if delta is None and delta_unit is None:
        return RUN_DELTA
    unit = "f" if delta_unit is None else delta_unit.strip().lower()
    if unit in ANGLE_UNITS:
        raise ConfigError(f"--delta-unit {delta_unit}: pairs by rotation angle (evo's d / r) are not implemented; "
                          "use f (frames), m (metres) or s (seconds)")
    if unit not in UNIT_WORDS:
        raise ConfigError(f"--delta-unit {delta_unit!r}: use f / frames, m / meters or s / seconds")
    value = 1.0 if delta is None else delta
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"--delta: expected a number > 0, got {value:g}")
    return value, UNIT_WORDS[unit]


def scaled(traj: Trajectory, scale: float) -> Trajectory:
    """``traj`` with its positions multiplied by ``scale`` (evo's ``PosePath3D.scale``)."""
    poses = traj.poses.copy()
    poses[:, :3, 3] *= scale
    return Trajectory(traj.timestamps, poses, traj.name)


def eval_command(
    ctx: typer.Context,
    gt_path: Path = typer.Argument(..., metavar="GT", help="ground truth (TUM, KITTI or EuRoC csv)"),
    est_path: Path = typer.Argument(..., metavar="EST", help="estimated trajectory (TUM or KITTI)"),
    align: bool = typer.Option(False, "--align", "-a", help="Umeyama SE(3) alignment, as evo's -a (the default "
                                                            "unless -s is given); `--align sim3|none|se3` also works"),
    correct_scale: bool = typer.Option(False, "--correct_scale", "--correct-scale", "-s",
                                       help="with -a: Sim(3) alignment; alone: the scale only (as evo)"),
    max_diff: float = typer.Option(0.02, "--max-diff", "--t_max_diff", help="max time difference to associate [s]"),
    delta: Optional[float] = typer.Option(None, "--delta", help="RPE pair spacing (default: 1 s, as semslam run; "
                                                                "with --delta alone, frames as evo)"),
    delta_unit: Optional[str] = typer.Option(None, "--delta-unit", "--delta_unit",
                                             help="f (frames), m (meters) or s (seconds); evo's letters"),
    all_pairs: bool = typer.Option(False, "--all-pairs", "--all_pairs", help="RPE over overlapping pairs (evo)"),
    report: Optional[Path] = typer.Option(None, "--report", help="write an HTML report here"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="write the statistics as JSON here"),
    gt_times: Optional[Path] = typer.Option(None, "--gt-times", help="KITTI times.txt of GT"),
    est_times: Optional[Path] = typer.Option(None, "--est-times", help="KITTI times.txt of EST"),
) -> None:
    """ATE and RPE of EST against GT (formats auto-detected; numbers as evo for evo's flags).

    Default: SE(3) alignment and RPE over 1 s, as `semslam run` reports; evo's -a, -s,
    --delta, --delta_unit and --all_pairs mean what they mean for evo_ape / evo_rpe."""
    if len(ctx.args) > 1 or (ctx.args and not align):
        raise ConfigError(f"unexpected argument(s): {' '.join(ctx.args)} (expected GT EST and options)")
    mode = alignment_mode(align, correct_scale, ctx.args[0] if ctx.args else None)
    delta_value, unit = rpe_delta(delta, delta_unit)
    console = Console()
    gt, est, notes = _read_pair(gt_path, est_path, gt_times, est_times)
    for note in notes:
        console.print(f"[dim]note: {note}[/dim]")
    scale_only = None
    if mode == "scale":  # evo: the Umeyama Sim(3) fit's scale applied to the estimate, nothing else
        scale_only = ate(gt, est, align="sim3", max_diff=max_diff).scale
        est = scaled(est, scale_only)
    metric_align = "none" if mode == "scale" else mode
    ate_res = ate(gt, est, align=metric_align, max_diff=max_diff)
    try:
        rpe_res: RpeResult | None = rpe(gt, est, delta=delta_value, delta_unit=unit, align=metric_align,
                                        max_diff=max_diff, all_pairs=all_pairs)
    except EvalError as exc:
        if delta is not None or delta_unit is not None:
            raise  # the user's own delta: their error
        rpe_res = None  # shorter than semslam run's default 1 s: ATE only, as semslam run does
        console.print(f"[yellow]RPE over 1 s skipped: {exc}[/yellow]")
    console.print(_stats_table(ate_res, rpe_res))
    scale = scale_only if scale_only is not None else ate_res.scale
    scale_note = f", scale {scale:.6f}" if mode in ("sim3", "scale") else ""
    console.print(
        f"associated {ate_res.n_associated} poses (ground truth {len(gt)}, estimate {len(est)}), "
        f"alignment {mode}{scale_note}"
    )
    if json_out is not None:
        payload = _json_payload(gt, est, ate_res, rpe_res, max_diff)
        payload["align"] = mode
        payload["alignment"]["scale"] = scale
        try:
            json_out.write_text(json.dumps(payload, indent=2) + "\n")
        except OSError as exc:
            raise ConfigError(f"{json_out}: cannot write ({exc.strerror or exc})") from None
        console.print(f"wrote {json_out}")
    if report is not None:
        from semslam.eval.report import write_report  # matplotlib only when needed

        write_report(report, gt, est, ate_res, rpe_res, title=f"{est_path.name} vs {gt_path.name}")
        console.print(f"wrote {report}")


def register(app: typer.Typer) -> None:
    """Add the ``eval`` command to the semslam CLI."""
    # Extra arguments allowed: the word after --align (``--align sim3``, semslam's old form).
    app.command("eval", context_settings={"allow_extra_args": True})(eval_command)
