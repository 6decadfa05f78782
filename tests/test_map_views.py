"""Map views for the report: PLY clouds with and without labels are read (bad files refused
naming the file), the top-down view shows what is seen from above (a table over a floor)
in class colours or the points' own, and the HTML report embeds the views when the run
wrote a cloud and still works when it did not.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from plyfile import PlyData, PlyElement

from semslam.errors import DataError
from semslam.eval.metrics import ate
from semslam.eval.report import write_report
from semslam.core.trajectory import Trajectory
from semslam.reconstruction.keyframe_cloud import write_ply
from semslam.viz.map_views import Cloud, find_cloud, perspective_png, read_cloud, top_down_png, write_views
from semslam.viz.palette import class_colour, class_name

FLOOR, TABLE = 2, 7  # the maps' class indices (core.map_classes: NYU-40 ids) of "floor" and "table"
FLOOR_RGB, TABLE_RGB = (30, 60, 220), (230, 30, 30)


def _scene(n: int = 40_000) -> Cloud:
    """A 4 x 4 m floor 1 m below the first camera (y = +1: y points down) and a 1 x 1 m table
    top 0.3 m above it, over the floor's centre."""
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-2, 2, n), np.full(n, 1.0), rng.uniform(1, 5, n)])
    m = n // 16  # the floor's density
    table = np.column_stack([rng.uniform(-0.5, 0.5, m), np.full(m, 0.7), rng.uniform(2.5, 3.5, m)])
    xyz = np.vstack([table, floor])  # the table first: drawn first unless sorted by height
    rgb = np.vstack([np.tile(TABLE_RGB, (m, 1)), np.tile(FLOOR_RGB, (n, 1))]).astype(np.uint8)
    labels = np.concatenate([np.full(m, TABLE), np.full(n, FLOOR)])
    return Cloud(xyz, rgb, labels)


def _write_labelled(path: Path, cloud: Cloud) -> None:
    rows = np.empty(len(cloud.xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                                           ("blue", "u1"), ("label", "<u2")])
    for k, name in enumerate("xyz"):
        rows[name] = cloud.xyz[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        rows[name] = cloud.rgb[:, k]
    assert cloud.labels is not None
    rows["label"] = cloud.labels
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))


def _near(img: np.ndarray, colour: tuple[int, int, int], tol: float = 20) -> np.ndarray:
    return np.abs(img[..., :3] * 255 - np.array(colour)).max(-1) < tol


def _shares(png: bytes, table: tuple[int, int, int], floor: tuple[int, int, int]) -> tuple[float, float]:
    """The table colour's share of the coloured pixels in a window at the floor's centre
    (where the table is), and over the whole view."""
    img = imread(io.BytesIO(png), format="png")
    t, f = _near(img, table), _near(img, floor)
    ys, xs = np.nonzero(t | f)
    cy, cx, r = int(np.median(ys)), int(np.median(xs)), int(0.05 * (xs.max() - xs.min()))
    tw, fw = t[cy - r:cy + r, cx - r:cx + r].sum(), f[cy - r:cy + r, cx - r:cx + r].sum()
    return float(tw / (tw + fw)), float(t.sum() / (t.sum() + f.sum()))


def test_read_cloud_with_and_without_labels(tmp_path: Path) -> None:
    cloud = _scene(1000)
    _write_labelled(tmp_path / "semantic_cloud.ply", cloud)
    got = read_cloud(tmp_path / "semantic_cloud.ply")
    assert np.allclose(got.xyz, cloud.xyz, atol=1e-6) and (got.rgb == cloud.rgb).all()
    assert got.labels is not None and (got.labels == cloud.labels).all()
    write_ply(tmp_path / "keyframe_cloud.ply", cloud.xyz, cloud.rgb)
    assert read_cloud(tmp_path / "keyframe_cloud.ply").labels is None
    assert find_cloud(tmp_path) == tmp_path / "semantic_cloud.ply"  # preferred over the keyframe cloud
    (tmp_path / "semantic_cloud.ply").unlink()
    assert find_cloud(tmp_path) == tmp_path / "keyframe_cloud.ply"
    (tmp_path / "keyframe_cloud.ply").unlink()
    assert find_cloud(tmp_path) is None


def test_bad_ply_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "semantic_cloud.ply"
    bad.write_bytes(b"not a ply")
    with pytest.raises(DataError, match="semantic_cloud.ply: cannot read a PLY"):
        read_cloud(bad)
    rows = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(bad))
    with pytest.raises(DataError, match="lack red, green, blue"):
        read_cloud(bad)


def test_top_down_shows_what_is_seen_from_above() -> None:
    cloud = _scene(160_000)  # 4 points per 2 cm cell: few cells without a table point
    by_class = top_down_png(cloud)
    assert by_class[:8] == b"\x89PNG\r\n\x1a\n"
    # Seen from above the table hides the floor under it: 1 m2 of the 16 m2 floor's view.
    centre, overall = _shares(by_class, class_colour(TABLE), class_colour(FLOOR))
    assert centre > 0.95 and 0.04 < overall < 0.09, (centre, overall)
    plain = top_down_png(Cloud(cloud.xyz, cloud.rgb))  # no labels: the points' own colours
    centre, overall = _shares(plain, TABLE_RGB, FLOOR_RGB)
    assert centre > 0.95 and 0.04 < overall < 0.09, (centre, overall)
    assert not _near(imread(io.BytesIO(plain), format="png"), class_colour(TABLE)).any()
    assert class_name(TABLE) == "table" and class_name(FLOOR) == "floor"


def test_perspective_view_shows_both_surfaces() -> None:
    """Points are anti-aliased over white: count pixels by their dominant channel."""
    img = imread(io.BytesIO(perspective_png(_scene())), format="png")[..., :3] * 255
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    red, blue = (r - np.maximum(g, b) > 60).sum(), (b - np.maximum(r, g) > 60).sum()
    assert red > 300 and blue > 5 * red, (red, blue)  # the table is 1/16 of the floor's points


def _report(tmp_path: Path, map_dir: Path | None) -> str:
    t = np.arange(50) * 0.1
    poses = np.tile(np.eye(4), (50, 1, 1))
    poses[:, :3, 3] = np.column_stack([np.cos(t), np.sin(t), 0.1 * t])
    gt = Trajectory(t, poses, "gt")
    res = ate(gt, gt, align="se3")
    path = write_report(tmp_path / "report.html", gt, gt, res, map_dir=map_dir)
    return path.read_text()


def test_report_embeds_the_map_views(tmp_path: Path) -> None:
    map_dir = tmp_path / "map"
    map_dir.mkdir()
    html = _report(tmp_path, map_dir)  # no cloud: the report as before
    assert "<h2>Map</h2>" not in html and "<h2>ATE over time</h2>" in html
    assert "<h2>Map</h2>" not in _report(tmp_path, None)
    _write_labelled(map_dir / "semantic_cloud.ply", _scene(2000))
    html = _report(tmp_path, map_dir)
    assert "<h2>Map</h2>" in html and "semantic_cloud.ply" in html
    assert 'alt="map_top (map_top.png)"' in html and 'alt="map_perspective (map_perspective.png)"' in html
    assert html.count("data:image/png;base64,") == 4  # trajectory, ATE, two map views
    assert (map_dir / "map_top.png").stat().st_size > 1000 and (map_dir / "map_perspective.png").is_file()
    (map_dir / "semantic_cloud.ply").write_bytes(b"garbage")  # a broken cloud: a note, not a failed report
    assert "map views skipped: " in _report(tmp_path, map_dir)


def test_write_views_elsewhere(tmp_path: Path) -> None:
    write_ply(tmp_path / "keyframe_cloud.ply", np.random.default_rng(1).random((100, 3)), np.zeros((100, 3), np.uint8))
    paths = write_views(tmp_path / "keyframe_cloud.ply", tmp_path / "views")
    assert set(paths) == {"map_top", "map_perspective"} and all(p.parent == tmp_path / "views" for p in paths.values())
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths.values())
