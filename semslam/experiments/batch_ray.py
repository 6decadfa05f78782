"""Batch jobs as Ray tasks: on a local Ray instance started for the batch, or on an existing
cluster (``--address``), each job reserving ``num_cpus`` of it.

Ray is an optional dependency (the ``batch`` extra); without it ``semslam batch --no-ray``
runs the same jobs in-process. On a cluster every node needs semslam installed and the
batch's output (and data) folders on a shared file system: each job writes its own folder.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from semslam.errors import ConfigError
from semslam.experiments.batch_jobs import JobRecord, one_line, run_job, write_record
from semslam.experiments.batch_plan import Job


def import_ray() -> Any:
    """The ``ray`` module, or one line saying how to get it."""
    try:
        import ray
    except ImportError:
        raise ConfigError("Ray is not installed: pip install 'semslam[batch]' (ray), or run the jobs one after "
                          "another in this process with --no-ray") from None
    return ray


@contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """Ray, ready: the session already open in this process if there is one (left open);
    else a connection to ``address``, or a local instance with ``num_cpus`` (default: the
    machine's), quiet and without the dashboard, shut down at the end."""
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report over the network
    quiet = {"log_to_driver": False, "logging_level": logging.ERROR}
    try:
        if address:
            ray.init(address=address, **quiet)
        else:
            ray.init(num_cpus=num_cpus or os.cpu_count() or 1, include_dashboard=False, **quiet)
    except ConnectionError as exc:
        raise ConfigError(f"--address {address}: cannot connect to the Ray cluster ({one_line(exc)})") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def run_on_ray(ray: Any, jobs: list[Job]) -> Iterator[JobRecord]:
    """Submit every job as a task; yield each record as its task finishes (any order). A
    task whose worker died (killed, out of memory) is recorded as failed here."""
    if not jobs:
        return
    total = float(ray.cluster_resources().get("CPU", 0))
    need = max(j.num_cpus for j in jobs)
    if need > total:
        raise ConfigError(f"num_cpus: {need:g} per job, but the Ray cluster has {total:g} CPUs (no job could start)")
    # max_retries=0: a job that crashed its worker is a result, not something to repeat.
    task = ray.remote(max_retries=0)(run_job)
    pending = {task.options(num_cpus=j.num_cpus, name=f"semslam {j.key}").remote(j): j for j in jobs}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    record = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - Ray's errors for a lost task: that job failed
                    record = JobRecord.for_job(job, "failed", one_line(exc))
                    write_record(record)
                yield record
    finally:
        for ref in pending:  # stopped early (Ctrl-C): the rest should not run on
            ray.cancel(ref, force=True)
