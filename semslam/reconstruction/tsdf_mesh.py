"""A coloured triangle mesh of the static scene: the keyframes' depth fused into a TSDF
(Open3D's tensor ``VoxelBlockGrid``) and meshed by marching cubes at the end.

Pixels the dynamic stage left unknown (``snapshot.dynamic``, what background inpainting
could not fill) and, by default, pixels invented by image inpainting (``synthesized``) get
depth 0, so people leave no surface behind. Filled pixels (static background seen by earlier
keyframes) are integrated like observed ones.

Each keyframe's masked depth (uint16 mm), colour and pose are kept: loop closing and
bundle adjustment move keyframes after they were integrated, and a TSDF cannot move what it
has fused, so ``finish`` integrates every keyframe again with its final pose when any pose
moved by more than 1 mm or 0.05 deg; otherwise the grid built online is meshed as it is.

Camera model: the depth is integrated with the pinhole intrinsics, lens distortion ignored.
For TUM fr1/fr2 the depth images are registered to the colour camera by the sensor driver
(a pinhole model), and the colour camera's distortion coefficients do not describe them:
TUM recommends using the depth without undistortion. The synthetic, Bonn and ICL sequences
have no distortion, so nothing changes for them.

Images are kept and integrated every ``stride``-th pixel (intrinsics divided by ``stride``):
by default the largest stride at which one pixel at ``max_depth_m`` still spans at most one
voxel, since the TSDF cannot resolve finer (2 cm voxels, 4 m, f = 525 px: stride 2).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.config import MapsConfig
from semslam.core.protocols import KeyframeSnapshot
from semslam.geometry.camera import PinholeCamera
from semslam.reconstruction.backproject import pose_moved

log = logging.getLogger(__name__)

#: Truncation distance in voxels (the config says: 4 voxels).
TRUNC_VOXELS = 4.0
#: Voxels per block edge: 8 (16 cm blocks at 2 cm) keeps the voxels allocated around thin
#: surfaces few; Open3D preallocates ``block_count`` blocks (1000 x 8^3 x 20 B = 10 MB) and
#: grows the hash map as the scene does.
BLOCK_RESOLUTION = 8


# ---------------------------------------------------------------------------- pure helpers
def default_stride(camera: PinholeCamera, voxel_m: float, max_depth_m: float) -> int:
    """The largest pixel stride at which a pixel at ``max_depth_m`` spans at most one voxel."""
    f = min(camera.fx, camera.fy)
    return max(1, int(voxel_m * f / max_depth_m))


def strided_intrinsics(camera: PinholeCamera, stride: int) -> NDArray[np.float64]:
    """K of the image sampled every ``stride``-th pixel: pixel u' is pixel stride * u', so
    fx' = fx / stride and cx' = cx / stride exactly."""
    return np.array([[camera.fx / stride, 0.0, camera.cx / stride],
                     [0.0, camera.fy / stride, camera.cy / stride],
                     [0.0, 0.0, 1.0]])


def masked_depth_mm(snapshot: KeyframeSnapshot, stride: int, max_depth_m: float,
                    include_synthesized: bool = False) -> NDArray[np.uint16]:
    """The keyframe's depth in millimetres every ``stride``-th pixel, 0 where it must not be
    integrated: no measurement, beyond ``max_depth_m``, unknown (dynamic), synthesised."""
    assert snapshot.depth is not None
    depth = snapshot.depth[::stride, ::stride]
    keep = np.isfinite(depth) & (depth > 0) & (depth <= max_depth_m)
    if snapshot.dynamic is not None:
        keep &= ~snapshot.dynamic[::stride, ::stride]
    if snapshot.synthesized is not None and not include_synthesized:
        keep &= ~snapshot.synthesized[::stride, ::stride]
    mm = np.zeros(depth.shape, np.uint16)
    mm[keep] = np.round(depth[keep] * 1000.0).astype(np.uint16)
    return mm


# ---------------------------------------------------------------------------- the builder
@dataclass
class _Kept:
    """What re-integration needs of one keyframe."""

    depth_mm: NDArray[np.uint16]
    rgb: NDArray[np.uint8]
    K: NDArray[np.float64]
    T_wc_integrated: NDArray[np.float64] | None  # None: not in the online grid
    T_wc: NDArray[np.float64]

    @property
    def nbytes(self) -> int:
        return self.depth_mm.nbytes + self.rgb.nbytes


class TsdfMesh:
    """``MapBuilder``: a TSDF of the keyframes' static depth, written as ``mesh.ply``."""

    def __init__(self, cfg: MapsConfig | None = None, stride: int | None = None,
                 include_synthesized: bool = False, min_weight: float = 2.0) -> None:
        """``min_weight``: a voxel is meshed once at least this many keyframes saw it, which
        drops the flying pixels a single keyframe sees at depth edges."""
        cfg = cfg or MapsConfig()
        self.voxel_m = cfg.mesh_voxel_m
        self.max_depth_m = cfg.max_depth_m
        self.stride = stride
        self.include_synthesized = include_synthesized
        self.min_weight = min_weight
        self._kept: dict[int, _Kept] = {}
        # Open3D is imported (0.5-2 s) and the grid made now, when the System is built, not in
        # the tracking thread at the first keyframe.
        self._grid = self._new_grid()
        self.integrate_ms: list[float] = []

    # ------------------------------------------------------------------ MapBuilder contract
    def add_keyframe(self, snapshot: KeyframeSnapshot) -> None:
        if snapshot.depth is None:
            return
        stride = self.stride or default_stride(snapshot.camera, self.voxel_m, self.max_depth_m)
        kept = _Kept(masked_depth_mm(snapshot, stride, self.max_depth_m, self.include_synthesized),
                     np.ascontiguousarray(snapshot.rgb[::stride, ::stride]),
                     strided_intrinsics(snapshot.camera, stride), None, snapshot.T_wc.copy())
        self._kept[snapshot.keyframe_id] = kept
        t0 = time.perf_counter()
        if self._grid is None:  # closed
            self._grid = self._new_grid()
        self._integrate(self._grid, kept)
        kept.T_wc_integrated = kept.T_wc
        self.integrate_ms.append((time.perf_counter() - t0) * 1e3)

    def correct_poses(self, poses_wc: dict[int, NDArray[np.float64]]) -> None:
        for kf_id, T in poses_wc.items():
            if kf_id in self._kept:
                self._kept[kf_id].T_wc = np.asarray(T, np.float64).copy()

    def finish(self, out_dir: Path) -> dict[str, Path]:
        """Mesh the grid (re-integrated with the final poses when any moved) into ``mesh.ply``."""
        import open3d as o3d

        if not self._kept:
            log.warning("mesh: no keyframe with depth was integrated; no mesh.ply written")
            return {}
        if self._grid is None or self.needs_reintegration():
            self._grid = self._new_grid()
            for kept in self._kept.values():
                self._integrate(self._grid, kept)
                kept.T_wc_integrated = kept.T_wc
        mesh = self.mesh()
        if not mesh.has_vertices():  # a short run: no voxel seen by enough keyframes (a one-frame sequence)
            log.warning("mesh: no surface was seen by %g keyframes or more; no mesh.ply written",
                        self.min_weight)
            return {}
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "mesh.ply"
        if not o3d.io.write_triangle_mesh(str(path), mesh):
            raise OSError(f"{path}: Open3D could not write the mesh")
        return {"mesh": path}

    def close(self) -> None:
        self._kept.clear()
        self._grid = None

    # ------------------------------------------------------------------ the rest
    def needs_reintegration(self) -> bool:
        """Whether any keyframe moved since it was integrated (or was never integrated)."""
        return any(k.T_wc_integrated is None or pose_moved(k.T_wc_integrated, k.T_wc) for k in self._kept.values())

    def mesh(self):  # -> open3d.geometry.TriangleMesh (legacy), Open3D imported lazily
        """The current grid's surface as a legacy Open3D mesh (vertex colours in [0, 1])."""
        assert self._grid is not None
        return self._grid.extract_triangle_mesh(weight_threshold=self.min_weight).to_legacy()

    @property
    def kept_bytes(self) -> int:
        """Memory held for re-integration (depth + colour of every keyframe)."""
        return sum(k.nbytes for k in self._kept.values())

    def _new_grid(self):  # -> open3d.t.geometry.VoxelBlockGrid
        import open3d as o3d
        import open3d.core as o3c

        return o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=self.voxel_m, block_resolution=BLOCK_RESOLUTION, block_count=1000,
            device=o3c.Device("CPU:0"))

    def _integrate(self, grid, kept: _Kept) -> None:
        import open3d as o3d
        import open3d.core as o3c

        if not kept.depth_mm.any():  # all masked: nothing to fuse (Open3D wants >= 1 block)
            return

        depth = o3d.t.geometry.Image(o3c.Tensor(kept.depth_mm))
        color = o3d.t.geometry.Image(o3c.Tensor(kept.rgb))
        K = o3c.Tensor(kept.K, o3c.float64)
        T_cw = o3c.Tensor(np.linalg.inv(kept.T_wc), o3c.float64)
        blocks = grid.compute_unique_block_coordinates(depth, K, T_cw, 1000.0, self.max_depth_m, TRUNC_VOXELS)
        grid.integrate(blocks, depth, color, K, T_cw, 1000.0, self.max_depth_m, TRUNC_VOXELS)
