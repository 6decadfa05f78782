"""Exceptions per area, so the CLI can print one clear line instead of a traceback.

Every error a user can cause (a bad file, a bad option) is one of these; anything else
escaping the CLI is a bug.
"""

from __future__ import annotations

from pathlib import Path


class SemslamError(Exception):
    """Base of all errors a user can cause."""


class DataError(SemslamError):
    """A dataset file or folder is missing, unreadable or inconsistent.

    The message always names the file and the problem.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class TrajectoryError(DataError):
    """A trajectory file cannot be read or two trajectories cannot be compared."""


class EvalError(SemslamError):
    """Metrics cannot be computed on the given input (too few poses, no overlap, ...)."""


class ConfigError(SemslamError):
    """A preset, a --set override or a command-line option is invalid."""


class OutputError(DataError):
    """An output path (``--out``, ``--save-map``, ``--rerun``, ``--save-inpainted``) cannot be
    written, or the output folder holds another run's files; found before the first frame,
    so no run is lost to it."""


class WorkerFailed(SemslamError):
    """A background worker (local mapping, loop closing, the maps' worker) raised; the run
    stops after writing what it has."""


class RunInterrupted(KeyboardInterrupt):
    """The run was asked to stop (Ctrl-C, SIGTERM) and has written what it had; the CLI
    exits with ``exit_code``: 128 + the signal's number, as a shell reports a command the
    signal ended (130 for SIGINT, 143 for SIGTERM)."""

    def __init__(self, message: str, exit_code: int = 130) -> None:
        super().__init__(message)
        self.exit_code = exit_code
