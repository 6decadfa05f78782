"""The semantic point cloud (SDF-SLAM IV-C) against an analytic scene (tests/map_scene.py):
merged points on the true surfaces with their colours and classes, one point per voxel, no
person where it was masked, files that reopen, and points that follow corrected poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.config import MapsConfig
from semslam.core import protocols, registry
from semslam.eval.map_eval import read_class_table
from semslam.io.ply import read_vertex_ply, xyz_of
from semslam.reconstruction import voxels
from semslam.core.map_classes import CLASS_COLOURS, CLASS_INDEX
from semslam.reconstruction.semantic_cloud import SemanticCloud, merge_voxels
from tests import map_scene as scene

VOXEL = 0.02


def _built(person: bool = True, mask_person: bool = True) -> SemanticCloud:
    b = SemanticCloud(MapsConfig(cloud_voxel_m=VOXEL))
    for i, T in enumerate(scene.poses()):
        b.add_keyframe(scene.snapshot(i, T, person=person, mask_person=mask_person))
    return b


def test_registry_builds_it_as_a_map_builder() -> None:
    b = registry.create("map_builder", "cloud", MapsConfig(cloud_voxel_m=0.03))
    assert isinstance(b, protocols.MapBuilder) and b.voxel_m == 0.03


def test_merged_points_lie_on_the_surfaces_with_their_colour_and_class() -> None:
    c = _built().cloud()
    dist, true_class = scene.nearest_surface(c.xyz)
    # A voxel's mean of points on one plane lies on it; only voxels at the floor-wall corner
    # mix both planes' points.
    assert len(c.xyz) > 5000 and np.mean(dist < 1e-4) > 0.98 and dist.max() < VOXEL
    assert np.mean(c.labels == true_class) >= 0.98
    true_rgb = np.where((true_class == 2)[:, None], scene.RGB[scene.FLOOR_ID], scene.RGB[scene.WALL_ID])
    assert np.mean(np.all(c.rgb == true_rgb, axis=1)) >= 0.98
    # One point per voxel, and every sample counted once.
    keys = voxels.pack(voxels.voxel_coords(c.xyz, VOXEL))
    assert len(np.unique(keys)) == len(keys) and c.counts.min() >= 1


def test_masked_person_is_left_out_and_unmasked_one_is_kept() -> None:
    assert not (_built(mask_person=True).cloud().labels == CLASS_INDEX["person"]).any()
    ghost = _built(mask_person=False).cloud()
    person = ghost.labels == CLASS_INDEX["person"]
    assert person.sum() > 500 and np.allclose(ghost.xyz[person, 1], scene.PERSON_Y, atol=1e-4)


def test_merge_voxels_means_and_majority() -> None:
    xyz = np.array([[0.001, 0.001, 0.001], [0.003, 0.001, 0.001], [0.005, 0.004, 0.001],  # voxel (0,0,0)
                    [0.011, 0.0, 0.0], [0.013, 0.0, 0.0], [0.019, 0.0, 0.0]])  # voxel (1,0,0)
    rgb = np.array([[0, 0, 0], [30, 60, 90], [60, 0, 0], [10, 10, 10], [20, 20, 20], [30, 30, 30]], np.uint8)
    classes = np.array([0, 0, 1, 2, 2, 5])  # unknown never outvotes a class; 2 beats 5
    c = merge_voxels(xyz, rgb, classes, 0.01)
    np.testing.assert_allclose(c.xyz, [[0.003, 0.002, 0.001], [0.043 / 3, 0.0, 0.0]])
    np.testing.assert_array_equal(c.rgb, [[30, 20, 30], [20, 20, 20]])
    np.testing.assert_array_equal(c.labels, [1, 2])
    np.testing.assert_array_equal(c.counts, [3, 3])


def test_file_reopens_with_open3d_and_plyfile(tmp_path: Path) -> None:
    b = _built()
    c = b.cloud()
    paths = b.finish(tmp_path)
    path = paths["semantic_cloud"]
    table = read_class_table(paths["semantic_cloud_classes"])  # what eval-map reads
    assert table[1] == "wall" and table[2] == "floor" and len(table) == len(CLASS_COLOURS)
    o3d = pytest.importorskip("open3d")
    pcd = o3d.io.read_point_cloud(str(path))
    assert len(pcd.points) == len(c.xyz)
    np.testing.assert_allclose(np.asarray(pcd.colors), c.rgb / 255.0, atol=1e-6)  # the observed colour
    v = read_vertex_ply(path)
    np.testing.assert_allclose(xyz_of(v), c.xyz, atol=1e-6)
    np.testing.assert_array_equal(v["label"], c.labels)
    cc = CLASS_COLOURS[c.labels]
    np.testing.assert_array_equal(np.stack([v["class_red"], v["class_green"], v["class_blue"]], axis=1), cc)
    assert int(v["count"].sum()) == int(c.counts.sum())


def test_points_follow_corrected_poses() -> None:
    b = _built(person=False)
    before = b.cloud()
    shift = np.array([0.3, -0.1, 0.05])
    moved: dict[int, np.ndarray] = {99: np.eye(4)}  # a keyframe the builder never saw is ignored
    for i, T in enumerate(scene.poses()):
        moved[i] = T.copy()
        moved[i][:3, 3] += shift
    b.correct_poses(moved)
    after = b.cloud()
    # The mean of all samples (voxel means weighted by their counts) does not depend on how
    # the voxels cut them: it moves by exactly the shift.
    mean = lambda c: (c.xyz * c.counts[:, None]).sum(axis=0) / c.counts.sum()  # noqa: E731
    assert after.counts.sum() == before.counts.sum()
    np.testing.assert_allclose(mean(after), mean(before) + shift, atol=1e-6)
    d_after, _ = scene.nearest_surface(after.xyz - shift)
    assert np.mean(d_after < 1e-4) > 0.98
