"""``semslam batch``: every job of a plan, on Ray or one after another in this process, then
``summary.json``, ``summary.md`` and ``summary.html`` in the batch's output folder.

Both ways run the same ``batch_jobs.run_job`` on the same jobs and write the same summary.
Jobs an earlier invocation finished are skipped (``resume``); failed ones run again.
Synthetic sequences are rendered here first (cached), so jobs only read them.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from semslam.experiments.batch_html import write_html
from semslam.experiments.batch_jobs import JobRecord, finished_record, run_job
from semslam.experiments.batch_plan import Job, Plan
from semslam.experiments.batch_summary import markdown, summarize


@dataclass(frozen=True)
class Executor:
    """Where the jobs run: Ray (a local instance, or the cluster at ``address``) or this
    process, one after another."""

    ray: bool = True
    address: str | None = None
    num_cpus: int | None = None  # size of the local Ray instance (default: the machine's cores)

    def to_dict(self) -> dict[str, Any]:
        return {"ray": self.ray, "address": self.address}


def render_synthetic(plan: Plan, log: Callable[[str], None]) -> Plan:
    """Render the plan's synthetic sequences into its data folder (skipped when a render of
    the same configuration is there); the plan with their folders as sources."""
    from semslam.synth import SEQUENCES, ensure_rendered

    sources = {}
    for s in plan.sequences:
        if not s.synth:
            continue
        frames = s.frames or plan.frames
        cfg = SEQUENCES[s.synth] if frames is None else SEQUENCES[s.synth].replace(frames=frames)
        if s.layout is not None:
            cfg = cfg.replace(layout=s.layout)
        folder = plan.data.resolve() / s.render_name  # absolute: jobs may run in another working directory
        t0 = time.perf_counter()
        if ensure_rendered(cfg, folder):
            log(f"rendered {s.render_name} ({cfg.frames} frames) in {time.perf_counter() - t0:.1f} s")
        sources[s.label] = str(folder)
    return plan.with_sources(sources)


def _stderr(text: str) -> None:
    print(text, file=sys.stderr)


def run_batch(plan: Plan, out: str | Path, executor: Executor = Executor(), resume: bool = True,
              progress: bool = True, on_record: Callable[[JobRecord], None] | None = None,
              log: Callable[[str], None] = _stderr) -> dict[str, Any]:
    """Run the plan's jobs into ``out`` and write the summaries; returns ``summary.json``'s
    document. ``on_record`` sees each job's record as it finishes (skipped ones first)."""
    if executor.ray:  # no Ray: say so before rendering anything
        from semslam.experiments.batch_ray import import_ray

        import_ray()
    out = Path(out).resolve()  # absolute: jobs may run in another working directory
    plan = render_synthetic(plan, log)
    jobs = plan.jobs(out)
    records: dict[str, JobRecord] = {}
    if resume:
        for job in jobs:
            if (rec := finished_record(job)) is not None:
                records[job.key] = rec
    todo = [j for j in jobs if j.key not in records]
    if records:
        log(f"{len(records)} of {len(jobs)} jobs finished earlier (skipped); running {len(todo)}")
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    # Warnings of in-process runs (--no-ray) are printed above the bar instead of through it.
    with tqdm(total=len(jobs), initial=len(records), unit="job", desc="semslam batch", disable=not progress,
              dynamic_ncols=True, file=sys.stderr) as bar, logging_redirect_tqdm():
        if on_record is not None:
            for rec in records.values():
                on_record(rec)
        failed = 0
        for rec in _execute(todo, executor):
            records[rec.key] = rec
            failed += not rec.ok
            bar.set_postfix_str(f"{rec.key} {rec.status}" + (f", {failed} failed" if failed else ""), refresh=False)
            bar.update(1)
            if on_record is not None:
                on_record(rec)
    summary = summarize(plan, [records[j.key] for j in jobs], executor.to_dict())
    write_summary(out, summary)
    return summary


def _execute(jobs: list[Job], executor: Executor) -> Iterator[JobRecord]:
    if not executor.ray:
        yield from (run_job(j) for j in jobs)
        return
    if not jobs:
        return
    from semslam.experiments.batch_ray import ray_session, run_on_ray

    with ray_session(executor.address, executor.num_cpus) as ray:
        yield from run_on_ray(ray, jobs)


def write_summary(out: Path, summary: dict[str, Any]) -> dict[str, Path]:
    """``summary.json``, ``summary.md`` and ``summary.html`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / "summary.json", "md": out / "summary.md", "html": out / "summary.html"}
    paths["json"].write_text(json.dumps(summary, indent=2))
    paths["md"].write_text(markdown(summary))
    write_html(paths["html"], summary)
    return paths
