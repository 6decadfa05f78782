"""Shared fixtures: the real reference data beside the repo and tiny TUM folders."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from semslam.core.types import Frame

if TYPE_CHECKING:
    from semslam.synth import Renderer

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def rendered_frames(renderer: Renderer, indices: Iterable[int]) -> list[Frame]:
    """Frames ``indices`` of a ``synth.Renderer`` as the tracker takes them (depth in metres,
    from the 16-bit PNG values the writer stores: 5000 per metre)."""
    frames = []
    for i in indices:
        f = renderer.render(i)
        frames.append(Frame(i, float(renderer.times[i]), f.rgb, f.depth.astype(np.float32) / 5000.0))
    return frames


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real reference data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def real_grays(shared_data: Path) -> list[np.ndarray]:
    """The real frames beside the repo (Kinect colour, TUM frames with people), grey: the
    extractor tests' real images."""
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))
    paths += sorted((shared_data / "images_people").glob("*.png"))
    if not paths:
        pytest.skip(f"no real frames under {shared_data}")
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]


@pytest.fixture(scope="session")
def real_gray(real_grays: list[np.ndarray]) -> np.ndarray:
    return real_grays[0]


@pytest.fixture(scope="session")
def synth_gray() -> np.ndarray:
    """The first frame of the static_xyz render, grey."""
    from semslam.synth import SEQUENCES, Renderer

    rgb = Renderer(SEQUENCES["static_xyz"].replace(frames=3)).render(0).rgb
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def write_tum_folder(root: Path, n: int = 5, size: tuple[int, int] = (64, 48), depth_offset: float = 0.004,
                     t0: float = 1305031102.0, dt: float = 1 / 30) -> Path:
    """A minimal TUM RGB-D folder with random images, depth 2 m, list files and ground truth."""
    rng = np.random.default_rng(0)
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(exist_ok=True)
    rgb_lines = ["# color images", "# file: 'test'", "# timestamp filename"]
    depth_lines = ["# depth maps", "# file: 'test'", "# timestamp filename"]
    gt_lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    w, h = size
    for i in range(n):
        t = t0 + i * dt
        td = t + depth_offset
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
        cv2.imwrite(str(root / f"depth/{td:.6f}.png"), np.full((h, w), 10000, np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
        gt_lines.append(f"{t:.4f} {0.01 * i} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    return root


@pytest.fixture()
def tum_folder(tmp_path: Path) -> Path:
    return write_tum_folder(tmp_path / "rgbd_dataset_freiburg1_test")


#: Frames of the short renders shared by the end-to-end tests (rendering costs ~10 s each).
E2E_FRAMES = 90


def _render_once(tmp_path_factory: pytest.TempPathFactory, name: str) -> Path:
    from semslam.synth import SEQUENCES, render_sequence

    return render_sequence(SEQUENCES[name].replace(frames=E2E_FRAMES), tmp_path_factory.mktemp("e2e") / name)


@pytest.fixture(scope="session")
def static_render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``static_xyz`` on disk (TUM layout, with ``semantic/`` labels), rendered once per
    session for every test that runs the CLI on it."""
    return _render_once(tmp_path_factory, "static_xyz")


@pytest.fixture(scope="session")
def walking_render(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``walking_xyz`` (two people) on disk, rendered once per session."""
    return _render_once(tmp_path_factory, "walking_xyz")


def run_cli(seq: Path, out: Path, *extra: str) -> dict:
    """``semslam run SEQ --out OUT --quiet ...``; must exit 0; returns its stats.json."""
    import json

    from semslam.cli.main import main

    assert main(["run", str(seq), "--out", str(out), "--quiet", *extra]) == 0
    return json.loads((out / "stats.json").read_text())


def evo_ate(gt: Path, est: Path, correct_scale: bool = False) -> float:
    """ATE RMSE (translation) computed by evo itself, the reference: SE(3)-aligned, or Sim(3)
    with ``correct_scale`` (monocular)."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref, e = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt)),
                                         file_interface.read_tum_trajectory_file(str(est)), max_diff=0.02)
    e.align(ref, correct_scale=correct_scale)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, e))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


@pytest.fixture(scope="module")
def torch_one_thread():
    """One torch thread for a test module: on a busy 2-core machine two threads wait on each
    other ~10x longer."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
