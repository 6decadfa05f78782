"""``semslam ARGS`` run in this process for the CLI tests: exit code, stdout and stderr."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from semslam.cli.main import main


@dataclass
class Outcome:
    rc: int
    out: str
    err: str

    @property
    def error_line(self) -> str:
        """The one ``error:`` line of a refused command (exit 2, nothing else on stderr)."""
        assert self.rc == 2 and "Traceback" not in self.err, self.err
        lines = [line for line in self.err.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), self.err
        return lines[0]


def cli(capsys: pytest.CaptureFixture[str], *args: object) -> Outcome:
    """``semslam ARGS`` in this process."""
    capsys.readouterr()
    rc = main([str(a) for a in args])
    captured = capsys.readouterr()
    return Outcome(rc, captured.out, captured.err)
