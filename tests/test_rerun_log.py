"""The Rerun recording: frames logged to an ``.rrd`` file are read back with Rerun's own
dataframe API (entities, timelines, poses, keypoints, mask, the static map entities), the
recorder refuses what it cannot do with one clear error, and ``semslam run --rerun`` records
every frame of a run (and, on a rendered sequence, its trajectory, map points and mesh).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import ConfigError
from semslam.geometry.camera import PinholeCamera
from semslam.reconstruction.keyframe_cloud import write_ply
from semslam.viz.palette import class_colour, class_table
from semslam.viz.rerun_log import DYNAMIC_COLOUR, STATIC_COLOUR, RerunRecorder
from tests.conftest import run_cli

rr = pytest.importorskip("rerun")

W, H = 160, 120
CAM = PinholeCamera(130.0, 130.0, 79.5, 59.5, width=W, height=H)
T0 = 1305031102.0


def _pose(k: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [0.1 * k, 0.0, 0.02 * k]
    return T


def _record(path: Path, n: int = 4) -> None:
    rec = RerunRecorder("semslam-test", path=path)
    for k in range(n):
        mask = np.zeros((H, W), bool)
        mask[10:20, 30 + k:50 + k] = True  # 200 dynamic pixels
        xy = np.array([[5.0 + k, 6.0], [50.0, 60.0], [100.0, 7.5]])
        pose = None if k == 2 else _pose(k)  # frame 2 lost: no pose logged
        rec.log_frame(k, T0 + k / 30, np.full((H, W, 3), 40 * k, np.uint8), mask, xy, np.array([True, False, True]),
                      pose, CAM, depth=np.full((H, W), 1.5, np.float32) if k == 0 else None)
    rec.log_trajectory(np.array([_pose(k)[:3, 3] for k in range(n)]))
    rec.log_map_points(np.arange(30, dtype=float).reshape(10, 3))
    labels = np.array([0, 31, 31, 5, 5, 5])  # map class indices: unknown, person, chair
    rec.log_semantic_cloud(np.random.default_rng(0).random((6, 3)), np.zeros((6, 3), np.uint8), labels,
                           class_table(labels))
    rec.close()
    rec.close()  # twice is fine


def _column(table: object, name: str) -> list:
    return table.column(name).to_pylist()  # type: ignore[attr-defined]


def test_frames_read_back_from_the_rrd(tmp_path: Path) -> None:
    path = tmp_path / "run.rrd"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RerunWarning means something was not logged
        _record(path)
    recording = rr.dataframe.load_recording(str(path))
    entities = {c.entity_path for c in recording.schema().component_columns()}
    for e in ("/world", "/world/camera", "/world/camera/image", "/world/camera/image/dynamic",
              "/world/camera/image/depth", "/world/camera/image/keypoints", "/world/trajectory", "/world/map_points",
              "/world/semantic_cloud", "/world/semantic_cloud/classes"):
        assert e in entities, (e, sorted(entities))

    frames = recording.view(index="frame", contents="/world/camera/**").select().read_all()
    assert _column(frames, "frame") == [0, 1, 2, 3]
    times = [t.timestamp() for t in _column(frames, "time")]
    assert np.allclose(times, T0 + np.arange(4) / 30, atol=1e-6)
    translations = _column(frames, "/world/camera:Translation3D")
    assert translations[2] is None  # the lost frame
    for k in (0, 1, 3):
        assert np.allclose(translations[k][0], _pose(k)[:3, 3], atol=1e-6)
    assert all(b is not None for b in _column(frames, "/world/camera/image:Blob"))  # JPEG per frame
    kps = _column(frames, "/world/camera/image/keypoints:Position2D")
    assert [len(k) for k in kps] == [3, 3, 3, 3] and np.allclose(kps[3][0], [8.0, 6.0])
    colours = _column(frames, "/world/camera/image/keypoints:Color")[0]

    def rgba(c: tuple[int, int, int]) -> int:
        return (c[0] << 24) | (c[1] << 16) | (c[2] << 8) | 255

    assert colours == [rgba(STATIC_COLOUR), rgba(DYNAMIC_COLOUR), rgba(STATIC_COLOUR)]
    mask = np.frombuffer(bytes(_column(frames, "/world/camera/image/dynamic:ImageBuffer")[1][0]), np.uint8)
    assert mask.size == W * H and mask.sum() == 200

    static = recording.view(index="frame", contents="/world/**").select_static().read_all()
    strip = _column(static, "/world/trajectory:LineStrip3D")[0][0]
    assert np.allclose(strip, [_pose(k)[:3, 3] for k in range(4)], atol=1e-6)
    assert len(_column(static, "/world/map_points:Position3D")[0]) == 10
    assert _column(static, "/world/semantic_cloud/classes:ClassId")[0] == [0, 31, 31, 5, 5, 5]
    context = _column(static, "/world/semantic_cloud/classes:AnnotationContext")[0][0]  # one row, one context
    names = {c["class_id"]: c["class_description"]["info"]["label"] for c in context}
    assert names == {0: "unknown", 31: "person", 5: "chair"}
    r, g, b = class_colour(5)
    assert {c["class_id"]: c["class_description"]["info"]["color"] for c in context}[5] == rgba((r, g, b))


def test_recorder_refuses_clearly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match="needs a file"):
        RerunRecorder()
    with pytest.raises(ConfigError, match=r"expected a \.rrd file"):
        RerunRecorder(path=tmp_path / "run.txt")
    monkeypatch.setitem(sys.modules, "rerun", None)  # as if rerun-sdk were not installed
    with pytest.raises(ConfigError, match="need the rerun-sdk package"):
        RerunRecorder(path=tmp_path / "run.rrd")


def test_semslam_run_records_every_frame(tum_folder: Path, tmp_path: Path) -> None:
    """A tiny run (5 frames) through the CLI: the recording has every frame, closed."""
    path = tmp_path / "rec" / "run.rrd"
    stats = run_cli(tum_folder, tmp_path / "out", "--preset", "f2kf", "--no-report", "--rerun", str(path))
    frames = rr.dataframe.load_recording(str(path)).view(index="frame", contents="/world/camera/image").select()
    assert _column(frames.read_all(), "frame") == list(range(stats["frames"])) == list(range(5))


def test_an_interrupted_run_still_closes_the_recording(tum_folder: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C at the fourth frame: the run writes what it has and the recording is complete
    with the three frames tracked before it (and the end-of-run entities)."""
    from semslam.config import load_config
    from semslam.io.sequence import open_sequence
    from semslam.pipeline import run_slam
    from semslam.api import System

    track = System._track

    def interrupted(self: System, parts: object, packet: object) -> object:
        if self.n_frames == 3:
            raise KeyboardInterrupt
        return track(self, parts, packet)  # type: ignore[arg-type]

    monkeypatch.setattr(System, "_track", interrupted)
    path = tmp_path / "run.rrd"
    with pytest.raises(KeyboardInterrupt):
        run_slam(open_sequence(tum_folder), load_config("f2kf"), tmp_path / "out", progress=False, report=False,
                 rerun=path)
    assert "KeyboardInterrupt" in (tmp_path / "out" / "stats.json").read_text()
    recording = rr.dataframe.load_recording(str(path))
    frames = recording.view(index="frame", contents="/world/camera/image").select().read_all()
    assert _column(frames, "frame") == [0, 1, 2]


@pytest.mark.slow
def test_run_with_mesh_and_rerun_on_a_render(static_render: Path, tmp_path: Path) -> None:
    """ORB-SLAM on the rendered static sequence with the mesh and keyframe-cloud builders:
    the recording holds every frame, the final trajectory and the map points; mesh.ply is
    written and the report shows the map views."""
    import open3d as o3d

    out, path = tmp_path / "run", tmp_path / "run.rrd"
    stats = run_cli(static_render, out, "--preset", "orb", "--sequential", "--rerun", str(path),
                    "--set", "maps.builders=[mesh,keyframe_cloud]")
    recording = rr.dataframe.load_recording(str(path))
    frames = recording.view(index="frame", contents="/world/camera/**").select().read_all()
    assert len(_column(frames, "frame")) == stats["frames"]
    assert sum(t is not None for t in _column(frames, "/world/camera:Translation3D")) == stats["tracked_frames"]
    static = recording.view(index="frame", contents="/world/**").select_static().read_all()
    assert len(_column(static, "/world/trajectory:LineStrip3D")[0][0]) == stats["tracked_frames"]
    assert len(_column(static, "/world/map_points:Position3D")[0]) == stats["map_points"]
    mesh = o3d.io.read_triangle_mesh(str(out / "map" / "mesh.ply"))
    assert len(mesh.triangles) > 1000
    # The mesh lies on the rendered surfaces: vertices moved into the renderer's world and
    # projected into frame 45 agree with its exact depth where they are visible (the fused
    # depth averages the Kinect-like noise out: better than one frame's noise).
    from semslam.synth import SEQUENCES, Renderer
    from tests.conftest import E2E_FRAMES

    cfg = SEQUENCES["static_xyz"].replace(frames=E2E_FRAMES)
    r = Renderer(cfg)
    v = np.asarray(mesh.vertices)
    T_gt0, T_cw = r.poses[0], np.linalg.inv(r.poses[45])
    pc = (v @ T_gt0[:3, :3].T + T_gt0[:3, 3]) @ T_cw[:3, :3].T + T_cw[:3, 3]
    cam = PinholeCamera(*cfg.intrinsics(), width=cfg.width, height=cfg.height)
    front = pc[:, 2] > 0.1
    uv = cam.project(pc[front])
    inside = cam.in_image(uv)
    u, vv = uv[inside].astype(int).T
    exact = r.render(45).z.astype(np.float64)[vv, u]
    z = pc[front][inside, 2]
    ok = np.isfinite(exact) & (z <= exact + 0.05)  # vertices behind a nearer surface are not compared
    err = np.abs(z[ok] - exact[ok])
    assert ok.sum() > 5000 and np.median(err) < 0.01, (ok.sum(), np.median(err))
    html = (out / "report.html").read_text()
    assert "<h2>Map</h2>" in html and "keyframe_cloud.ply" in html and (out / "map" / "map_top.png").is_file()


def test_semantic_cloud_of_a_map_dir(tmp_path: Path) -> None:
    """``log_map_dir`` logs ``semantic_cloud.ply`` when the maps wrote one."""
    map_dir = tmp_path / "map"
    map_dir.mkdir()
    path = tmp_path / "a.rrd"
    rec = RerunRecorder(path=path)
    rec.log_map_dir(map_dir)  # nothing there: nothing logged
    write_ply(map_dir / "semantic_cloud.ply", np.ones((4, 3)), np.full((4, 3), 7, np.uint8))
    rec.log_map_dir(map_dir)
    rec.close()
    static = rr.dataframe.load_recording(str(path)).view(index="frame", contents="/world/**").select_static()
    table = static.read_all()
    assert len(_column(table, "/world/semantic_cloud:Position3D")[0]) == 4
    assert "/world/semantic_cloud/classes:ClassId" not in table.column_names  # no labels in this PLY
