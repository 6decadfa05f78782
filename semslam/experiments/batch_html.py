"""``summary.html``: a batch's results on one self-contained page (no scripts, no network).

Plots are matplotlib figures inlined as SVG: per sequence and variant, every repeat as a
dot, the median as a bar and the min-max range as a line, for ATE RMSE and ms/frame.
Each plot's artists carry ids (``ate-runs-0``: the repeats of the first variant), so a
browser test can count what was drawn.
"""

from __future__ import annotations

import html
import io
from pathlib import Path
from typing import Any

import matplotlib
from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.figure import Figure

from semslam.experiments.batch_summary import markdown

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em; color: #222;
       max-width: 1200px; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: right; }
th { background: #f3f3f3; } td.k, th.k { text-align: left; } tr.failed td { color: #b00; }
figure.plot { margin: 1em 0; } figure.plot svg { max-width: 100%; height: auto; }
.meta { color: #666; font-size: 0.9em; }
"""

#: (metric, scale to the plotted unit, axis label, plot id)
PLOTS = (("ate_rmse_m", 100.0, "ATE RMSE (cm)", "ate"), ("ms_per_frame_median", 1.0, "ms/frame (median of run)", "ms"))


def _order(items: list[dict[str, Any]], key: str) -> list[str]:
    return list(dict.fromkeys(i[key] for i in items))


def metric_svg(summary: dict[str, Any], metric: str, scale: float, ylabel: str, plot_id: str) -> str:
    """One plot as inline SVG markup: sequences along x, one colour per variant."""
    jobs = [j for j in summary["jobs"] if j["status"] == "ok" and j[metric] is not None]
    groups = {(g["sequence"], g["variant"]): g for g in summary["groups"]}
    sequences, variants = _order(summary["groups"], "sequence"), _order(summary["groups"], "variant")
    fig = Figure(figsize=(min(16.0, max(6.0, 1.0 + 0.5 * len(sequences) * len(variants))), 3.8))
    FigureCanvasSVG(fig)
    ax = fig.add_subplot()
    width = 0.8 / len(variants)
    colours = matplotlib.colormaps["tab10"].colors
    for vi, var in enumerate(variants):
        colour = colours[vi % len(colours)]
        x_of = {s: si - 0.4 + width * (vi + 0.5) for si, s in enumerate(sequences)}
        runs = [(x_of[j["sequence"]], j[metric] * scale) for j in jobs if j["variant"] == var]
        cells = [(x_of[s], g[metric]) for s in sequences if (g := groups.get((s, var))) and g[metric]]
        if cells:
            xs = [x for x, _ in cells]
            ax.vlines(xs, [c["min"] * scale for _, c in cells], [c["max"] * scale for _, c in cells], colors=[colour],
                      linewidth=2.5, alpha=0.45, gid=f"{plot_id}-range-{vi}")
            ax.plot(xs, [c["median"] * scale for _, c in cells], linestyle="none", marker="_", markersize=16,
                    markeredgewidth=2.5, color=colour, gid=f"{plot_id}-median-{vi}")
        ax.plot([x for x, _ in runs], [y for _, y in runs], linestyle="none", marker="o", markersize=4,
                color=colour, alpha=0.8, label=var, gid=f"{plot_id}-runs-{vi}")
    failed = {s: sum(g["n_failed"] for g in summary["groups"] if g["sequence"] == s) for s in sequences}
    ax.set_xticks(range(len(sequences)), [s + (f"\n({failed[s]} failed)" if failed[s] else "") for s in sequences],
                  rotation=15 if len(sequences) > 4 else 0)
    ax.set_xlim(-0.6, len(sequences) - 0.4)
    ax.set_ylim(bottom=0)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize="small", loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=min(len(variants), 6),
              frameon=False)
    fig.tight_layout()
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": plot_id, "svg.fonttype": "path"}):  # ids unique per plot
        fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.index("<svg"):]  # drop the XML prolog and doctype: inline in HTML


def _cell(s: dict[str, float] | None, scale: float, digits: int) -> str:
    if s is None:
        return "n/a"
    return f"{s['median'] * scale:.{digits}f} <span class=meta>[{s['min'] * scale:.{digits}f}-{s['max'] * scale:.{digits}f}]</span>"


def _groups_table(summary: dict[str, Any]) -> str:
    rows = ["<table><tr><th class=k>sequence</th><th class=k>variant</th><th>ok / runs</th><th>ATE RMSE (cm)</th>"
            "<th>ms/frame median</th><th>lost frames</th></tr>"]
    for g in summary["groups"]:
        rows.append(f"<tr><td class=k>{html.escape(g['sequence'])}</td><td class=k>{html.escape(g['variant'])}</td>"
                    f"<td>{g['n_ok']} / {g['n_runs']}</td><td>{_cell(g['ate_rmse_m'], 100, 2)}</td>"
                    f"<td>{_cell(g['ms_per_frame_median'], 1, 1)}</td><td>{_cell(g['lost_frames'], 1, 0)}</td></tr>")
    return "\n".join(rows) + "</table>"


def _jobs_table(summary: dict[str, Any], out: Path) -> str:
    rows = ["<table><tr><th class=k>sequence</th><th class=k>variant</th><th>repeat</th><th>status</th><th>ATE RMSE (cm)</th>"
            "<th>ms/frame</th><th>lost</th><th>job s</th><th>folder</th><th>error</th></tr>"]
    for j in summary["jobs"]:
        try:
            rel = Path(j["out_dir"]).resolve().relative_to(out.resolve()).as_posix()
        except ValueError:
            rel = j["out_dir"]
        ate = "" if j["ate_rmse_m"] is None else f"{j['ate_rmse_m'] * 100:.2f}"
        ms = "" if j["ms_per_frame_median"] is None else f"{j['ms_per_frame_median']:.1f}"
        job_s = "" if j["job_s"] is None else f"{j['job_s']:.1f}"
        lost = "" if j["lost_frames"] is None else j["lost_frames"]
        cls = "" if j["status"] == "ok" else " class=failed"
        rows.append(f"<tr{cls}><td class=k>{html.escape(j['sequence'])}</td><td class=k>{html.escape(j['variant'])}"
                    f"</td><td>{j['repeat']}</td><td class=k>{j['status']}{' (earlier)' if j['resumed'] else ''}</td>"
                    f"<td>{ate}</td><td>{ms}</td><td>{lost}</td><td>{job_s}</td>"
                    f"<td class=k><a href=\"{html.escape(rel)}/\">{html.escape(rel)}</a></td>"
                    f"<td class=k>{html.escape(j['error'] or '')}</td></tr>")
    return "\n".join(rows) + "</table>"


def write_html(path: Path, summary: dict[str, Any]) -> Path:
    """Write the page; the plots are drawn from ``summary`` alone."""
    ex = summary["executor"]
    where = f"Ray ({ex.get('address') or 'local'})" if ex.get("ray") else "in-process, one job after another"
    plots = []
    for metric, scale, label, plot_id in PLOTS:
        plots.append(f"<h2>{html.escape(label)}</h2>\n<p class=meta>Dots: the repeats; bar: their median; line: "
                     f"min-max.</p>\n<figure class=plot id=\"{plot_id}-plot\">"
                     f"{metric_svg(summary, metric, scale, label, plot_id)}</figure>")
    body = [
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>semslam batch</title>",
        f"<style>{_CSS}</style></head><body>",
        "<h1>semslam batch</h1>",
        f"<p class=meta>{summary['n_jobs']} jobs: {summary['n_ok']} ok, {summary['n_failed']} failed "
        f"({summary['n_resumed']} finished earlier); run {html.escape(where)}; machine: "
        f"{html.escape(', '.join(f'{k} {v}' for k, v in summary['machine'].items()))}</p>",
        "<h2>Per sequence and variant: median [min-max] over repeats</h2>", _groups_table(summary),
        *plots,
        "<h2>Jobs</h2>", _jobs_table(summary, path.parent),
        "<h2>Markdown</h2><pre>" + html.escape(markdown(summary)) + "</pre>",
        "</body></html>",
    ]
    path.write_text("\n".join(body))
    return path
