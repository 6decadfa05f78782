"""The TSDF mesh builder against analytic geometry: a wall at z = 2.5 m and a box in front of
it, seen from several known poses with exact (ray-cast) depth. The mesh must lie on those
surfaces within a voxel, masked (dynamic or synthesised) pixels must leave no surface, and
moved keyframe poses must move the mesh (re-integration), while tiny moves keep the grid.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from semslam.config import MapsConfig
from semslam.core import registry
from semslam.core.protocols import KeyframeSnapshot, MapBuilder
from semslam.geometry.camera import PinholeCamera
from semslam.reconstruction.tsdf_mesh import TsdfMesh, default_stride, masked_depth_mm, pose_moved

W, H = 160, 120
CAM = PinholeCamera(130.0, 130.0, 79.5, 59.5, width=W, height=H)
VOXEL = 0.02
WALL_Z = 2.5
BOX_C, BOX_H = np.array([0.0, 0.1, 1.9]), np.array([0.25, 0.2, 0.2])  # centre, half sizes (m)
WALL_RGB, BOX_RGB = (200, 60, 40), (40, 90, 210)


def _pose(x: float, yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[0, 3] = x
    return T


POSES = [_pose(x, yaw) for x, yaw in ((-0.3, 6.0), (-0.1, 2.0), (0.1, -2.0), (0.3, -6.0))]


def _render(T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact z-depth, colour and box mask of the wall + box scene from camera pose ``T_wc``."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays_c = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u, float)], -1)  # z = 1
    d = rays_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    t_wall = (WALL_Z - o[2]) / d[..., 2]
    with np.errstate(divide="ignore"):  # slab test for the box
        t1, t2 = (BOX_C - BOX_H - o) / d, (BOX_C + BOX_H - o) / d
    t_near = np.minimum(t1, t2).max(-1)
    t_far = np.maximum(t1, t2).min(-1)
    box = (t_near <= t_far) & (t_near > 0)
    depth = np.where(box, t_near, t_wall).astype(np.float32)  # ray z-component is 1: t is z-depth
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[...] = WALL_RGB
    rgb[box] = BOX_RGB
    return depth, rgb, box


def _distance_to_scene(p: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
    """Unsigned distance of points to the wall or the box surface (both moved by ``shift``)."""
    p = p - (shift if shift is not None else 0.0)
    q = np.abs(p - BOX_C) - BOX_H
    box_sdf = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
    return np.minimum(np.abs(p[:, 2] - WALL_Z), np.abs(box_sdf))


def _snapshots(mask: str | None = None) -> list[KeyframeSnapshot]:
    snaps = []
    for k, T in enumerate(POSES):
        depth, rgb, box = _render(T)
        snap = KeyframeSnapshot(k, float(k), T, rgb, depth, None, None, CAM)
        if mask == "dynamic":
            snap.dynamic = box
        elif mask == "synthesized":
            snap.synthesized = box
        snaps.append(snap)
    return snaps


def _build(snaps: list[KeyframeSnapshot], **kwargs: object) -> TsdfMesh:
    builder = TsdfMesh(MapsConfig(mesh_voxel_m=VOXEL, max_depth_m=4.0), **kwargs)  # type: ignore[arg-type]
    for s in snaps:
        builder.add_keyframe(s)
    return builder


def test_registered_and_implements_the_contract() -> None:
    builder = registry.create("map_builder", "mesh", MapsConfig())
    assert isinstance(builder, TsdfMesh) and isinstance(builder, MapBuilder)


def test_pure_helpers() -> None:
    tum = PinholeCamera(525.0, 525.0, 319.5, 239.5)
    assert default_stride(tum, 0.02, 4.0) == 2  # 4 m * 2 / 525 px = 1.5 cm per pixel <= 2 cm
    assert default_stride(tum, 0.01, 4.0) == 1 and default_stride(CAM, 0.02, 4.0) == 1
    snap = _snapshots("dynamic")[0]
    mm = masked_depth_mm(snap, 1, 4.0)
    assert mm.dtype == np.uint16 and not mm[snap.dynamic].any()
    keep = ~snap.dynamic
    assert np.abs(mm[keep] / 1000.0 - snap.depth[keep]).max() <= 0.0005
    assert not masked_depth_mm(snap, 1, 2.0).any()  # the wall at 2.5 m is beyond max depth, the box is masked
    T = POSES[0]
    assert not pose_moved(T, T) and pose_moved(T, _pose(-0.3 + 0.002, 6.0))
    assert pose_moved(T, _pose(-0.3, 6.1)) and not pose_moved(T, _pose(-0.3 + 0.0005, 6.02))


def test_mesh_lies_on_the_surfaces_and_reopens(tmp_path: Path) -> None:
    builder = _build(_snapshots())
    paths = builder.finish(tmp_path)
    assert paths == {"mesh": tmp_path / "mesh.ply"}
    mesh = o3d.io.read_triangle_mesh(str(paths["mesh"]))
    v = np.asarray(mesh.vertices)
    assert len(mesh.triangles) > 1000
    err = _distance_to_scene(v)
    # Marching cubes on exact depth: planar faces within millimetres; rounded box edges within a voxel.
    assert np.median(err) < 0.1 * VOXEL and np.percentile(err, 99) < VOXEL and err.max() < 2 * VOXEL, (
        np.median(err), np.percentile(err, 99), err.max())
    # Both surfaces are there, with their colours.
    on_box = _distance_to_scene(v) < 0.005
    on_box &= np.abs(v[:, 2] - WALL_Z) > 0.05
    assert on_box.sum() > 200
    colours = np.asarray(mesh.vertex_colors) * 255
    assert np.abs(np.median(colours[on_box], axis=0) - BOX_RGB).max() < 3
    on_wall = np.abs(v[:, 2] - WALL_Z) < 0.005
    assert np.abs(np.median(colours[on_wall], axis=0) - WALL_RGB).max() < 3


@pytest.mark.parametrize("mask", ["dynamic", "synthesized"])
def test_masked_pixels_leave_no_surface(tmp_path: Path, mask: str) -> None:
    """The box (1.7-2.1 m) masked in every keyframe: no vertex in front of the wall, and the
    wall is meshed exactly as without the mask (masked pixels hold the box's depth, so they
    never said anything about the wall behind it). Control: synthesised pixels are
    integrated when asked for."""
    v = np.asarray(o3d.io.read_triangle_mesh(str(_build(_snapshots(mask)).finish(tmp_path)["mesh"])).vertices)
    assert len(v) > 1000
    assert (v[:, 2] < WALL_Z - 2 * VOXEL).sum() == 0
    v_full = np.asarray(_build(_snapshots()).mesh().vertices)
    wall_full = v_full[np.abs(v_full[:, 2] - WALL_Z) < VOXEL]
    assert len(v) == len(wall_full) and np.abs(np.sort(v, 0) - np.sort(wall_full, 0)).max() < 1e-6
    if mask == "synthesized":
        v_all = np.asarray(_build(_snapshots(mask), include_synthesized=True).mesh().vertices)
        assert len(v_all) == len(v_full)


def test_pose_correction_moves_the_mesh(tmp_path: Path) -> None:
    """Every keyframe moved by 5 cm in x and -10 cm in z (as a loop correction moves them):
    ``finish`` integrates again and the mesh lies on the moved scene; sub-millimetre moves
    keep the online grid."""
    shift = np.array([0.05, 0.0, -0.1])
    builder = _build(_snapshots())
    n_online = len(builder.mesh().vertices)
    T_shift = np.eye(4)
    T_shift[:3, 3] = shift
    builder.correct_poses({k: T_shift @ T for k, T in enumerate(POSES)})
    assert builder.needs_reintegration()
    v = np.asarray(o3d.io.read_triangle_mesh(str(builder.finish(tmp_path)["mesh"])).vertices)
    assert not builder.needs_reintegration()
    assert np.percentile(_distance_to_scene(v, shift), 99) < VOXEL
    assert np.median(_distance_to_scene(v)) > 0.09  # off the scene where it was (the wall moved 10 cm)
    assert abs(len(v) - n_online) < 0.2 * n_online

    tiny = _build(_snapshots())
    T_tiny = np.eye(4)
    T_tiny[:3, 3] = [0.0005, 0.0, 0.0]
    tiny.correct_poses({k: T_tiny @ T for k, T in enumerate(POSES)})
    assert not tiny.needs_reintegration()


def test_no_keyframes_writes_nothing(tmp_path: Path) -> None:
    builder = TsdfMesh()
    builder.add_keyframe(KeyframeSnapshot(0, 0.0, np.eye(4), np.zeros((H, W, 3), np.uint8), None, None, None, CAM))
    assert builder.finish(tmp_path) == {} and not (tmp_path / "mesh.ply").exists()


def test_no_surface_yet_writes_nothing(tmp_path: Path) -> None:
    """One keyframe where the builder wants more observations per voxel (a run of a few
    frames): no mesh.ply and no error (Open3D refuses to write an empty mesh)."""
    builder = TsdfMesh(MapsConfig(mesh_voxel_m=VOXEL, max_depth_m=4.0), min_weight=5.0)  # type: ignore[arg-type]
    builder.add_keyframe(_snapshots()[0])
    assert builder.finish(tmp_path) == {} and not (tmp_path / "mesh.ply").exists()
