"""Datasets by name (semslam/datasets, `semslam dataset`): download with resume, verification,
extraction, and `semslam run tum/...` finding the result.

No network: a local HTTP server (Python's http.server with a small Range-capable handler)
serves archives the test builds in the official layouts from a short synthetic render, and
the catalogue's mirror setting points at it.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tarfile
import threading
import zipfile
from collections.abc import Iterator
from dataclasses import replace
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from semslam.cli.main import main
from semslam.datasets import CATALOGUE, DownloadError, get, lookup, resolve
from semslam.datasets.download import part_path
from semslam.errors import DataError
from semslam.io.calibration import KNOWN_CAMERAS, camera_from_folder_name
from semslam.io.sequence import TumRgbdSequence, open_sequence

N_FRAMES = 24
TUM_NAME = "tum/fr3_walking_xyz"
TUM_FOLDER = "rgbd_dataset_freiburg3_walking_xyz"
SEQUENCE_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt")


# ---------------------------------------------------------------------------- a local server
class RangeHandler(SimpleHTTPRequestHandler):
    """Serves a folder, answering ``Range: bytes=N-`` with 206 as real servers do.

    Server attributes steer it: ``ranges`` records each request's Range header,
    ``ignore_range`` answers 200 with the whole file, ``cut_after`` sends only that many
    bytes of the body and closes the connection (a dropped download).
    """

    def log_message(self, *args: Any) -> None:
        pass

    def send_head(self):  # type: ignore[no-untyped-def]
        server: Any = self.server
        rng = self.headers.get("Range")
        server.ranges.append(rng)
        path = self.translate_path(self.path)
        m = re.fullmatch(r"bytes=(\d+)-", rng or "")
        if m is None or server.ignore_range or not os.path.isfile(path):
            return super().send_head()
        size, start = os.path.getsize(path), int(m.group(1))
        if start >= size:
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{size}")
            self.end_headers()
            return None
        f = open(path, "rb")  # noqa: SIM115 - closed by do_GET after copyfile
        f.seek(start)
        self.send_response(206)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Range", f"bytes {start}-{size - 1}/{size}")
        self.send_header("Content-Length", str(size - start))
        self.end_headers()
        return f

    def copyfile(self, source, outputfile) -> None:  # type: ignore[no-untyped-def]
        cut = getattr(self.server, "cut_after", None)
        if cut is None:
            return super().copyfile(source, outputfile)
        outputfile.write(source.read(cut))
        self.close_connection = True


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[Any]:
    root = tmp_path / "mirror"
    root.mkdir()
    httpd: Any = ThreadingHTTPServer(("127.0.0.1", 0), partial(RangeHandler, directory=str(root)))
    httpd.ranges, httpd.ignore_range, httpd.cut_after, httpd.root = [], False, None, root
    httpd.url = f"http://127.0.0.1:{httpd.server_address[1]}"
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield httpd
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture()
def env(tmp_path: Path, server: Any, monkeypatch: pytest.MonkeyPatch) -> Path:
    """SEMSLAM_DATA in tmp and the mirror at the local server; returns the data folder."""
    data = tmp_path / "data"
    monkeypatch.setenv("SEMSLAM_DATA", str(data))
    monkeypatch.setenv("SEMSLAM_DATASET_MIRROR", server.url)
    return data


# ---------------------------------------------------------------------------- archives in the official layouts
@pytest.fixture(scope="module")
def render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short walking_xyz render (640x480, freiburg3 intrinsics as the synthetic camera)."""
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["walking_xyz"].replace(frames=N_FRAMES), tmp_path_factory.mktemp("ds") / "render")


def _official_files(render: Path) -> list[Path]:
    """What a TUM archive holds: the images and the three lists (no calib.txt: the folder name
    must give the calibration)."""
    return [render / n for n in SEQUENCE_FILES] + sorted((render / "rgb").iterdir()) + sorted((render / "depth").iterdir())


@pytest.fixture(scope="module")
def tum_archive(render: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("archives") / f"{TUM_FOLDER}.tgz"
    with tarfile.open(out, "w:gz", compresslevel=1) as tf:
        for f in _official_files(render):
            tf.add(f, arcname=f"{TUM_FOLDER}/{f.relative_to(render)}")
    return out


def _serve(server: Any, archive: Path, name: str | None = None) -> Path:
    target = server.root / (name or archive.name)
    shutil.copyfile(archive, target)
    return target


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _assert_same_sequence(folder: Path, render: Path) -> None:
    for f in _official_files(render):
        assert _sha(folder / f.relative_to(render)) == _sha(f), f


def _no_leftovers(data: Path) -> list[str]:
    """Sequence or temporary folders in the data folder (downloads aside)."""
    return sorted(p.name for p in data.iterdir() if p.name != ".downloads") if data.exists() else []


# ---------------------------------------------------------------------------- tests
def test_catalogue_folders_keep_the_calibration() -> None:
    """Every sequence extracts to a folder whose name io/calibration.py recognises."""
    counts = {"tum": 0, "bonn": 0, "icl": 0}
    for name, entry in CATALOGUE.items():
        counts[entry.family] += 1
        cam = camera_from_folder_name(Path(entry.folder))
        assert cam is not None, name
        key = f"freiburg{name[len('tum/fr')]}" if entry.family == "tum" else entry.family
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == KNOWN_CAMERAS[key][:4], name
        assert entry.url.startswith(("https://cvg.cit.tum.de/rgbd/dataset/freiburg",
                                     "https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/",
                                     "https://www.doc.ic.ac.uk/~ahanda/")), entry.url
    assert counts == {"tum": 47, "bonn": 26, "icl": 8}
    assert lookup(TUM_NAME).url == ("https://cvg.cit.tum.de/rgbd/dataset/freiburg3/"
                                    "rgbd_dataset_freiburg3_walking_xyz.tgz")
    with pytest.raises(DataError, match="did you mean tum/fr3_walking_xyz"):
        lookup("tum/fr3_walkingxyz")


def test_get_then_run_by_name(env: Path, server: Any, render: Path, tum_archive: Path, tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """Not downloaded: one line naming the command. Then `dataset get` fetches, verifies and
    extracts it byte for byte, and `semslam run tum/fr3_walking_xyz` runs on it."""
    out = tmp_path / "run"
    assert main(["run", TUM_NAME, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"run `semslam dataset get {TUM_NAME}`" in err

    _serve(server, tum_archive)
    assert main(["dataset", "get", TUM_NAME, "--quiet"]) == 0
    assert f"{N_FRAMES} frames, with ground truth" in capsys.readouterr().out
    folder = env / TUM_FOLDER
    _assert_same_sequence(folder, render)
    assert not (env / ".downloads" / tum_archive.name).exists()  # archive removed after extraction
    assert server.ranges == [None]

    seq = open_sequence(TUM_NAME)  # the Python-level opener resolves names too
    assert isinstance(seq, TumRgbdSequence) and seq.root == folder and len(seq) == N_FRAMES
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == KNOWN_CAMERAS["freiburg3"][:4]
    assert main(["dataset", "get", TUM_NAME, "--quiet"]) == 0 and server.ranges == [None]  # present: no download

    assert main(["run", TUM_NAME, "--out", str(out), "--quiet", "--preset", "orb", "--sequential", "--no-report"]) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["sequence"] == str(folder) and stats["frames"] == N_FRAMES
    assert stats["ate"]["rmse"] < 0.05  # tracked against the archive's ground truth


def test_interrupted_download_resumes_with_range(env: Path, server: Any, render: Path, tum_archive: Path) -> None:
    """A dropped connection keeps the bytes in .part and says to run again; the next call asks
    for the rest with Range and the result is the archive's exact content."""
    _serve(server, tum_archive)
    size = tum_archive.stat().st_size
    server.cut_after = size // 3
    with pytest.raises(DownloadError, match=r"incomplete: \d+ of \d+ bytes arrived; run the command again to resume"):
        get(TUM_NAME, progress=False)
    part = part_path(env / ".downloads" / tum_archive.name)
    assert part.stat().st_size == size // 3 and _no_leftovers(env) == []

    server.cut_after = None
    folder = get(TUM_NAME, progress=False, keep_archive=True)
    assert server.ranges == [None, f"bytes={size // 3}-"]
    assert _sha(env / ".downloads" / tum_archive.name) == _sha(tum_archive) and not part.exists()
    _assert_same_sequence(folder, render)


def test_server_without_range_starts_again(env: Path, server: Any, render: Path, tum_archive: Path) -> None:
    _serve(server, tum_archive)
    part = part_path(env / ".downloads" / tum_archive.name)
    part.parent.mkdir(parents=True)
    part.write_bytes(b"stale bytes from another file")
    server.ignore_range = True
    folder = get(TUM_NAME, progress=False)
    assert server.ranges == ["bytes=29-"]  # asked to resume, got 200 and the whole file
    _assert_same_sequence(folder, render)


def test_corrupt_archive_leaves_nothing(env: Path, server: Any, render: Path, tum_archive: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Right size, damaged content: one error line naming the archive, no folder (not even a
    half-extracted temporary one), and the archive deleted so the next get fetches it afresh."""
    data = bytearray(tum_archive.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 4096] = bytes(4096)
    (server.root / tum_archive.name).write_bytes(bytes(data))
    assert main(["dataset", "get", TUM_NAME, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"{tum_archive.name}: corrupt or truncated tgz archive" in err and "run the command again" in err
    assert _no_leftovers(env) == [] and list((env / ".downloads").iterdir()) == []
    with pytest.raises(DataError, match="not downloaded yet"):
        resolve(TUM_NAME)

    _serve(server, tum_archive)  # the mirror fixed: the same command now works
    _assert_same_sequence(get(TUM_NAME, progress=False), render)


def test_archive_without_ground_truth_is_refused(env: Path, server: Any, render: Path, tmp_path: Path) -> None:
    archive = tmp_path / f"{TUM_FOLDER}.tgz"
    with tarfile.open(archive, "w:gz", compresslevel=1) as tf:
        for f in _official_files(render)[:2]:  # rgb.txt and depth.txt only
            tf.add(f, arcname=f"{TUM_FOLDER}/{f.name}")
    _serve(server, archive)
    with pytest.raises(DataError, match=r"archive is incomplete: no groundtruth.txt in rgbd_dataset_freiburg3_walking_xyz/"):
        get(TUM_NAME, progress=False)
    assert _no_leftovers(env) == []


def test_checksum_is_verified(env: Path, server: Any, tum_archive: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _serve(server, tum_archive)
    entry = CATALOGUE[TUM_NAME]
    monkeypatch.setitem(CATALOGUE, TUM_NAME, replace(entry, sha256="0" * 64))
    with pytest.raises(DownloadError, match="does not match the catalogue's 0000"):
        get(TUM_NAME, progress=False)
    assert list((env / ".downloads").iterdir()) == []  # a wrong file is not kept for resuming
    monkeypatch.setitem(CATALOGUE, TUM_NAME, replace(entry, sha256=_sha(tum_archive)))
    assert get(TUM_NAME, progress=False).is_dir()


def test_bonn_zip_and_icl_flat_tarball(env: Path, server: Any, render: Path, tmp_path: Path) -> None:
    """Bonn's zip (a folder inside) and ICL-NUIM's TUM-format tarball (files at the top level,
    an associations file and *.gt.freiburg) extract to folders the reader and calibration know."""
    bonn = tmp_path / "rgbd_bonn_balloon.zip"
    with zipfile.ZipFile(bonn, "w") as zf:
        for f in _official_files(render):
            zf.write(f, f"rgbd_bonn_balloon/{f.relative_to(render)}")
    _serve(server, bonn)
    seq = open_sequence(get("bonn/balloon", progress=False))
    assert seq.root.name == "rgbd_bonn_balloon" and seq.camera.fx == KNOWN_CAMERAS["bonn"][0]
    flat = tmp_path / "rgbd_bonn_balloon2.zip"  # repacked without its folder: found at the top level
    with zipfile.ZipFile(flat, "w") as zf:
        for f in _official_files(render):
            zf.write(f, str(f.relative_to(render)))
    _serve(server, flat)
    assert len(open_sequence(get("bonn/balloon2", progress=False))) == N_FRAMES
    assert _no_leftovers(env) == ["rgbd_bonn_balloon", "rgbd_bonn_balloon2"]

    icl = tmp_path / "living_room_traj0_frei_png.tar.gz"
    rgb, depth = sorted((render / "rgb").iterdir())[:5], sorted((render / "depth").iterdir())[:5]
    lines = [f"{i} depth/{i}.png {i} rgb/{i}.png" for i in range(5)]
    gt = [f"{i} 0 0 {0.01 * i} 0 0 0 1" for i in range(5)]
    (tmp_path / "associations.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "livingRoom0.gt.freiburg").write_text("\n".join(gt) + "\n")
    with tarfile.open(icl, "w:gz") as tf:
        for i, (r, d) in enumerate(zip(rgb, depth)):
            tf.add(r, arcname=f"rgb/{i}.png")
            tf.add(d, arcname=f"depth/{i}.png")
        tf.add(tmp_path / "associations.txt", arcname="associations.txt")
        tf.add(tmp_path / "livingRoom0.gt.freiburg", arcname="livingRoom0.gt.freiburg")
    _serve(server, icl)
    assert get("icl/lr_kt0", progress=False) == env / "living_room_traj0_frei_png"
    seq = open_sequence("icl/lr_kt0")
    assert len(seq) == 5 and seq.groundtruth_path is not None and seq.groundtruth_path.name == "livingRoom0.gt.freiburg"
    assert seq.root.name == "living_room_traj0_frei_png" and seq.camera.fx == KNOWN_CAMERAS["icl"][0]
