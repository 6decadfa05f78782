"""The semantic octree against an analytic scene (tests/map_scene.py): occupied voxels on the
true surfaces with their classes, free space in front of them, no ghost where a person was
masked, files that reopen, and a rebuild when the poses are corrected."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semslam.config import MapsConfig
from semslam.core import protocols, registry
from semslam.eval.map_eval import read_class_table
from semslam.io.ply import read_vertex_ply, xyz_of
from semslam.reconstruction import voxels
from semslam.core.map_classes import CLASS_COLOURS, CLASS_INDEX
from semslam.reconstruction.octree import SemanticOctree, occupied_leaves, pose_moved
from tests import map_scene as scene

octomap = pytest.importorskip("octomap")

RES = 0.05


def _built(person: bool = True, mask_person: bool = True) -> SemanticOctree:
    b = SemanticOctree(MapsConfig(octree_resolution_m=RES))
    for i, T in enumerate(scene.poses()):
        b.add_keyframe(scene.snapshot(i, T, person=person, mask_person=mask_person))
    return b


def _in_person_box(centres: np.ndarray) -> np.ndarray:
    """Voxel centres within one voxel of the person rectangle."""
    (x0, x1), (z0, z1) = scene.PERSON_BOUNDS
    return ((centres[:, 0] > x0 - RES) & (centres[:, 0] < x1 + RES) & (np.abs(centres[:, 1] - scene.PERSON_Y) < RES)
            & (centres[:, 2] > z0 - RES) & (centres[:, 2] < z1 + RES))


def test_registry_builds_it_as_a_map_builder() -> None:
    b = registry.create("map_builder", "octree", MapsConfig(octree_resolution_m=0.1))
    assert isinstance(b, protocols.MapBuilder) and b.resolution == 0.1


def test_occupied_voxels_lie_on_the_surfaces_with_their_class() -> None:
    vx = _built().voxels()
    dist, true_class = scene.nearest_surface(vx.centres)
    # Floor and wall are axis-aligned planes: a voxel they cross has its centre within half a voxel.
    assert len(vx.centres) > 2000 and dist.max() <= RES / 2 + 1e-6
    assert np.mean(vx.labels == true_class) >= 0.95
    assert (vx.occupancy > 0.5).all() and (vx.occupancy <= 0.971).all()  # OctoMap's clamping max 0.97


def test_space_between_camera_and_wall_is_free() -> None:
    b = _built(person=False)
    T = scene.poses()[0]
    depth, _, labels = scene.render(scene.camera(), T, person=False)
    v, u = np.nonzero(labels == scene.WALL_ID)
    cam = scene.camera()
    pts_c = cam.backproject(np.stack([u, v], axis=1), depth[v, u])
    wall_w = pts_c @ T[:3, :3].T + T[:3, 3]
    fractions = np.linspace(0.2, 0.8, 7)
    samples = (T[:3, 3] + fractions[:, None, None] * (wall_w - T[:3, 3])[None]).reshape(-1, 3)
    state = b.tree.getLabels(samples)  # -1 unknown, 0 free, 1 occupied
    assert (state != 1).all() and np.mean(state == 0) > 0.99


def test_masked_person_leaves_no_ghost_and_unmasked_one_does() -> None:
    masked = _built(person=True, mask_person=True).voxels()
    assert not _in_person_box(masked.centres).any()
    ghost = _built(person=True, mask_person=False).voxels()
    inside = _in_person_box(ghost.centres)
    # The rectangle is 0.6 m x 1.2 m: about 12 x 24 voxels of it face the cameras.
    assert inside.sum() > 150 and np.mean(ghost.labels[inside] == CLASS_INDEX["person"]) > 0.95


def test_unlabelled_keyframes_give_unknown_voxels() -> None:
    b = SemanticOctree(MapsConfig(octree_resolution_m=RES))
    b.add_keyframe(scene.snapshot(0, scene.poses()[0], with_labels=False))
    vx = b.voxels()
    assert len(vx.labels) > 500 and (vx.labels == 0).all()


def test_files_reopen_with_octomap_open3d_and_plyfile(tmp_path: Path) -> None:
    b = _built()
    vx = b.voxels()
    paths = b.finish(tmp_path)
    assert set(paths) == {"octree", "octree_semantic", "octree_classes"}

    tree = octomap.OcTree(str(paths["octree"]).encode())  # the .bt constructor reads binary files
    assert tree.getResolution() == pytest.approx(RES)
    coords, occupancy = occupied_leaves(tree)
    assert len(coords) == len(vx.centres)
    np.testing.assert_array_equal(np.sort(voxels.pack(coords)),
                                  np.sort(voxels.pack(voxels.voxel_coords(vx.centres, RES))))

    o3d = pytest.importorskip("open3d")
    pcd = o3d.io.read_point_cloud(str(paths["octree_semantic"]))
    assert len(pcd.points) == len(vx.centres) and pcd.has_colors()
    np.testing.assert_allclose(np.asarray(pcd.colors), CLASS_COLOURS[vx.labels] / 255.0, atol=1e-6)

    v = read_vertex_ply(paths["octree_semantic"])
    np.testing.assert_allclose(xyz_of(v), vx.centres, atol=1e-6)
    np.testing.assert_array_equal(v["label"], vx.labels)
    np.testing.assert_allclose(v["occupancy"], vx.occupancy, atol=1e-6)

    legend = json.loads(paths["octree_classes"].read_text())
    assert legend["2"] == {"name": "floor", "colour": [152, 223, 138], "occupied_voxels": int((vx.labels == 2).sum()),
                           "possible": True}
    assert read_class_table(paths["octree_classes"])[31] == "person"  # what eval-map reads


def test_corrected_poses_rebuild_the_octree_where_the_keyframes_moved(tmp_path: Path) -> None:
    b = _built(person=False)
    before = b.voxels()
    online_tree = b.tree
    # Below the thresholds (0.5 mm): finish keeps the online octree.
    nudged = {i: T.copy() for i, T in enumerate(scene.poses())}
    for T in nudged.values():
        T[0, 3] += 0.0005
    b.correct_poses(nudged)
    assert not b.needs_rebuild()
    b.finish(tmp_path / "kept")
    assert b.tree is online_tree
    # Every keyframe moved by 5 voxels along x: the map moves with them.
    shift = np.array([5 * RES, 0.0, 0.0])
    moved = {i: T.copy() for i, T in enumerate(scene.poses())}
    for T in moved.values():
        T[:3, 3] += shift
    b.correct_poses(moved)
    assert b.needs_rebuild()
    paths = b.finish(tmp_path / "moved")
    assert b.tree is not online_tree
    after_xyz = xyz_of(read_vertex_ply(paths["octree_semantic"]))
    expected = voxels.pack(voxels.voxel_coords(before.centres + shift, RES))
    got = voxels.pack(voxels.voxel_coords(after_xyz, RES))
    # The same voxels shifted, but for points that sit on a voxel boundary in float32.
    assert len(np.intersect1d(expected, got)) > 0.995 * max(len(expected), len(got))
    np.testing.assert_allclose(after_xyz.mean(axis=0), before.centres.mean(axis=0) + shift, atol=2e-3)


def test_pose_moved_thresholds() -> None:
    T = scene.pose()
    small = T.copy()
    small[:3, 3] += [0.0009, 0.0, 0.0]
    assert not pose_moved(T, small)
    big = T.copy()
    big[:3, 3] += [0.0011, 0.0, 0.0]
    assert pose_moved(T, big)
    a = np.radians(0.06)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    turned = T.copy()
    turned[:3, :3] = rot @ T[:3, :3]
    assert pose_moved(T, turned) and not pose_moved(T, scene.pose(pitch_deg=20.04))


def test_occupied_leaves_expand_pruned_nodes_like_octomap() -> None:
    tree = octomap.OcTree(RES)
    block = np.array([[i, j, k] for i in range(4) for j in range(4) for k in range(4)], float) * RES + RES / 2
    for _ in range(10):  # hits until every voxel is clamped: OctoMap prunes the 4x4x4 block
        for p in block:
            tree.updateNode(p, True)
    tree.updateNode(np.array([1.0, 1.0, 1.0]), True)  # one more, lone voxel
    tree.updateInnerOccupancy()
    assert tree.getNumLeafNodes() < 65  # merged: fewer leaves than voxels
    coords, occupancy = occupied_leaves(tree)
    reference, _ = tree.extractPointCloud()  # the library's own expansion
    assert len(coords) == 65 and (occupancy > 0.5).all()
    np.testing.assert_array_equal(np.sort(voxels.pack(coords)), np.sort(voxels.pack(voxels.voxel_coords(reference, RES))))


@pytest.mark.parametrize("appear_free_below", [0.0, 0.3])
def test_a_mover_appearing_in_known_free_space_is_not_inserted(appear_free_below: float) -> None:
    """The keyframes first see the empty room (rays through where the person will stand),
    then the person walks in, unmasked: with the rule on, none of them enter the octree."""
    cfg = MapsConfig(octree_resolution_m=RES, octree_appear_free_below=appear_free_below)
    b = SemanticOctree(cfg)
    poses = scene.poses()
    for i, T in enumerate(poses):
        b.add_keyframe(scene.snapshot(i, T, person=False))
    for i, T in enumerate(poses):
        b.add_keyframe(scene.snapshot(len(poses) + i, T, person=True, mask_person=False))
    vx = b.voxels()
    ghosts = int(_in_person_box(vx.centres).sum())
    if appear_free_below > 0:
        assert ghosts <= 5, ghosts
        static = _built(person=False).voxels()  # the room itself is all there
        assert len(vx.centres) >= 0.97 * len(static.centres)
    else:
        assert ghosts > 150
