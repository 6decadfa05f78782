"""``semslam eval GT EST``: ATE and RPE of a trajectory file against ground truth.

Numbers match ``evo_ape`` / ``evo_rpe`` for the same settings (see semslam.eval.metrics),
so results can be compared with published evo numbers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from semslam.errors import ConfigError
from semslam.eval.metrics import (
    ALIGN_MODES,
    DELTA_UNITS,
    STAT_NAMES,
    AteResult,
    RpeResult,
    ate,
    rpe,
)
from semslam.io.trajectory import Trajectory, detect_format, read_trajectory


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


def eval_command(
    gt_path: Path = typer.Argument(..., metavar="GT", help="ground truth (TUM, KITTI or EuRoC csv)"),
    est_path: Path = typer.Argument(..., metavar="EST", help="estimated trajectory (TUM or KITTI)"),
    align: str = typer.Option("se3", "--align", help="se3 (RGB-D/stereo), sim3 (monocular) or none"),
    max_diff: float = typer.Option(0.02, "--max-diff", help="max time difference to associate [s]"),
    delta: float = typer.Option(1.0, "--delta", help="RPE pair spacing"),
    delta_unit: str = typer.Option("frames", "--delta-unit", help="frames, seconds or meters"),
    report: Path | None = typer.Option(None, "--report", help="write an HTML report here"),
    json_out: Path | None = typer.Option(None, "--json", help="write the statistics as JSON here"),
    gt_times: Path | None = typer.Option(None, "--gt-times", help="KITTI times.txt of GT"),
    est_times: Path | None = typer.Option(None, "--est-times", help="KITTI times.txt of EST"),
) -> None:
    """ATE and RPE of EST against GT (formats auto-detected; numbers as evo)."""
    if align not in ALIGN_MODES:
        raise ConfigError(f"--align {align!r}: use one of {', '.join(ALIGN_MODES)}")
    if delta_unit not in DELTA_UNITS:
        raise ConfigError(f"--delta-unit {delta_unit!r}: use one of {', '.join(DELTA_UNITS)}")
    console = Console()
    gt, est, notes = _read_pair(gt_path, est_path, gt_times, est_times)
    for note in notes:
        console.print(f"[dim]note: {note}[/dim]")
    ate_res = ate(gt, est, align=align, max_diff=max_diff)
    rpe_res = rpe(gt, est, delta=delta, delta_unit=delta_unit, align=align, max_diff=max_diff)
    console.print(_stats_table(ate_res, rpe_res))
    scale = f", scale {ate_res.scale:.6f}" if align == "sim3" else ""
    console.print(
        f"associated {ate_res.n_associated} poses (ground truth {len(gt)}, estimate {len(est)}), "
        f"alignment {align}{scale}"
    )
    if json_out is not None:
        payload = _json_payload(gt, est, ate_res, rpe_res, max_diff)
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
    app.command("eval")(eval_command)
