"""Unpacking a downloaded sequence archive into its folder, all or nothing.

The archive is unpacked into a hidden temporary folder beside the target; only when it
opened without error and holds the files the catalogue requires is the sequence folder
moved to its final name (one rename on the same file system). On any failure the
temporary folder is removed, so no half-extracted sequence is ever left where
``semslam run`` would find it.
"""

from __future__ import annotations

import shutil
import tarfile
import tempfile
import zipfile
import zlib
from pathlib import Path

from semslam.datasets.catalogue import DatasetEntry
from semslam.errors import DataError


def missing_files(folder: Path, required: tuple[str, ...]) -> list[str]:
    """The required names (globs) with no match in ``folder``."""
    return [pattern for pattern in required if not any(folder.glob(pattern))]


def _unpack(archive: Path, kind: str, into: Path) -> None:
    try:
        if kind == "zip":
            with zipfile.ZipFile(archive) as zf:
                zf.extractall(into)  # zipfile drops absolute paths and ".." itself
        else:
            with tarfile.open(archive, "r:*") as tf:
                tf.extractall(into, filter="data")  # refuses links and paths leaving `into`
    except (tarfile.TarError, zipfile.BadZipFile, EOFError, zlib.error, OSError, ValueError) as exc:
        raise DataError(archive, f"corrupt or truncated {kind} archive ({exc.__class__.__name__}: {exc})") from None


def _sequence_root(archive: Path, entry: DatasetEntry, tmp: Path) -> Path:
    """The unpacked folder holding the sequence: the catalogue's ``inner`` folder, else (a
    publisher repacked it) the top level or a single folder there that has the files."""
    expected = tmp / entry.inner if entry.inner else tmp
    candidates = [expected, tmp, *sorted(p for p in tmp.iterdir() if p.is_dir())]
    found = next((c for c in candidates if c.is_dir() and not missing_files(c, entry.required)), None)
    if found is not None:
        return found
    if not expected.is_dir():
        names = sorted(p.name for p in tmp.iterdir())[:5]
        raise DataError(archive, f"archive has no folder {entry.inner}/ (it holds: {', '.join(names) or 'nothing'})")
    where = f"{entry.inner}/" if entry.inner else "its top level"
    raise DataError(archive, f"archive is incomplete: no {', '.join(missing_files(expected, entry.required))} in {where}")


def extract(archive: Path, entry: DatasetEntry, target: Path) -> Path:
    """Unpack ``archive`` (as described by ``entry``) to ``target``; return ``target``.

    Raises :class:`DataError` naming the archive when it cannot be read or lacks the
    sequence's files; ``target`` does not exist afterwards in that case.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".extracting", dir=target.parent))
    try:
        _unpack(archive, entry.archive, tmp)
        _sequence_root(archive, entry, tmp).rename(target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target
