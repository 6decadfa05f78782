"""What a batch measured: per job, and per sequence x variant the median and the range
(min-max) over its repeats, so threaded runs, which differ from run to run, are compared
with their spread instead of one lucky or unlucky number.

``summary.json`` holds it all; ``summary.md`` is the table for a README or an issue.
"""

from __future__ import annotations

import os
import platform
from typing import Any

import numpy as np

from semslam.experiments.batch_jobs import JobRecord
from semslam.experiments.batch_plan import Plan

#: The per-job numbers summarised per sequence x variant.
METRICS = ("ate_rmse_m", "ms_per_frame_median", "lost_frames")


def machine() -> dict[str, Any]:
    return {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count()}


def spread(values: list[float]) -> dict[str, float] | None:
    """Median, min and max of the values there are (None when there are none)."""
    if not values:
        return None
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def group(records: list[JobRecord]) -> list[dict[str, Any]]:
    """One entry per (sequence, variant), in the plan's order, over its repeats."""
    cells: dict[tuple[str, str], list[JobRecord]] = {}
    for r in records:
        cells.setdefault((r.sequence, r.variant), []).append(r)
    out = []
    for (seq, var), rs in cells.items():
        ok = [r for r in rs if r.ok]
        entry: dict[str, Any] = {"sequence": seq, "variant": var, "preset": rs[0].preset, "n_runs": len(rs),
                                 "n_ok": len(ok), "n_failed": len(rs) - len(ok)}
        for m in METRICS:
            entry[m] = spread([getattr(r, m) for r in ok if getattr(r, m) is not None])
        entry["errors"] = [f"r{r.repeat}: {r.error}" for r in rs if not r.ok]
        out.append(entry)
    return out


def summarize(plan: Plan, records: list[JobRecord], executor: dict[str, Any]) -> dict[str, Any]:
    """The ``summary.json`` document."""
    n_ok = sum(r.ok for r in records)
    return {"plan": plan.to_dict(), "machine": machine(), "executor": executor,
            "n_jobs": len(records), "n_ok": n_ok, "n_failed": len(records) - n_ok,
            "n_resumed": sum(r.resumed for r in records),
            "groups": group(records), "jobs": [r.to_dict() for r in records]}


def _cm(s: dict[str, float] | None) -> str:
    return "n/a" if s is None else f"{s['median'] * 100:.2f} [{s['min'] * 100:.2f}-{s['max'] * 100:.2f}]"


def _num(s: dict[str, float] | None, digits: int) -> str:
    return "n/a" if s is None else f"{s['median']:.{digits}f} [{s['min']:.{digits}f}-{s['max']:.{digits}f}]"


def markdown(summary: dict[str, Any]) -> str:
    """Per sequence x variant: runs ok, then median [min-max] over the repeats; failed
    jobs with their errors below."""
    lines = ["| sequence | variant | ok / runs | ATE RMSE (cm) | ms/frame median | lost frames |",
             "|---|---|---|---|---|---|"]
    for g in summary["groups"]:
        lines.append(f"| {g['sequence']} | {g['variant']} | {g['n_ok']} / {g['n_runs']} | {_cm(g['ate_rmse_m'])} | "
                     f"{_num(g['ms_per_frame_median'], 1)} | {_num(g['lost_frames'], 0)} |")
    lines.append("")
    lines.append("Median [min-max] over the repeats that finished.")
    failed = [j for j in summary["jobs"] if j["status"] != "ok"]
    if failed:
        lines += ["", f"Failed jobs ({len(failed)}):", ""]
        lines += [f"- {j['sequence']}/{j['variant']}/r{j['repeat']}: {j['error']}" for j in failed]
    return "\n".join(lines) + "\n"
