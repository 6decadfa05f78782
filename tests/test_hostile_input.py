"""Hostile input through ``semslam run`` (issue 13, 5): every case ends in one line naming
the file and the problem (exit 2, no traceback), or, where the run can go on, in a warning
and a count in ``stats.json``.

All runs are sequential (deterministic) on one 10-frame, 320x240 render of two people
walking, rendered once for the module; each test edits a copy of it.
"""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.cli.main import main
from semslam.core import registry
from semslam.core.types import LabelMap
from semslam.semantics.ground_truth import GroundTruthSegmenter

FRAMES = 10
W, H = 320, 240
TIFF_RAW = [cv2.IMWRITE_TIFF_COMPRESSION, 1]  # float TIFFs written as they are


@dataclass
class Outcome:
    rc: int
    err: str
    stats: dict | None
    out: Path

    @property
    def error_line(self) -> str:
        """The one ``error:`` line of a refused run (and that there is exactly one)."""
        assert "Traceback" not in self.err
        lines = [line for line in self.err.splitlines() if line.startswith("error:")]
        assert len(lines) == 1, self.err
        return lines[0]


def run(seq: Path, capsys: pytest.CaptureFixture[str], *extra: str, preset: str = "orb",
        sequential: bool = True, maps: bool = False) -> Outcome:
    """``semslam run SEQ`` in this process (without the preset's maps unless ``maps``);
    stats.json when it exits 0."""
    out = seq.parent / f"{seq.name}_out"
    capsys.readouterr()
    rc = main(["run", str(seq), "--out", str(out), "--quiet", "--no-report", "--preset", preset,
               *([] if maps else ["--map", "none"]), *(["--sequential"] if sequential else []), *extra])
    err = capsys.readouterr().err
    stats = json.loads((out / "stats.json").read_text()) if rc == 0 else None
    return Outcome(rc, err, stats, out)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES["walking_xyz"].replace(frames=FRAMES, width=W, height=H),
                           tmp_path_factory.mktemp("hostile") / "walking")


@pytest.fixture()
def seq(base: Path, tmp_path: Path) -> Path:
    """A copy of the render to spoil."""
    return Path(shutil.copytree(base, tmp_path / "seq"))


@pytest.fixture(scope="module")
def reference(base: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """The untouched render's trajectory.txt (orb, sequential) and the map it saved."""
    out = tmp_path_factory.mktemp("reference")
    assert main(["run", str(base), "--out", str(out), "--quiet", "--no-report", "--map", "none", "--preset", "orb",
                 "--sequential", "--save-map", str(out / "map.npz")]) == 0
    return (out / "trajectory.txt").read_text(), out / "map.npz"


def poses(out: Path) -> int:
    """Poses in a run's trajectory.txt (its header is a comment)."""
    return sum(1 for line in (out / "trajectory.txt").read_text().splitlines() if line and not line.startswith("#"))


def images(seq: Path, kind: str = "rgb") -> list[Path]:
    return sorted((seq / kind).glob("*.png"))


def list_lines(path: Path) -> tuple[list[str], list[str]]:
    """A list file's comment lines and data lines."""
    lines = path.read_text().splitlines()
    return [x for x in lines if x.startswith("#")], [x for x in lines if not x.startswith("#")]


# --- frames that cannot be tracked: the run goes on, counted ----------------------------

BLANK = {
    "black": np.zeros((H, W, 3), np.uint8),
    "white": np.full((H, W, 3), 255, np.uint8),
    "featureless": np.repeat(np.tile(np.linspace(0, 255, W).astype(np.uint8), (H, 1))[..., None], 3, axis=2),
}


@pytest.mark.parametrize("coast", [False, True], ids=["orb", "blur_coast"])
@pytest.mark.parametrize("kind", sorted(BLANK))
def test_blank_frames_are_lost_counted_and_warned(kind: str, coast: bool, seq: Path, capsys: pytest.CaptureFixture[str],
                                                  caplog: pytest.LogCaptureFixture) -> None:
    """Also with ``default``'s blur coasting: a blank frame is "blurred" (no sharpness at all),
    but nothing in it holds a pose, so it is lost, not coasted."""
    spoiled = images(seq)[3:7]
    for p in spoiled:
        cv2.imwrite(str(p), BLANK[kind])
    extra = ("--set", "slam.blur_coast_sharp_ratio=0.6") if coast else ()
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys, *extra)
    assert r.rc == 0 and r.stats is not None
    assert r.stats["frames"] == FRAMES and r.stats["frames_featureless"] == 4
    assert r.stats["tracked_frames"] == FRAMES - 4 and r.stats["lost_frames"] == 4  # relocalised after them
    assert poses(r.out) == FRAMES - 4
    assert f"frame 3 ({spoiled[0]})" in caplog.text and "frames_featureless" in caplog.text
    assert r.stats["coasted_frames"] == 0


def test_blank_frames_with_a_learned_detector(seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``sdf`` (monocular; FPFDCNN finds "keypoints" even on black): blank frames are told by
    their grey levels, not by the keypoint count."""
    pytest.importorskip("torch")
    for p in images(seq)[3:7]:
        cv2.imwrite(str(p), BLANK["black"])
    r = run(seq, capsys, preset="sdf_paper")
    assert r.rc == 0 and r.stats is not None
    assert r.stats["frames_featureless"] == 4 and r.stats["tracked_frames"] <= FRAMES - 4


def test_all_black_sequence_never_initialises(seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for p in images(seq):
        cv2.imwrite(str(p), BLANK["black"])
    r = run(seq, capsys, preset="default")
    assert r.rc == 0 and r.stats is not None
    assert r.stats["uninitialized_frames"] == FRAMES and r.stats["frames_featureless"] == FRAMES
    assert "ate" not in r.stats and poses(r.out) == 0


def _float_depth(seq: Path) -> None:
    """Depth as 32-bit float TIFFs (metres) holding only NaN, inf and negative values."""
    comments, lines = list_lines(seq / "depth.txt")
    bad = np.full((H, W), np.nan, np.float32)
    bad[::3], bad[1::3] = np.inf, -1.0
    new = []
    for line in lines:
        stamp, name = line.split()
        tiff = name.replace(".png", ".tiff")
        assert cv2.imwrite(str(seq / tiff), bad, TIFF_RAW)
        new.append(f"{stamp} {tiff}")
    (seq / "depth.txt").write_text("\n".join(comments + new) + "\n")


@pytest.mark.parametrize("kind", ["zero", "65535", "nan_inf_float"])
def test_depth_without_measurements(kind: str, seq: Path, capsys: pytest.CaptureFixture[str],
                                    caplog: pytest.LogCaptureFixture) -> None:
    if kind == "nan_inf_float":
        _float_depth(seq)
    else:
        for p in images(seq, "depth"):
            cv2.imwrite(str(p), np.full((H, W), 0 if kind == "zero" else 65535, np.uint16))
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys)
    assert r.rc == 0 and r.stats is not None
    # RGB-D initialisation needs depth: no frame is tracked, every one is counted.
    assert r.stats["frames_without_depth"] == FRAMES and r.stats["uninitialized_frames"] == FRAMES
    assert "frame 0 (" in caplog.text and "frames_without_depth" in caplog.text


def _person_everywhere(seq: Path, frames: range) -> None:
    names = json.loads((seq / "semantic" / "labels.json").read_text())
    person = next(int(i) for i, n in names.items() if n == "person")
    for p in sorted((seq / "semantic").glob("*.png"))[frames.start:frames.stop]:
        cv2.imwrite(str(p), np.full((H, W), person, np.uint8))


@pytest.mark.parametrize("preset", ["default", "ddl", "stdc"])
def test_person_filling_the_view(preset: str, seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Frames 4-6 entirely person (exact labels, each preset's own dynamics pipeline)."""
    _person_everywhere(seq, range(4, 7))
    r = run(seq, capsys, "--set", "semantics.backend=ground_truth", preset=preset)
    assert r.rc == 0 and r.stats is not None
    assert r.stats["frames_all_dynamic"] >= 3  # frames 4-6 (and a later one given their mask, warped)
    assert r.stats["tracked_frames"] >= 4 and r.stats["frames"] == FRAMES


def test_person_filling_the_view_real_segmenter(seq: Path, capsys: pytest.CaptureFixture[str], shared_data: Path,
                                                caplog: pytest.LogCaptureFixture) -> None:
    """A real TUM photo: a person's torso filling the view at 0.8 m, through mediapipe + SRM."""
    pytest.importorskip("mediapipe")
    photo = cv2.imread(str(shared_data / "images_people" / "fr3_walking_person.png"))
    torso = cv2.resize(photo[120:340, 70:230], (W, H), interpolation=cv2.INTER_LINEAR)
    for p in images(seq)[4:7]:
        cv2.imwrite(str(p), torso)
    for p in images(seq, "depth")[4:7]:
        cv2.imwrite(str(p), np.full((H, W), 4000, np.uint16))
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys, preset="default")
    assert r.rc == 0 and r.stats is not None
    assert r.stats["frames_all_dynamic"] >= 3 and "frames_all_dynamic" in caplog.text


# --- segmentation masks of the wrong size ------------------------------------------------

@pytest.mark.parametrize("sequential", [True, False], ids=["sequential", "threaded"])
def test_label_file_of_wrong_size_is_an_error(sequential: bool, seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Labels read from files: a file of another size belongs to another image; resizing it
    could put a person's label on the wall, so it is refused. From frame 2 on (labels made at
    another resolution): threaded, with ``schedule: latest``, a frame whose segmentation was
    skipped or overtaken never reads its file, so which one is named depends on timing."""
    labels = sorted((seq / "semantic").glob("*.png"))[2:]
    for label in labels:
        cv2.imwrite(str(label), cv2.imread(str(label), cv2.IMREAD_UNCHANGED)[:100, :100])
    r = run(seq, capsys, "--set", "semantics.backend=ground_truth", preset="default", sequential=sequential)
    assert r.rc == 2
    named = labels[0] if sequential else next(p for p in labels if f"error: {p}:" in r.error_line)
    assert r.error_line == f"error: {named}: labels are 100x100 but the image is {W}x{H}"


class HalfSizeSegmenter(GroundTruthSegmenter):
    """The exact labels at half resolution, as a network answering at its input size would."""

    def segment(self, rgb: np.ndarray, frame=None) -> LabelMap:  # noqa: ANN001 - the protocol's signature
        full = super().segment(rgb, frame)
        half = cv2.resize(full.labels, (W // 2, H // 2), interpolation=cv2.INTER_NEAREST)
        return LabelMap(half, full.names)


def create_half_size_segmenter(cfg: object) -> HalfSizeSegmenter:
    return HalfSizeSegmenter(cfg)  # type: ignore[arg-type]


def test_backend_labels_of_another_size_are_resized(base: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    caplog: pytest.LogCaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A backend answering at its own resolution: resized to the frame (nearest), warned once,
    counted; the masks match the full-size labels' to the half-resolution edge."""
    monkeypatch.setitem(registry.PLUGINS["segmenter"], "half_size", f"{__name__}:create_half_size_segmenter")
    seq = Path(shutil.copytree(base, tmp_path / "half"))
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys, "--set", "semantics.backend=half_size", preset="default")
    exact = run(Path(shutil.copytree(base, tmp_path / "exact")), capsys, "--set", "semantics.backend=ground_truth",
                preset="default")
    assert r.rc == 0 and r.stats is not None and exact.stats is not None
    assert r.stats["resized_label_maps"] == r.stats["segmented_frames"] >= FRAMES // 2
    assert exact.stats["resized_label_maps"] == 0
    assert caplog.text.count(f"returned {W // 2}x{H // 2} labels for a {W}x{H} image") == 1
    assert r.stats["dynamic_ratio_mean"] == pytest.approx(exact.stats["dynamic_ratio_mean"], abs=0.01)
    assert r.stats["tracked_frames"] == FRAMES


# --- list files ---------------------------------------------------------------------------

@pytest.mark.parametrize("preset", ["orb", "default", "f2kf"])
def test_sequence_of_one_frame(preset: str, seq: Path, capsys: pytest.CaptureFixture[str],
                               caplog: pytest.LogCaptureFixture) -> None:
    """``default`` builds its maps too: one keyframe fills the octree and the cloud, and is
    too little for a mesh (a voxel needs 2 keyframes), which is a warning, not a failure."""
    for name in ("rgb.txt", "depth.txt"):
        comments, lines = list_lines(seq / name)
        (seq / name).write_text("\n".join(comments + lines[:1]) + "\n")
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys, preset=preset, maps=preset == "default")
    assert r.rc == 0 and r.stats is not None
    assert r.stats["frames"] == r.stats["tracked_frames"] == 1
    assert poses(r.out) == 1
    assert "ate" not in r.stats  # one pose cannot be aligned; not an error
    if preset == "default":
        assert (r.out / "map" / "octree.bt").is_file() and not (r.out / "map" / "mesh.ply").exists()
        assert "no mesh.ply written" in caplog.text


@pytest.mark.parametrize("name", ["rgb.txt", "depth.txt"])
def test_duplicate_timestamps(name: str, seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    comments, lines = list_lines(seq / name)
    stamp = lines[3].split()[0]
    lines[4] = f"{stamp} {lines[4].split()[1]}"
    (seq / name).write_text("\n".join(comments + lines) + "\n")
    r = run(seq, capsys)
    n = len(comments) + 5
    assert r.rc == 2
    assert r.error_line.startswith(f"error: {seq / name}: line {n}: duplicate timestamp {stamp} (line {n - 1} has")


@pytest.mark.parametrize("entry", ["../elsewhere/x.png", "rgb/../../elsewhere/x.png", "/etc/hostname"])
def test_list_pointing_outside_the_folder_is_refused(entry: str, seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    comments, lines = list_lines(seq / "rgb.txt")
    lines[2] = f"{lines[2].split()[0]} {entry}"
    (seq / "rgb.txt").write_text("\n".join(comments + lines) + "\n")
    r = run(seq, capsys)
    assert r.rc == 2
    assert r.error_line == (f"error: {seq / 'rgb.txt'}: line {len(comments) + 3}: {entry!r} points outside the "
                            "sequence folder; list files must name files inside it, by relative paths")


def test_symlinked_image_folder_is_inside(seq: Path, reference: tuple[str, Path],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """The check is on the listed names: a dataset whose rgb/ is a link to another disk runs."""
    moved = seq.parent / "other_disk_rgb"
    (seq / "rgb").rename(moved)
    (seq / "rgb").symlink_to(moved)
    r = run(seq, capsys)
    assert r.rc == 0 and (r.out / "trajectory.txt").read_text() == reference[0]


def test_broken_groundtruth_is_a_warning(seq: Path, capsys: pytest.CaptureFixture[str],
                                         caplog: pytest.LogCaptureFixture) -> None:
    with (seq / "groundtruth.txt").open("a") as f:
        f.write("1341846650.0 1 2 three 0 0 0 1\n")
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys)
    assert r.rc == 0 and r.stats is not None
    assert r.stats["tracked_frames"] == FRAMES and "ate" not in r.stats
    assert "groundtruth.txt: line" in caplog.text and "'three' is not a number" in caplog.text
    assert "without evaluation" in caplog.text


# --- image files ---------------------------------------------------------------------------

def _write_variant(path: Path, kind: str) -> None:
    from PIL import Image

    bgr = cv2.imread(str(path))
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    if kind == "float-tiff":  # rgb.txt is rewritten to name these; uncompressed (OpenCV's default, LogLuv, is lossy)
        assert cv2.imwrite(str(path.with_suffix(".tiff")), bgr.astype(np.float32) / 255.0, TIFF_RAW)
    elif kind == "16-bit":
        cv2.imwrite(str(path), bgr.astype(np.uint16) * 257)
    elif kind == "grey":
        cv2.imwrite(str(path), grey)
    elif kind == "rgba":
        cv2.imwrite(str(path), cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA))
    else:
        Image.fromarray(grey).convert("LA").save(path)


@pytest.mark.parametrize("kind", ["16-bit", "grey", "rgba", "grey+alpha", "float-tiff"])
def test_png_variants_decode_to_the_same_run(kind: str, seq: Path, reference: tuple[str, Path],
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Converted losslessly, each variant decodes to the image ORB tracking saw (it tracks
    grey): the sequential run's trajectory is byte-identical to the original's."""
    for p in images(seq):
        _write_variant(p, kind)
    if kind == "float-tiff":
        (seq / "rgb.txt").write_text((seq / "rgb.txt").read_text().replace(".png", ".tiff"))
    r = run(seq, capsys)
    assert r.rc == 0 and (r.out / "trajectory.txt").read_text() == reference[0]


@pytest.mark.parametrize("kind", ["rgb", "depth", "depth of another size", "frame of another size"])
def test_unusable_image_inside_is_skipped_and_counted(kind: str, seq: Path, capsys: pytest.CaptureFixture[str],
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """A truncated image, a depth image that does not fit its colour image, a frame that
    does not fit the camera (the first image's size): skipped, warned, counted."""
    p = images(seq, "depth" if kind.startswith("depth") else "rgb")[5]
    if kind == "depth of another size":
        cv2.imwrite(str(p), np.full((H // 2, W // 2), 10000, np.uint16))
        problem = f"depth is {W // 2}x{H // 2} but rgb is {W}x{H}"
    elif kind == "frame of another size":
        cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p)), (W // 2, H // 2)))
        cv2.imwrite(str(images(seq, "depth")[5]), np.full((H // 2, W // 2), 10000, np.uint16))
        problem = f"image is {W // 2}x{H // 2} but the sequence's first image is {W}x{H}"
    else:
        p.write_bytes(p.read_bytes()[:1000])
        problem = "truncated PNG (no IEND chunk at the end)"
    with caplog.at_level(logging.WARNING):
        r = run(seq, capsys)
    assert r.rc == 0 and r.stats is not None
    assert r.stats["skipped_frames"] == 1 and r.stats["frames"] == FRAMES - 1
    assert r.stats["skipped"] == [f"{p}: {problem}"]
    assert f"skipping frame 5: {p}: {problem}" in caplog.text


def test_every_png_truncated_is_an_error(seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for p in images(seq):
        p.write_bytes(p.read_bytes()[:1000])
    r = run(seq, capsys)
    assert r.rc == 2
    assert r.error_line == f"error: {images(seq)[0]}: first frame unreadable: truncated PNG (no IEND chunk at the end)"


@pytest.mark.parametrize("text,problem", [
    ("267.7 269.6 160.05", "expected 4 numbers (fx fy cx cy) or 9 (with k1 k2 p1 p2 k3), got 3"),
    ("267.7 269.6 160.05 123.8 0.1 0 0", "expected 4 numbers (fx fy cx cy) or 9 (with k1 k2 p1 p2 k3), got 7"),
    ("267.7 nan 160.05 123.8", "every value must be a finite number, got 267.7 nan 160.05 123.8"),
])
def test_calib_with_wrong_values(text: str, problem: str, seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (seq / "calib.txt").write_text(text + "\n")
    r = run(seq, capsys)
    assert r.rc == 2 and r.error_line == f"error: {seq / 'calib.txt'}: {problem}"


# --- map files (--load-map) ----------------------------------------------------------------

def _spoil_map(good: Path, bad: Path, kind: str) -> None:
    data = good.read_bytes()
    if kind == "truncated":
        bad.write_bytes(data[: len(data) // 2])
    elif kind == "damaged":
        flipped = bytearray(data)
        for k in range(len(data) // 3, len(data) // 3 + 16):  # inside the first arrays' compressed data
            flipped[k] ^= 0xFF
        bad.write_bytes(bytes(flipped))
    elif kind == "other_version":
        with np.load(good) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays["meta"]))
        meta["format"] = "semslam-map-0"
        arrays["meta"] = np.array(json.dumps(meta))
        with open(bad, "wb") as f:
            np.savez_compressed(f, **arrays)
    elif kind == "rewritten":  # a point moved, written back as a valid zip (new CRCs): the checksum catches it
        with np.load(good) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["pt_pos"] = arrays["pt_pos"] + np.array([0.01, 0.0, 0.0])
        with open(bad, "wb") as f:
            np.savez_compressed(f, **arrays)
    elif kind == "npz_not_a_map":
        with open(bad, "wb") as f:
            np.savez(f, weights=np.zeros(3))
    elif kind == "png":
        cv2.imwrite(str(bad.with_suffix(".png")), np.zeros((4, 4), np.uint8))
        bad.with_suffix(".png").rename(bad)
    else:
        with open(bad, "wb") as f:
            np.savez(f, meta=np.array("not json {"))


MAP_ERRORS = {
    "truncated": "truncated or damaged map (File is not a zip file)",
    "damaged": "truncated or damaged map (",
    "other_version": "unsupported map format 'semslam-map-0' (written by semslam ",
    "rewritten": "damaged map: the arrays' SHA-256 ",
    "npz_not_a_map": "not a semslam map (no 'meta' entry; maps are written by --save-map)",
    "png": "not a semslam map (not the .npz archive --save-map writes)",
    "bad_meta": "truncated or damaged map (",
}


@pytest.mark.parametrize("kind", sorted(MAP_ERRORS))
def test_bad_map_file(kind: str, reference: tuple[str, Path], tmp_path: Path, base: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "map.npz"
    _spoil_map(reference[1], bad, kind)
    r = run(base, capsys, "--load-map", str(bad))
    assert r.rc == 2 and r.error_line.startswith(f"error: {bad}: {MAP_ERRORS[kind]}")


def test_map_of_a_run_that_never_initialised(seq: Path, base: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for p in images(seq):
        cv2.imwrite(str(p), BLANK["black"])
    empty = seq.parent / "empty.npz"
    assert run(seq, capsys, "--save-map", str(empty)).rc == 0
    r = run(base, capsys, "--load-map", str(empty))
    assert r.rc == 2
    assert r.error_line == f"error: {empty}: the map holds no keyframes (its run never initialised): nothing to relocalise in"


def test_good_map_still_loads(reference: tuple[str, Path], seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    r = run(seq, capsys, "--load-map", str(reference[1]))
    assert r.rc == 0 and r.stats is not None and r.stats["tracked_frames"] == FRAMES
    assert r.stats["relocalisations"] >= 1  # it started lost in the loaded map and found itself
