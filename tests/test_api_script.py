"""The README's ``semslam.System`` example, saved as a plain script (no ``__main__`` guard) and
run as a user would: ``python example.py``. Spawned worker processes used to re-run such a
script (issue 38): ~300 lines of multiprocessing errors with ``default``, a child traceback
and a broken loop-closing worker with ``orb``. The block is read from README.md, so the test
follows what the README prints; the reference is the render's exact ground truth."""

from __future__ import annotations

import multiprocessing.spawn
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from semslam.worker_processes import main_module_hidden

ROOT = Path(__file__).resolve().parents[1]
HEADING = "### Python API: `semslam.System`"
#: What the example renders (checked against its text, so a README change fails here first).
SEQUENCE, FRAMES = "static_xyz", 30
PRESET_CALL = 'System("default"'
POSE_LINE = re.compile(r"^(\d+\.\d*) \[(.*)\]$")


def readme_example() -> str:
    """The first ``python`` block after the System heading of README.md, as printed."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```python\n(.*?)```", text[text.index(HEADING):], re.DOTALL)
    assert block is not None, f"no python block after {HEADING!r} in README.md"
    return block.group(1)


def ground_truth_position(frames: int) -> np.ndarray:
    """The last camera's position in the first camera's frame (SLAM's world)."""
    from semslam.synth import SEQUENCES, Renderer

    poses = Renderer(SEQUENCES[SEQUENCE].replace(frames=frames)).poses
    return (np.linalg.inv(poses[0]) @ poses[-1])[:3, 3]


def test_example_renders_what_the_test_expects() -> None:
    code = readme_example()
    assert f'SEQUENCES["{SEQUENCE}"]' in code and f"n={FRAMES}" in code
    assert code.count(PRESET_CALL) == 1
    assert "__main__" not in code  # the point: a script without the guard


@pytest.mark.parametrize("preset", ["default", "orb"])
def test_readme_example_runs_as_a_script(preset: str, tmp_path: Path) -> None:
    script = tmp_path / "example.py"
    script.write_text(readme_example().replace(PRESET_CALL, f'System("{preset}"'))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=180, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "Error" not in proc.stderr, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines[-1] == f"{FRAMES} poses, {lines[-1].split()[2]} keyframes", lines[-1]
    positions = [np.array(m.group(2).split(), float) for m in map(POSE_LINE.match, lines[:-1]) if m]
    assert len(positions) == len(lines) - 1 == FRAMES  # a pose on every frame: nothing lost
    # The last pose printed while tracking, against the exact ground truth (5-6 mm here).
    assert np.linalg.norm(positions[-1] - ground_truth_position(FRAMES)) < 0.03
    assert len((tmp_path / "run1" / "trajectory.txt").read_text().splitlines()) == FRAMES + 1  # + header


def test_hidden_main_is_not_sent_to_spawned_children() -> None:
    """Inside ``main_module_hidden`` spawn's preparation data names no main module to
    re-import; outside, ``__main__`` is as it was (pytest's own script here)."""
    main = sys.modules["__main__"]
    before = (main.__dict__.get("__file__"), main.__dict__.get("__spec__"))
    with main_module_hidden():
        data = multiprocessing.spawn.get_preparation_data("worker")
    assert not {"init_main_from_path", "init_main_from_name"} & data.keys()
    assert (main.__dict__.get("__file__"), main.__dict__.get("__spec__")) == before
