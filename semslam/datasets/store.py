"""Where downloaded sequences live, and getting one there by name.

The data folder is, in order: an explicit argument (``--data-dir``), ``$SEMSLAM_DATA``,
``$XDG_CACHE_HOME/semslam/datasets``, ``~/.cache/semslam/datasets``. Each sequence is a
folder in it named as its publisher names it; archives are downloaded into
``.downloads/`` there and deleted after extraction unless asked to keep them.

A mirror (``--mirror URL`` or ``$SEMSLAM_DATASET_MIRROR``) is a URL under which every
archive lies by its published file name; the tests point it at a local HTTP server.
"""

from __future__ import annotations

import difflib
import logging
import os
import shutil
from pathlib import Path

from semslam.datasets.archive import extract, missing_files
from semslam.datasets.catalogue import CATALOGUE, FAMILIES, DatasetEntry
from semslam.datasets.download import download
from semslam.errors import DataError

log = logging.getLogger(__name__)

DATA_ENV = "SEMSLAM_DATA"
MIRROR_ENV = "SEMSLAM_DATASET_MIRROR"


def data_dir(override: str | Path | None = None) -> Path:
    """The folder downloaded sequences are extracted to (see the module docstring)."""
    if override:
        return Path(override).expanduser()
    if os.environ.get(DATA_ENV):
        return Path(os.environ[DATA_ENV]).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache).expanduser() / "semslam" / "datasets"


def is_dataset_name(text: str) -> bool:
    """``family/name`` with a known family (``tum/``, ``bonn/``, ``icl/``)."""
    family, sep, rest = text.partition("/")
    return bool(sep) and family in FAMILIES and bool(rest) and "/" not in rest


def lookup(name: str) -> DatasetEntry:
    """The catalogue entry for ``name``; an unknown name is one line with the nearest names."""
    if name in CATALOGUE:
        return CATALOGUE[name]
    close = difflib.get_close_matches(name, list(CATALOGUE), n=3, cutoff=0.6)
    hint = f"; did you mean {' or '.join(close)}?" if close else ""
    raise DataError(name, f"unknown dataset name (see `semslam dataset list`){hint}")


def local_folder(entry: DatasetEntry, root: Path | None = None) -> Path:
    return (root if root is not None else data_dir()) / entry.folder


def is_downloaded(entry: DatasetEntry, root: Path | None = None) -> bool:
    folder = local_folder(entry, root)
    return folder.is_dir() and not missing_files(folder, entry.required)


def resolve(name: str, root: Path | None = None) -> Path:
    """The extracted folder of dataset ``name``; if it is not there, one line saying the
    command that downloads it."""
    entry = lookup(name)
    folder = local_folder(entry, root)
    if not is_downloaded(entry, root):
        raise DataError(name, f"not downloaded yet (no {folder}); run `semslam dataset get {name}`")
    return folder


def archive_url(entry: DatasetEntry, mirror: str | None = None) -> str:
    """The official URL, or the archive's file name under ``mirror`` / ``$SEMSLAM_DATASET_MIRROR``."""
    base = mirror or os.environ.get(MIRROR_ENV)
    return f"{base.rstrip('/')}/{entry.filename}" if base else entry.url


def get(name: str, root: Path | None = None, mirror: str | None = None, progress: bool = True,
        keep_archive: bool = False, force: bool = False) -> Path:
    """Download (resuming), verify and extract dataset ``name``; return its folder.

    An already extracted, complete folder is returned as it is unless ``force``. A corrupt
    archive is deleted (the next call downloads it again) and reported as one line.
    """
    entry = lookup(name)
    root = data_dir() if root is None else root
    folder = local_folder(entry, root)
    if folder.exists():
        if is_downloaded(entry, root) and not force:
            return folder
        if not force:
            raise DataError(folder, f"exists but lacks {', '.join(missing_files(folder, entry.required))}; "
                                    f"remove it or run `semslam dataset get {name} --force`")
        shutil.rmtree(folder)
    archive = root / ".downloads" / entry.filename
    if not archive.is_file():
        download(archive_url(entry, mirror), archive, sha256=entry.sha256, progress=progress)
    try:
        extract(archive, entry, folder)
    except DataError as exc:  # a complete-sized but unreadable archive: fetch it afresh next time
        archive.unlink(missing_ok=True)
        raise DataError(exc.path, f"{exc.problem}; deleted it, run the command again to download it afresh") from None
    if not keep_archive:
        archive.unlink(missing_ok=True)
    return folder
