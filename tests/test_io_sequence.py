"""TUM RGB-D / image-folder readers, calibration precedence and every bad-input case."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.errors import ConfigError, DataError
from semslam.io.calibration import KNOWN_CAMERAS, resolve_camera
from semslam.io.sequence import ImageFolderSequence, TumRgbdSequence, open_sequence

from .conftest import write_tum_folder


def test_reads_tum_folder_and_associates(tum_folder: Path) -> None:
    seq = open_sequence(tum_folder)
    assert isinstance(seq, TumRgbdSequence)
    assert len(seq) == 5
    frame = seq.load(2)
    assert frame.rgb.shape == (48, 64, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth is not None and frame.depth.dtype == np.float32
    assert np.allclose(frame.depth, 2.0)  # 10000 / 5000
    assert frame.depth_path is not None and abs(float(frame.depth_path.stem) - frame.timestamp - 0.004) < 1e-6
    assert seq.groundtruth_path == tum_folder / "groundtruth.txt"


def test_rgb_written_as_bgr_is_read_back_as_rgb(tmp_path: Path) -> None:
    root = write_tum_folder(tmp_path / "seq", n=2)
    first = sorted((root / "rgb").iterdir())[0]
    img = np.zeros((48, 64, 3), np.uint8)
    img[..., 0] = 255  # blue in OpenCV's BGR
    cv2.imwrite(str(first), img)
    frame = open_sequence(root).load(0)
    assert frame.rgb[0, 0].tolist() == [0, 0, 255]


def test_association_drops_unmatched_and_respects_max_diff(tmp_path: Path) -> None:
    root = write_tum_folder(tmp_path / "seq", n=6, depth_offset=0.015)
    assert len(open_sequence(root)) == 6
    assert len(TumRgbdSequence(root, max_diff=0.02)) == 6
    with pytest.raises(DataError, match="no rgb/depth pairs within 0.01 s"):
        TumRgbdSequence(root, max_diff=0.01)


def test_associations_file_used_when_given(tum_folder: Path) -> None:
    rgb = [line.split() for line in (tum_folder / "rgb.txt").read_text().splitlines() if not line.startswith("#")]
    dep = [line.split() for line in (tum_folder / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    assoc = tum_folder / "assoc.txt"
    assoc.write_text("".join(f"{r[0]} {r[1]} {d[0]} {d[1]}\n" for r, d in list(zip(rgb, dep))[:3]))
    assert len(TumRgbdSequence(tum_folder, associations=assoc)) == 3


def test_calibration_precedence(tum_folder: Path, caplog: pytest.LogCaptureFixture) -> None:
    cam = resolve_camera(tum_folder)  # folder name says freiburg1
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == KNOWN_CAMERAS["freiburg1"][:4]
    assert cam.dist == KNOWN_CAMERAS["freiburg1"][4:]
    (tum_folder / "calib.txt").write_text("# fx fy cx cy\n500 501 320 240\n")
    assert resolve_camera(tum_folder).fx == 500.0
    cam = resolve_camera(tum_folder, "510,511,300,200,0.1,0,0,0,0")
    assert (cam.fx, cam.dist[0]) == (510.0, 0.1)
    plain = tum_folder.parent / "unnamed"
    plain.mkdir()
    with caplog.at_level(logging.WARNING):
        cam = resolve_camera(plain)
    assert (cam.fx, cam.cx) == (525.0, 319.5) and "Kinect defaults" in caplog.text
    for name, key in [("rgbd_dataset_freiburg2_desk", "freiburg2"), ("rgbd_dataset_freiburg3_walking_xyz", "freiburg3"),
                      ("rgbd_bonn_balloon", "bonn"), ("living_room_traj0_frei_png", "icl")]:
        (tum_folder.parent / name).mkdir()
        assert resolve_camera(tum_folder.parent / name).fx == KNOWN_CAMERAS[key][0]


@pytest.mark.parametrize("text", ["1,2,3", "a,b,c,d", "-1,1,1,1"])
def test_bad_camera_option(tum_folder: Path, text: str) -> None:
    with pytest.raises(ConfigError, match="--camera"):
        resolve_camera(tum_folder, text)


def test_bad_calib_file(tum_folder: Path) -> None:
    (tum_folder / "calib.txt").write_text("500 501\n")
    with pytest.raises(DataError, match="calib.txt"):
        resolve_camera(tum_folder)


# --- bad input: each names the file and the problem -----------------------------------


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="nowhere.*not found"):
        open_sequence(tmp_path / "nowhere")


def test_missing_rgb_txt(tum_folder: Path) -> None:
    (tum_folder / "rgb.txt").unlink()
    with pytest.raises(DataError, match=r"rgb.txt: file not found"):
        TumRgbdSequence(tum_folder)


def test_missing_depth_txt(tum_folder: Path) -> None:
    (tum_folder / "depth.txt").unlink()
    with pytest.raises(DataError, match=r"depth.txt: file not found"):
        TumRgbdSequence(tum_folder)


def test_non_monotonic_timestamps(tum_folder: Path) -> None:
    lines = (tum_folder / "rgb.txt").read_text().splitlines()
    lines[4], lines[5] = lines[5], lines[4]
    (tum_folder / "rgb.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"rgb.txt: line 6: .*timestamps must increase"):
        open_sequence(tum_folder)


def test_bad_list_line(tum_folder: Path) -> None:
    with (tum_folder / "depth.txt").open("a") as f:
        f.write("notanumber depth/x.png\n")
    with pytest.raises(DataError, match=r"depth.txt: line 9: timestamp 'notanumber'"):
        open_sequence(tum_folder)


def test_no_overlap(tmp_path: Path) -> None:
    root = write_tum_folder(tmp_path / "seq", depth_offset=100.0)
    with pytest.raises(DataError, match="no rgb/depth pairs"):
        open_sequence(root)


def test_eight_bit_depth(tum_folder: Path) -> None:
    first = sorted((tum_folder / "depth").iterdir())[0]
    cv2.imwrite(str(first), np.full((48, 64), 100, np.uint8))
    with pytest.raises(DataError, match=rf"{first.name}: depth image is 8-bit"):
        next(iter(open_sequence(tum_folder)))


def test_truncated_image_inside_sequence_is_skipped_and_counted(tum_folder: Path, caplog: pytest.LogCaptureFixture) -> None:
    third = sorted((tum_folder / "rgb").iterdir())[2]
    third.write_bytes(third.read_bytes()[:200])
    seq = open_sequence(tum_folder)
    with caplog.at_level(logging.WARNING):
        frames = list(seq)
    assert len(frames) == 4 and len(seq.skipped) == 1
    assert "truncated PNG" in seq.skipped[0][1] and third.name in seq.skipped[0][1]
    assert "skipping frame 2" in caplog.text


def test_unreadable_first_frame_is_an_error(tum_folder: Path) -> None:
    first = sorted((tum_folder / "rgb").iterdir())[0]
    first.write_bytes(b"this is not a png")
    with pytest.raises(DataError, match=rf"{first.name}: first frame unreadable: not a readable image"):
        list(open_sequence(tum_folder))


def test_too_many_unreadable_frames(tmp_path: Path) -> None:
    root = write_tum_folder(tmp_path / "seq", n=12)
    for p in sorted((root / "rgb").iterdir())[1:6]:
        p.write_bytes(b"")
    with pytest.raises(DataError, match="unreadable frames"):
        list(open_sequence(root))


def test_missing_listed_images(tmp_path: Path) -> None:
    root = write_tum_folder(tmp_path / "seq", n=12)
    gone = sorted((root / "rgb").iterdir())[3]
    gone.unlink()
    seq = open_sequence(root)
    assert len(seq) == 12  # the listed frames; the missing one is skipped when reached, by its name
    assert len(list(seq)) == 11 and seq.skipped == [(3, f"{gone}: file not found")]
    for p in sorted((root / "rgb").iterdir())[:6]:
        p.unlink()
    with pytest.raises(DataError, match="file not found, and 6 more listed images are missing"):
        open_sequence(root)


def test_depth_size_mismatch(tum_folder: Path) -> None:
    first = sorted((tum_folder / "depth").iterdir())[0]
    cv2.imwrite(str(first), np.full((10, 10), 5000, np.uint16))
    with pytest.raises(DataError, match="depth is 10x10 but rgb is 64x48"):
        next(iter(open_sequence(tum_folder)))


def test_not_a_folder(tum_folder: Path) -> None:
    with pytest.raises(DataError, match="not a folder"):
        open_sequence(tum_folder / "rgb.txt")


# --- image folders (monocular) -------------------------------------------------------


def test_image_folder_with_times(tmp_path: Path) -> None:
    folder = tmp_path / "mono"
    (folder / "image_0").mkdir(parents=True)
    for i in (0, 1, 2, 10):
        cv2.imwrite(str(folder / f"image_0/{i:06d}.png"), np.zeros((8, 8, 3), np.uint8))
    seq = open_sequence(folder)
    assert isinstance(seq, ImageFolderSequence) and len(seq) == 4 and not seq.has_depth
    assert np.allclose(np.diff(seq.timestamps), [1 / 30, 1 / 30, 1 / 30])
    (folder / "times.txt").write_text("0.0\n0.1\n0.2\n0.3\n")
    assert np.allclose(open_sequence(folder).timestamps, [0.0, 0.1, 0.2, 0.3])
    (folder / "times.txt").write_text("0.0\n0.1\n0.1\n0.3\n")
    with pytest.raises(DataError, match="times.txt: timestamps must increase"):
        open_sequence(folder)
    (folder / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(DataError, match="2 timestamps for 4 images"):
        open_sequence(folder)


def test_image_folder_nanosecond_names(tmp_path: Path) -> None:
    folder = tmp_path / "cam0" / "data"
    folder.mkdir(parents=True)
    for ns in (1403715524907143168, 1403715524957143168):
        cv2.imwrite(str(folder / f"{ns}.png"), np.zeros((8, 8), np.uint8))
    seq = ImageFolderSequence(tmp_path)
    assert seq.load(0).rgb.shape == (8, 8, 3)
    assert np.allclose(np.diff(seq.timestamps), 0.05)


def test_empty_image_folder(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no images"):
        open_sequence(tmp_path)
