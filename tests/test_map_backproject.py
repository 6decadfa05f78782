"""The pieces every map builder shares: which pixels are usable, their 3D points, the class
table and the voxel keys."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.core.labels import NYU40_CLASSES, SYNTH_CLASSES, VOC_CLASSES, synth_static_id
from semslam.core.protocols import KeyframeSnapshot
from semslam.core.types import LabelMap
from semslam.geometry.camera import PinholeCamera
from semslam.reconstruction import voxels
from semslam.reconstruction.backproject import static_points, stride_for_voxel, usable_pixels
from semslam.core.map_classes import (
    CLASS_COLOURS,
    CLASS_INDEX,
    CLASS_NAMES,
    N_CLASSES,
    class_image,
    label_lut,
    voc_colour,
)
from tests import map_scene as scene


def _flat_snapshot(**masks: np.ndarray) -> KeyframeSnapshot:
    cam = PinholeCamera(100.0, 100.0, 15.5, 11.5, width=32, height=24)
    depth = np.full((24, 32), 2.0, np.float32)
    depth[0, :4] = [0.0, np.nan, np.inf, 4.5]  # no reading, invalid, invalid, beyond max depth
    depth[0, 4] = 4.0  # exactly max depth: usable
    labels = LabelMap(np.full((24, 32), 101, np.uint8), {101: "wall"}, np.full((24, 32), 0.8, np.float32))
    return KeyframeSnapshot(3, 0.0, np.eye(4), np.zeros((24, 32, 3), np.uint8), depth, masks.get("dynamic"), labels,
                            cam, synthesized=masks.get("synthesized"))


def test_usable_pixels_leave_out_bad_depth_dynamic_and_synthesised() -> None:
    dynamic = np.zeros((24, 32), bool)
    dynamic[10:, :] = True
    synth = np.zeros((24, 32), bool)
    synth[5:10, :16] = True
    snap = _flat_snapshot(dynamic=dynamic, synthesized=synth)
    v, u = usable_pixels(snap, 1, 4.0)
    keep = np.zeros((24, 32), bool)
    keep[v, u] = True
    expected = ~dynamic & ~synth
    expected[0, :4] = False
    np.testing.assert_array_equal(keep, expected)
    v2, _ = usable_pixels(snap, 1, 4.0, include_synthesized=True)
    assert len(v2) == len(v) + 5 * 16
    v4, u4 = usable_pixels(snap, 4, 4.0)
    # Rows 0, 4, 8 x 8 columns, less (0, 0) (no depth) and row 8's 4 synthesised columns.
    assert (v4 % 4 == 0).all() and (u4 % 4 == 0).all() and len(v4) == 3 * 8 - 1 - 4


def test_static_points_are_the_pinhole_back_projection_with_classes() -> None:
    sp = static_points(_flat_snapshot(), 1, 4.0)
    assert len(sp) == 24 * 32 - 4
    z = np.where((sp.v == 0) & (sp.u == 4), 4.0, 2.0)
    np.testing.assert_allclose(sp.points_c[:, 2], z)
    np.testing.assert_allclose(sp.points_c[:, 0], (sp.u - 15.5) / 100.0 * z, rtol=1e-6)
    np.testing.assert_allclose(sp.points_c[:, 1], (sp.v - 11.5) / 100.0 * z, rtol=1e-6)
    assert (sp.class_ids == CLASS_INDEX["wall"]).all() and sp.confidence is not None
    np.testing.assert_allclose(sp.confidence, 0.8)
    T = scene.pose()
    np.testing.assert_allclose(sp.in_world(T), sp.points_c @ T[:3, :3].T + T[:3, 3], atol=1e-12)


def test_scene_points_land_on_the_scene() -> None:
    T = scene.poses()[1]
    sp = static_points(scene.snapshot(0, T), 1, 4.0)
    dist, true_class = scene.nearest_surface(sp.in_world(T))
    assert dist.max() < 1e-5 and (sp.class_ids == true_class).all()


def test_stride_puts_samples_a_voxel_apart_at_the_median_depth() -> None:
    snap = _flat_snapshot()  # median depth 2 m, f = 100 px: a pixel spans 2 cm
    assert stride_for_voxel(snap, 0.05, 4.0) == 2  # 5 cm / 2 cm -> every 2nd pixel (2.5, rounded down)
    assert stride_for_voxel(snap, 0.01, 4.0) == 1


def test_class_table_is_nyu40_with_its_palette_and_extras() -> None:
    for nyu_id, name in NYU40_CLASSES.items():
        assert CLASS_INDEX[name] == nyu_id
    assert CLASS_NAMES[0] == "unknown" and CLASS_NAMES[41] == "moving_object" and N_CLASSES == 59
    # ScanNet's create_color_palette(): wall, floor, person, otherprop.
    assert [tuple(CLASS_COLOURS[i]) for i in (1, 2, 31, 40)] == [(174, 199, 232), (152, 223, 138),
                                                                 (120, 185, 128), (100, 85, 144)]
    assert voc_colour(15) == (192, 128, 128) and voc_colour(1) == (128, 0, 0)  # the VOC devkit's colours
    assert tuple(CLASS_COLOURS[CLASS_INDEX["car"]]) == voc_colour(7)
    assert len({tuple(c) for c in CLASS_COLOURS}) == N_CLASSES  # every class has its own colour


def test_backend_ids_map_to_one_index_per_name() -> None:
    assert label_lut(VOC_CLASSES)[15] == label_lut(SYNTH_CLASSES)[15] == CLASS_INDEX["person"] == 31
    assert label_lut(VOC_CLASSES)[0] == 0 and label_lut({255: "void", 7: "Floor "})[[255, 7]].tolist() == [0, 2]
    assert label_lut(SYNTH_CLASSES)[21] == CLASS_INDEX["moving_object"]
    assert label_lut({synth_static_id("desk"): "desk"})[114] == 14
    assert (class_image(None, (3, 4)) == 0).all()
    small = LabelMap(np.array([[101, 102], [102, 101]], np.uint8), {101: "wall", 102: "floor"})
    np.testing.assert_array_equal(class_image(small, (4, 4)), [[1, 1, 2, 2], [1, 1, 2, 2], [2, 2, 1, 1], [2, 2, 1, 1]])


def test_voxel_keys_round_trip_and_match_octomap_keys() -> None:
    octomap = pytest.importorskip("octomap")
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.uniform(-20, 20, (200, 3)), rng.integers(-400, 400, (100, 3)) * 0.05,  # on boundaries
                          [[0.0, -1e-9, 0.049999], [-0.05, 0.05, 1234.56]]])
    q = voxels.voxel_coords(pts, 0.05)
    tree = octomap.OcTree(0.05)
    keys = [tree.coordToKey(p) for p in pts]
    np.testing.assert_array_equal(q, [[k[0] - 32768, k[1] - 32768, k[2] - 32768] for k in keys])
    np.testing.assert_array_equal(voxels.unpack(voxels.pack(q)), q)
    np.testing.assert_allclose(voxels.voxel_centres(np.array([[0, -1, 2]]), 0.05), [[0.025, -0.025, 0.125]])
    with pytest.raises(ValueError, match="cannot be packed"):
        voxels.pack(np.array([[2**20, 0, 0]]))
    k, c = voxels.majority(np.array([5, 5, 5, 7, 7]), np.array([0, 0, 3, 4, 2]), np.array([1.0, 1.0, 0.2, 1.0, 1.0]))
    np.testing.assert_array_equal(k, [5, 7])
    np.testing.assert_array_equal(c, [3, 2])  # unknown never outvotes; a tie goes to the lower index
