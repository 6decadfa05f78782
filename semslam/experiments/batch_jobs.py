"""One batch job, run in whatever process it lands in (a Ray worker or the batch's own):
open the sequence as ``semslam run`` does, ``run_slam`` into the job's folder, and leave a
``job.json`` there saying how it ended.

``job.json`` is written last, so a job is finished when its folder holds one with
``"status": "ok"`` (and the run's ``stats.json``): a re-run batch skips it. A failed job
records its error as one line and never raises; only a stop request (Ctrl-C) does.
"""

from __future__ import annotations

import json
import socket
import time
import traceback
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from semslam.config import load_config
from semslam.core.types import RunResult
from semslam.errors import SemslamError
from semslam.experiments.batch_plan import Job
from semslam.io.sequence import kind_for_sensor, open_sequence
from semslam.pipeline import run_slam
from semslam.runtime import limit_threads

RESULT_FILE = "job.json"


@dataclass
class JobRecord:
    """How one job ended, with the numbers the summary compares (from its ``stats.json``)."""

    sequence: str
    variant: str
    preset: str
    overrides: list[str]
    repeat: int
    seed: int | None
    source: str
    max_frames: int | None
    out_dir: str
    status: str  # "ok" or "failed"
    error: str | None = None
    ate_rmse_m: float | None = None
    ms_per_frame_median: float | None = None
    lost_frames: int | None = None
    frames: int | None = None
    tracked_frames: int | None = None
    keyframes: int | None = None
    job_s: float | None = None  # the whole job: opening, warm-up, tracking, outputs
    host: str = ""
    resumed: bool = False  # finished by an earlier invocation of the batch

    @property
    def key(self) -> str:
        return f"{self.sequence}/{self.variant}/r{self.repeat}"

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "JobRecord":
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})

    @classmethod
    def for_job(cls, job: Job, status: str, error: str | None = None, job_s: float | None = None) -> "JobRecord":
        return cls(job.sequence, job.variant, job.preset, list(job.overrides), job.repeat, job.seed, job.source,
                   job.max_frames, str(job.out_dir), status, error, job_s=job_s, host=socket.gethostname())

    def same_work(self, job: Job) -> bool:
        """Whether this record is of ``job`` as the plan now has it (same preset, overrides,
        seed, sequence and frames): a changed plan runs the job again."""
        return (self.preset, tuple(self.overrides), self.seed, self.source, self.max_frames) == (
            job.preset, job.overrides, job.seed, job.source, job.max_frames)

    def with_result(self, r: RunResult) -> "JobRecord":
        """The run's numbers, as its ``stats.json`` holds them."""
        self.ate_rmse_m, self.ms_per_frame_median = r.ate_rmse, r.ms_per_frame.get("median")
        self.lost_frames, self.frames, self.tracked_frames, self.keyframes = (
            r.lost_frames, r.frames, r.tracked_frames, r.keyframes)
        return self


def one_line(exc: BaseException) -> str:
    """A semslam error's own line (it names the file and the problem); for anything else
    the last line of the exception as Python prints it."""
    if isinstance(exc, SemslamError):
        return f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    text = "".join(traceback.format_exception_only(type(exc), exc))
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else type(exc).__name__


def read_stats(out_dir: str | Path) -> RunResult:
    return RunResult.from_dict(json.loads((Path(out_dir) / "stats.json").read_text()))


def finished_record(job: Job) -> JobRecord | None:
    """The record of a job an earlier batch finished (``job.json`` ok, of the same work,
    and ``stats.json`` readable), marked ``resumed``; None if it has to run."""
    path = job.out_dir / RESULT_FILE
    try:
        record = JobRecord.from_dict(json.loads(path.read_text()))
        if not record.ok or not record.same_work(job):
            return None
        record.with_result(read_stats(job.out_dir))
    except (OSError, ValueError, TypeError):
        return None
    record.resumed = True
    return record


def write_record(record: JobRecord) -> None:
    out = Path(record.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / RESULT_FILE).write_text(json.dumps(record.to_dict(), indent=2))


def run_job(job: Job) -> JobRecord:
    """``semslam run`` for one job; the record is also written to the job's ``job.json``."""
    limit_threads()  # a Ray worker is a fresh process: one BLAS / OpenCV thread, as the CLI sets
    (job.out_dir / RESULT_FILE).unlink(missing_ok=True)  # a failed earlier attempt
    t0 = time.perf_counter()
    try:
        cfg = load_config(job.preset, job.run_overrides)
        seq = open_sequence(job.source, kind=kind_for_sensor(cfg.sensor), depth_scale=cfg.depth_scale)
        run_slam(seq, cfg, job.out_dir, max_frames=job.max_frames, progress=False, report=job.report)
        record = JobRecord.for_job(job, "ok", job_s=time.perf_counter() - t0).with_result(read_stats(job.out_dir))
    except Exception as exc:  # noqa: BLE001 - any failure is this job's, recorded; the batch goes on
        record = JobRecord.for_job(job, "failed", one_line(exc), job_s=time.perf_counter() - t0)
    write_record(record)
    return record
