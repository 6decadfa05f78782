"""Reading the small text files of a sequence (lists, trajectories, calibration) with one
rule for what cannot be read: a missing file, a folder, bytes that are not UTF-8 text are
each one error naming the file."""

from __future__ import annotations

from pathlib import Path

from semslam.errors import DataError


def read_text_lines(path: Path, error: type[DataError] = DataError) -> list[str]:
    """The file's lines (a UTF-8 byte order mark is dropped); ``error`` (a DataError type)
    for a file that is missing, not a regular file, unreadable or not text."""
    if not path.exists():
        raise error(path, "file not found")
    if not path.is_file():
        raise error(path, "not a regular file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise error(path, "not a text file (cannot decode as UTF-8)") from None
    except OSError as exc:
        raise error(path, f"cannot read ({exc.strerror or exc})") from None
    return text.splitlines()
