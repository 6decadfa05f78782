"""Static ground-truth geometry of the synthetic scenes (``semslam/synth/static_geometry.py``):
analytic point-to-box-surface distances, surface sampling, the movers' boxes, file errors.

References are independent of the code under test: hand-computed distances, and a brute
force nearest neighbour over a dense sampling of the faces.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from semslam.core.labels import synth_static_id
from semslam.errors import DataError
from semslam.geometry.se3 import so3_exp
from semslam.synth.scene import _box
from semslam.synth.static_geometry import (
    MOVERS_FILE,
    SCENE_FILE,
    StaticGeometry,
    load_movers,
    load_static_geometry,
    mover_boxes,
    movers_json,
    scene_json,
)

WALL, FLOOR, CEILING = (synth_static_id(n) for n in ("wall", "floor", "ceiling"))
DESK, BOX, DOOR = (synth_static_id(n) for n in ("desk", "box", "door"))
SIX = ("wall", "floor", "ceiling", "desk", "box", "door")  # a class per face, to tell them apart


def _write_scene(tmp: Path, boxes) -> StaticGeometry:
    (tmp / SCENE_FILE).write_text(json.dumps(scene_json(boxes)))
    return load_static_geometry(tmp)


@pytest.fixture
def room_scene(tmp_path: Path) -> StaticGeometry:
    """A 4 x 3 x 2.5 m room with a desk-sized box standing on the floor and a yawed crate."""
    return _write_scene(
        tmp_path,
        [
            _box(
                "room",
                (0, 0, 0),
                (4, 3, 2.5),
                "wall",
                inside=True,
                cls=("wall", "wall", "wall", "wall", "ceiling", "floor"),
            ),
            _box("desk", (1.0, 1.0, 0.0), (2.0, 1.5, 0.75), "wood", cls="desk"),
            _box("crate", (3.0, 2.0, 0.0), (3.4, 2.4, 0.4), "cardboard", yaw_deg=30, cls="box"),
        ],
    )


def test_distance_to_an_axis_aligned_box(tmp_path: Path) -> None:
    g = _write_scene(tmp_path, [_box("b", (-1, -2, -3), (1, 2, 3), "wood", cls=SIX)])
    pts = np.array(
        [
            [1.0, 0.5, 0.5],  # on the +x face
            [3.0, 0.0, 0.0],  # 2 m in front of +x
            [0.0, -2.5, 0.0],  # 0.5 m in front of -y
            [0.0, 0.0, 0.0],  # centre: 1 m from the x faces, 2 from y, 3 from z
            [2.0, 3.0, 0.0],  # beyond the +x/+y edge: sqrt(2)
            [2.0, 3.0, 4.0],  # beyond a corner: sqrt(3)
            [0.2, 0.0, 2.9],  # inside, 0.1 m below the top
        ]
    )
    d, c = g.distance(pts)
    np.testing.assert_allclose(d, [0.0, 2.0, 0.5, 1.0, np.sqrt(2), np.sqrt(3), 0.1], atol=1e-12)
    # faces in +x, -x, +y, -y, +z, -z order carry SIX's classes
    ids = [synth_static_id(n) for n in SIX]
    assert c[0] == ids[0] and c[1] == ids[0] and c[2] == ids[3] and c[6] == ids[4]
    assert c[3] in (ids[0], ids[1])  # both x faces are 1 m away
    # restricted to the -z face ("door"): from the centre that is 3 m, from the top 5.9 m
    d_door, c_door = g.distance(pts[[3, 6]], classes=[ids[5]])
    np.testing.assert_allclose(d_door, [3.0, 5.9], atol=1e-12)
    assert (c_door == ids[5]).all()
    with pytest.raises(ValueError):
        g.distance(pts, classes=[synth_static_id("bed")])
    with pytest.raises(ValueError):
        g.distance(np.zeros((4, 2)))


def test_distance_to_a_rotated_box(tmp_path: Path) -> None:
    g = _write_scene(tmp_path, [_box("b", (1, 2, 0), (1.6, 2.4, 0.5), "wood", yaw_deg=37, cls=SIX)])
    rot = so3_exp(np.array([0.0, 0.0, np.deg2rad(37.0)]))
    centre, half = np.array([1.3, 2.2, 0.25]), np.array([0.3, 0.2, 0.25])
    local = np.array([[half[0] + 0.5, 0.0, 0.0], [0.1, -half[1] - 0.2, 0.1], [0.0, 0.05, 0.0]])
    d, c = g.distance(centre + local @ rot.T)
    np.testing.assert_allclose(d, [0.5, 0.2, 0.15], atol=1e-12)
    assert list(c) == [synth_static_id(n) for n in ("wall", "desk", "ceiling")]  # +x, -y, +y


def test_inside_the_room(room_scene: StaticGeometry) -> None:
    pts = np.array([[0.6, 2.0, 1.4], [3.5, 1.0, 0.3], [3.5, 1.0, 2.4], [1.5, 1.25, 1.0]])
    d, c = room_scene.distance(pts)
    np.testing.assert_allclose(d, [0.6, 0.3, 0.1, 0.25], atol=1e-12)
    assert list(c) == [WALL, FLOOR, CEILING, DESK]  # the last one is 0.25 m above the desk
    d_floor, _ = room_scene.distance(pts, classes=[FLOOR])
    np.testing.assert_allclose(d_floor, pts[:, 2], atol=1e-12)


def test_distance_matches_brute_force(room_scene: StaticGeometry) -> None:
    """Against the nearest of dense surface samples (1 cm grid: error <= 7.1 mm)."""
    surf, cls = room_scene.sample_surface(0.01, include_hidden=True)
    tree = cKDTree(surf)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.3, -0.3, -0.3], [4.3, 3.3, 2.8], (3000, 3))
    d, c = room_scene.distance(pts)
    ref, idx = tree.query(pts)
    assert np.abs(d - ref).max() < 0.01 * np.sqrt(2) / 2 + 1e-9
    # same class as the nearest sample wherever another class is clearly farther
    per_class = {k: room_scene.distance(pts, classes=[k])[0] for k in np.unique(cls)}
    other = np.min([np.where(c == k, np.inf, v) for k, v in per_class.items()], axis=0)
    clear = other > d + 0.01
    assert clear.mean() > 0.9 and (c[clear] == cls[idx[clear]]).all()


def test_sample_surface(room_scene: StaticGeometry, tmp_path: Path) -> None:
    pts, cls = room_scene.sample_surface(0.05)
    d, c = room_scene.distance(pts)
    assert d.max() < 1e-9
    assert (c == cls).mean() > 0.98  # differs only on edges, where two faces meet
    # floor: 4 x 3 m at 5 cm = 80 x 60 cells, less the desk's and the crate's footprints
    floor = (cls == FLOOR).sum()
    crate_cells = 0.4 * 0.4 / 0.05**2  # ~64, yawed: about as many grid cells
    assert abs(floor - (80 * 60 - 20 * 10 - crate_cells)) < 12
    assert not (pts[cls == DESK][:, 2] < 1e-6).any()  # the desk's base is hidden
    everything, _ = room_scene.sample_surface(0.05, include_hidden=True)
    assert len(everything) > len(pts)
    # a 1 m cube alone: 6 faces of 10 x 10 cells
    g = _write_scene(tmp_path, [_box("b", (0, 0, 0), (1, 1, 1), "wood", cls="box")])
    assert len(g.sample_surface(0.1)[0]) == 600
    with pytest.raises(ValueError):
        g.sample_surface(0.0)


def test_scene_file_errors(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=SCENE_FILE):
        load_static_geometry(tmp_path)
    (tmp_path / SCENE_FILE).write_text("{nope")
    with pytest.raises(DataError, match="cannot read"):
        load_static_geometry(tmp_path)
    data = scene_json([_box("b", (0, 0, 0), (1, 1, 1), "wood", cls="box")])
    data["boxes"][0]["rotation"] = [[2, 0, 0], [0, 1, 0], [0, 0, 1]]
    (tmp_path / SCENE_FILE).write_text(json.dumps(data))
    with pytest.raises(DataError, match="orthonormal"):
        load_static_geometry(tmp_path)
    data["boxes"][0]["rotation"] = np.eye(3).tolist()
    data["labels"] = {}
    (tmp_path / SCENE_FILE).write_text(json.dumps(data))
    with pytest.raises(DataError, match="not named"):
        load_static_geometry(tmp_path)


def test_mover_boxes(tmp_path: Path) -> None:
    frames = [
        [{"name": "person", "label": 15, "min": [1, 1, 0], "max": [1.5, 1.4, 1.8]}],
        [],
        [
            {"name": "person", "label": 15, "min": [1.2, 1, 0], "max": [1.7, 1.4, 1.8]},
            {"name": "carried_box", "label": 21, "min": [3, 2, 0], "max": [4, 2.6, 0.8]},
        ],
    ]
    (tmp_path / MOVERS_FILE).write_text(json.dumps(movers_json(["1.0", "2.0", "3.0"], frames)))
    movers = load_movers(tmp_path)
    assert movers.stamps == ("1.0", "2.0", "3.0") and list(movers.frame) == [0, 2, 2]
    assert list(movers.label) == [15, 15, 21] and len(mover_boxes(tmp_path)) == 3
    pts = np.array(
        [[1.1, 1.2, 1.0], [1.65, 1.2, 1.0], [3.5, 2.3, 0.4], [2.5, 1.2, 1.0], [0.9, 1.2, 1.0]]
    )
    assert list(movers.in_any_mover(pts)) == [True, True, True, False, False]
    assert list(movers.in_any_mover(pts, margin=0.15)) == [True, True, True, False, True]
    (tmp_path / MOVERS_FILE).write_text(
        json.dumps({"format": 1, "frames": [{"movers": [{"min": [0, 0]}]}]})
    )
    with pytest.raises(DataError, match=MOVERS_FILE):
        load_movers(tmp_path)
