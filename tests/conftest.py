"""Shared fixtures: the real reference data beside the repo and tiny TUM folders."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real reference data not found at {SHARED_DATA}")
    return SHARED_DATA


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
