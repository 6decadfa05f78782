"""The ``walking_box`` sequence: a person pushes a large box into the view and carries it
up to the camera. The box is an unlabelled mover (class 21), never a person (15).

Which pixels show the box is decided independently of the renderer's label buffer: the
box alone is ray-cast again and its pixels are those where it is the nearest surface of
the rendered frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.synth import SEQUENCES, Renderer, needs_render, render_sequence
from semslam.synth.box_carry import BOX_SIZE, PERIOD, box_pose, carried_box, carrier_position
from semslam.synth.raycast import Buffers, cast_box

PERSON, MOVER = 15, 21
#: 10 s (one period of the choreography) at 3 frames/s and half resolution: 30 frames.
SHORT = {"frames": 30, "fps": 3.0, "width": 320, "height": 240}


def _box_pixels(r: Renderer, i: int, z_frame: np.ndarray) -> np.ndarray:
    """Pixels where the box alone, ray-cast again, is the nearest surface of the frame."""
    cfg = r.cfg
    buf = Buffers(cfg.height, cfg.width)
    table = np.zeros((6, 2, 4), np.float32)
    cast_box(buf, r.cam, r.poses[i], carried_box(float(r.times[i])), table, np.ones(6, np.float32))
    return np.isfinite(buf.z) & (np.abs(buf.z - z_frame) < 1e-4)


@pytest.fixture(scope="module")
def short_box(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = SEQUENCES["walking_box"].replace(**SHORT)
    return render_sequence(cfg, tmp_path_factory.mktemp("box") / "walking_box")


def test_box_is_an_unlabelled_mover_never_a_person(short_box: Path) -> None:
    meta = json.loads((short_box / "sequence.json").read_text())
    assert meta["config"]["box_carrier"] is True
    assert meta["labels"]["21"] == "moving_object" and meta["labels"]["15"] == "person"
    r = Renderer(SEQUENCES["walking_box"].replace(**SHORT))
    files = sorted((short_box / "semantic").glob("*.png"))
    assert len(files) == SHORT["frames"]
    coverage, person_with_box = [], 0
    for i, path in enumerate(files):
        sem = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        fr = r.render(i)
        assert np.array_equal(sem, fr.semantic)  # the file is what the renderer labelled
        box = _box_pixels(r, i, fr.z)
        # Every pixel of the box is labelled as the unlabelled mover, none as a person,
        # and the label covers nothing else (the person carrying it is 15).
        assert (sem[box] == MOVER).all()
        assert (sem == MOVER).sum() == box.sum()
        coverage.append(box.mean())
        if box.mean() > 0.05 and (sem == PERSON).mean() > 0.01:
            person_with_box += 1
    coverage = np.array(coverage)
    # Pushed into view, carried up to the camera (measured peak 0.61 at full resolution),
    # carried out again: a plausible range, large at its peak, absent at the start.
    assert 0.45 < coverage.max() < 0.75, coverage.round(2)
    assert coverage[0] == 0.0
    assert (coverage > 0.05).sum() >= 10
    assert person_with_box >= 8  # somebody is moving it


def test_box_and_person_paths() -> None:
    """The choreography is periodic, the box stands on the floor or is held up, its speed
    is that of a walking person and the person stays behind it (farther from the camera)."""
    t = np.linspace(0.0, 2 * PERIOD, 2001)
    centres = np.array([box_pose(v)[0] for v in t])
    assert np.allclose(box_pose(0.3)[0], box_pose(0.3 + PERIOD)[0])
    bottom = centres[:, 2] - BOX_SIZE[2] / 2
    assert bottom.min() >= -1e-9 and bottom.max() <= 0.61
    speed = np.linalg.norm(np.diff(centres, axis=0), axis=1) / np.diff(t)
    assert 0.5 < speed.max() < 1.5
    feet = np.array([carrier_position(v) for v in t])
    assert (feet[:, 1] > centres[:, 1] + BOX_SIZE[1] / 2).all()


def test_render_is_deterministic_and_old_renders_stay_valid(tmp_path: Path) -> None:
    cfg = SEQUENCES["walking_box"].replace(frames=2, width=160, height=120)
    a, b = Renderer(cfg).render(1), Renderer(cfg).render(1)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    # A render cached before SynthConfig had ``box_carrier`` (no such key in its
    # sequence.json) is still valid for the same configuration without the box.
    plain = SEQUENCES["static_xyz"].replace(frames=2, width=160, height=120)
    seq = render_sequence(plain, tmp_path / "old")
    meta = json.loads((seq / "sequence.json").read_text())
    del meta["config"]["box_carrier"]
    (seq / "sequence.json").write_text(json.dumps(meta))
    assert not needs_render(seq, plain)
    assert needs_render(seq, plain.replace(box_carrier=True))
