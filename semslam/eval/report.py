"""Self-contained HTML evaluation report: one file, plots embedded as base64 PNG.

A single file is easy to attach to an issue or archive next to a run; it needs no server
and no side files. Plots use matplotlib's Agg canvas directly (no pyplot global state), so
reports can be written from worker threads and headless machines.
"""

from __future__ import annotations

import base64
import html
import io
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from semslam.errors import DataError, EvalError
from semslam.eval.metrics import STAT_NAMES, AteResult, RpeResult
from semslam.geometry.alignment import apply_sim3
from semslam.core.trajectory import Trajectory
from semslam.viz.map_views import find_cloud, write_views

log = logging.getLogger(__name__)

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em;
       color: #222; max-width: 1100px; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.7em; text-align: right; }
th { background: #f3f3f3; } td.k, th.k { text-align: left; }
img { max-width: 100%; height: auto; }
.meta { color: #666; font-size: 0.9em; }
"""

_GT_COLOR = "#444444"
_EST_COLOR = "#1f77b4"
_ERR_COLOR = "#d62728"


def _png(fig: Figure) -> str:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(b64: str, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{b64}">'


def _fmt(value: Any) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    return html.escape(str(value))


def _trajectory_plot(gt: Trajectory, est_aligned: Trajectory) -> str:
    fig = Figure(figsize=(11, 4.6))
    for k, (axis, label) in enumerate(((1, "y"), (2, "z"))):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.plot(gt.positions[:, 0], gt.positions[:, axis], "-", color=_GT_COLOR, lw=1.2,
                label="ground truth")
        ax.plot(est_aligned.positions[:, 0], est_aligned.positions[:, axis], "-",
                color=_EST_COLOR, lw=1.0, label="estimate (aligned)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel(f"{label} [m]")
        ax.set_title(f"x-{label}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _ate_plot(ate_result: AteResult) -> str:
    fig = Figure(figsize=(11, 3.2))
    ax = fig.add_subplot(1, 1, 1)
    t = ate_result.timestamps - ate_result.timestamps[0]
    ax.plot(t, ate_result.errors, "-", color=_ERR_COLOR, lw=1.0)
    ax.axhline(ate_result.stats["rmse"], color="k", ls="--", lw=0.8,
               label=f"rmse {ate_result.stats['rmse']:.4g} m")
    ax.set_xlabel("time since first pose [s]")
    ax.set_ylabel("ATE [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _rpe_plot(rpe_result: RpeResult, t0: float) -> str:
    fig = Figure(figsize=(11, 4.8))
    t = rpe_result.timestamps - t0
    ax1 = fig.add_subplot(2, 1, 1)
    ax1.plot(t, rpe_result.trans_errors, "-", color=_ERR_COLOR, lw=1.0)
    ax1.set_ylabel("RPE trans [m]")
    ax1.grid(True, alpha=0.3)
    ax2 = fig.add_subplot(2, 1, 2, sharex=ax1)
    ax2.plot(t, rpe_result.rot_errors, "-", color="#9467bd", lw=1.0)
    ax2.set_ylabel("RPE rot [deg]")
    ax2.set_xlabel("time since first pose [s]")
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    return _png(fig)


#: How the summary names each ATE alignment when a run reports two.
_ALIGN_NAMES = {"sim3": "Sim(3) aligned", "se3": "SE(3) aligned, metric scale", "none": "not aligned"}


def _stats_table(rows: list[tuple[str, dict[str, float], str]]) -> str:
    head = "".join(f"<th>{n}</th>" for n in STAT_NAMES)
    body = []
    for label, stats, unit in rows:
        cells = "".join(f"<td>{stats[n]:.6g}</td>" for n in STAT_NAMES)
        body.append(f'<tr><td class="k">{html.escape(label)}</td><td>{unit}</td>{cells}</tr>')
    return (
        f'<table><tr><th class="k">metric</th><th>unit</th>{head}</tr>'
        + "".join(body)
        + "</table>"
    )


def _map_section(map_dir: Path) -> list[str]:
    """Views of the map's cloud (semantic, else keyframe cloud), also written as PNGs next
    to it; nothing when the run wrote no cloud, a note when the cloud cannot be read."""
    cloud = find_cloud(map_dir)
    if cloud is None:
        return []
    try:
        views = write_views(cloud)
    except DataError as exc:
        log.warning("map views skipped: %s", exc)
        return ["<h2>Map</h2>", f'<p class="meta">map views skipped: {html.escape(str(exc))}</p>']
    parts = ["<h2>Map</h2>", f'<p class="meta">{html.escape(cloud.name)}; views also in '
             f'{html.escape(", ".join(p.name for p in views.values()))} beside it</p>']
    for name, png in views.items():
        parts.append(_img(base64.b64encode(png.read_bytes()).decode("ascii"), f"{name} ({png.name})"))
    return parts


def write_report(
    path: str | Path,
    gt: Trajectory,
    est: Trajectory,
    ate_result: AteResult,
    rpe_result: RpeResult | None = None,
    title: str = "",
    extra: Mapping[str, Any] | None = None,
    map_dir: str | Path | None = None,
    ate_se3: AteResult | None = None,
) -> Path:
    """Write an HTML report comparing ``est`` with ``gt`` and return its path.

    Contents: a summary table (ATE and RPE statistics, alignment, ``extra`` key/values
    such as fps), top-down plots (x-y and x-z) of the ground truth and the whole estimate
    mapped by the ATE alignment, ATE over time and RPE over time; with ``map_dir``, views
    of the map's point cloud when the run wrote one (``viz.map_views``). ``ate_se3``: for a
    monocular run aligned with Sim(3), the same trajectory's ATE with SE(3) alignment only
    (a depth network's metric scale is then part of the error), as a second row.
    """
    path = Path(path)
    title = title or "Trajectory evaluation"
    est_aligned = Trajectory(
        est.timestamps,
        apply_sim3(est.poses, ate_result.rotation, ate_result.translation, ate_result.scale),
        est.name,
    )
    rows = [(f"ATE ({_ALIGN_NAMES.get(ate_result.align, ate_result.align)})" if ate_se3 is not None else "ATE",
             ate_result.stats, "m")]
    if ate_se3 is not None:
        rows.append((f"ATE ({_ALIGN_NAMES['se3']})", ate_se3.stats, "m"))
    if rpe_result is not None:
        what = f"RPE trans (delta {rpe_result.delta:g} {rpe_result.delta_unit})"
        rows.append((what, rpe_result.trans_stats, "m"))
        rows.append((f"RPE rot (delta {rpe_result.delta:g} {rpe_result.delta_unit})",
                     rpe_result.rot_stats, "deg"))

    info: dict[str, Any] = {
        "ground truth": gt.name or "-",
        "estimate": est.name or "-",
        "alignment": ate_result.align,
        "scale": ate_result.scale,
        "associated poses": f"{ate_result.n_associated} (gt {len(gt)}, est {len(est)})",
    }
    if rpe_result is not None:
        info["RPE pairs"] = len(rpe_result.pairs)
    info.update(dict(extra or {}))
    info_rows = "".join(
        f'<tr><td class="k">{html.escape(str(k))}</td><td class="k">{_fmt(v)}</td></tr>'
        for k, v in info.items()
    )

    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        "<h2>Summary</h2>",
        _stats_table(rows),
        f"<table>{info_rows}</table>",
        "<h2>Trajectory (top-down)</h2>",
        _img(_trajectory_plot(gt, est_aligned), "trajectory x-y and x-z"),
        "<h2>ATE over time</h2>",
        _img(_ate_plot(ate_result), "ATE over time"),
    ]
    if rpe_result is not None:
        parts += ["<h2>RPE over time</h2>",
                  _img(_rpe_plot(rpe_result, float(ate_result.timestamps[0])), "RPE over time")]
    if map_dir is not None:
        parts += _map_section(Path(map_dir))
    parts.append(
        '<p class="meta">ATE: translation part after alignment; RPE: relative motion error '
        "(translation in m, rotation in degrees); statistics as in evo.</p></body></html>"
    )
    try:
        path.write_text("\n".join(parts), encoding="utf-8")
    except OSError as exc:
        raise EvalError(f"{path}: cannot write the report ({exc.strerror or exc})") from None
    return path
