"""One file over HTTP(S) with resume, a progress bar and a size / checksum check.

The bytes go to ``FILE.part`` first: an interrupted download (network, Ctrl-C) keeps what it
has, and the next call asks the server for the rest with an HTTP ``Range`` request. A
server that ignores ``Range`` (answers 200) is downloaded again from the start. The file
gets its final name only when its size equals what the server announced
(``Content-Length`` / ``Content-Range``) and, where one is known, its SHA-256 matches.
"""

from __future__ import annotations

import hashlib
import http.client
import logging
import re
import urllib.error
import urllib.request
from pathlib import Path

from semslam.errors import SemslamError

log = logging.getLogger(__name__)

BLOCK = 1 << 20
USER_AGENT = "semslam-dataset/0.1 (+https://github.com/semslam)"


class DownloadError(SemslamError):
    """A download failed; the message names the URL and the problem."""

    def __init__(self, url: str, problem: str) -> None:
        self.url = url
        self.problem = problem
        super().__init__(f"{url}: {problem}")


def part_path(dest: Path) -> Path:
    return dest.with_name(dest.name + ".part")


def _total_from_range(header: str | None) -> tuple[int | None, int | None]:
    """``bytes START-END/TOTAL`` (or ``bytes */TOTAL``) -> (START, TOTAL); None where absent."""
    m = re.match(r"bytes\s+(?:(\d+)-\d+|\*)/(\d+|\*)", header or "")
    if not m:
        return None, None
    start = int(m.group(1)) if m.group(1) is not None else None
    total = int(m.group(2)) if m.group(2) != "*" else None
    return start, total


def _open(url: str, offset: int, timeout: float) -> http.client.HTTPResponse:
    headers = {"User-Agent": USER_AGENT}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    return urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(BLOCK), b""):
            digest.update(block)
    return digest.hexdigest()


def download(url: str, dest: Path, sha256: str | None = None, progress: bool = True,
             timeout: float = 60.0) -> Path:
    """Fetch ``url`` into ``dest`` (resuming ``dest.part``); return ``dest``.

    Raises :class:`DownloadError` with one line (HTTP status, connection problem, a size
    that does not match, a wrong checksum); what arrived stays in ``.part`` for the next
    call, except after a checksum mismatch, where it is deleted.
    """
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = part_path(dest)
    have = part.stat().st_size if part.is_file() else 0
    try:
        resp = _open(url, have, timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # nothing left to send: .part may be complete already
            _, total = _total_from_range(exc.headers.get("Content-Range"))
            if total == have:
                return _finish(url, part, dest, sha256)
            part.unlink()
            return download(url, dest, sha256, progress, timeout)
        raise DownloadError(url, f"HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise DownloadError(url, f"cannot connect ({reason})") from None

    with resp:
        total: int | None
        if resp.status == 206:
            start, total = _total_from_range(resp.headers.get("Content-Range"))
            if start != have:
                raise DownloadError(url, f"server resumed at byte {start}, expected {have}")
            mode = "ab"
        else:
            if have:
                log.warning("%s: the server does not resume downloads; starting again", url)
            have, mode = 0, "wb"
            length = resp.headers.get("Content-Length")
            total = int(length) if length is not None else None
        _stream(url, resp, part, mode, have, total, progress)
    got = part.stat().st_size
    if total is not None and got != total:
        raise DownloadError(url, f"incomplete: {got} of {total} bytes arrived; run the command again to resume")
    return _finish(url, part, dest, sha256)


def _stream(url: str, resp: http.client.HTTPResponse, part: Path, mode: str, have: int, total: int | None,
            progress: bool) -> None:
    from tqdm import tqdm

    with part.open(mode) as out, tqdm(total=total, initial=have, unit="B", unit_scale=True, unit_divisor=1024,
                                      desc=part.name.removesuffix(".part"), disable=not progress,
                                      leave=False) as bar:
        try:
            for block in iter(lambda: resp.read(BLOCK), b""):
                out.write(block)
                bar.update(len(block))
        except (OSError, http.client.HTTPException) as exc:
            out.flush()
            raise DownloadError(url, f"interrupted after {part.stat().st_size} bytes ({exc.__class__.__name__}); "
                                     "run the command again to resume") from None


def _finish(url: str, part: Path, dest: Path, sha256: str | None) -> Path:
    if sha256 is not None:
        got = sha256_of(part)
        if got != sha256.lower():
            part.unlink()
            raise DownloadError(url, f"SHA-256 {got} does not match the catalogue's {sha256}; deleted the download")
    part.replace(dest)
    return dest
