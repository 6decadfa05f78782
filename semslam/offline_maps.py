"""Rebuilding the maps of a finished run (``semslam map RUN_OUT``), without tracking again.

A run leaves its final keyframe poses (``keyframes.txt``, after loop closing and global BA),
its config (``config.json``) and the sequence it read (``stats.json``). The keyframes'
images are read again from the sequence, their dynamic masks recomputed as the run's
config says (segmentation + SRM; the multi-view check against the previous keyframes,
which stand in for the covisible ones the live run used) and fed, in order and with the
final poses, to the same mapping worker a live run uses. So a user can change the maps'
settings (resolution, which maps) and rebuild in seconds per keyframe.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.assembly import pair_depth
from semslam.config import SystemConfig, config_from_dict
from semslam.core.protocols import FramePacket, KeyframeSnapshot
from semslam.core.types import Frame
from semslam.dynamics.stage import create_dynamic_stage
from semslam.errors import ConfigError, DataError
from semslam.frontend.stereo_depth import fill_frame_depth
from semslam.io.association import match_timestamps
from semslam.io.sequence import open_sequence
from semslam.io.trajectory import read_trajectory
from semslam.reconstruction.mapping_worker import MappingWorker

#: Pixel step of the depth grid that stands for a reference keyframe's keypoints in the
#: multi-view check (the live run used its ORB keypoints).
REFERENCE_GRID_PX = 8


def load_run(run_dir: Path, overrides: list[str] | None = None) -> tuple[SystemConfig, dict[str, Any]]:
    """The run's config (with ``--set`` overrides) and its stats; DataError naming what is missing."""
    for name in ("config.json", "stats.json", "keyframes.txt"):
        if not (run_dir / name).is_file():
            raise DataError(run_dir / name, "not found: give the output folder of a finished `semslam run`")
    try:
        config = json.loads((run_dir / "config.json").read_text())
        stats = json.loads((run_dir / "stats.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(run_dir, f"cannot read the run's config.json / stats.json ({exc})") from None
    return config_from_dict(config, str(run_dir / "config.json"), overrides), stats


def rebuild_maps(run_dir: Path, sequence_dir: Path | None = None, out_dir: Path | None = None,
                 overrides: list[str] | None = None,
                 progress: Callable[[int, int], None] | None = None) -> tuple[dict[str, Path], dict[str, float]]:
    """Write the maps of ``run_dir`` (into ``out_dir``, default ``run_dir/map``); returns the
    files written and the maps' counters."""
    cfg, stats = load_run(run_dir, overrides)
    if not cfg.maps.builders:
        raise ConfigError("no maps to build: the run's config has maps.builders empty; choose them with "
                          "--map octree,cloud,mesh")
    cfg.maps.save_inpainted = ""
    worker = MappingWorker(cfg.maps.builders, cfg.maps, threaded=False)
    try:
        for snap, done, total in keyframe_snapshots(run_dir, cfg, Path(sequence_dir or stats["sequence"])):
            worker.add_keyframe(snap)
            if progress is not None:
                progress(done, total)
        paths = worker.finish(out_dir or run_dir / "map")
        return paths, worker.stats()
    finally:
        worker.close()


def keyframe_snapshots(run_dir: Path, cfg: SystemConfig, sequence_dir: Path
                       ) -> Iterator[tuple[KeyframeSnapshot, int, int]]:
    """The run's keyframes in order, with their final poses and dynamic masks recomputed as
    ``cfg`` says: (snapshot, how many so far, how many in all)."""
    seq = open_sequence(sequence_dir, kind="stereo" if cfg.sensor == "stereo" else "auto", depth_scale=cfg.depth_scale)
    stereo_depth = pair_depth(cfg, seq.camera) if cfg.sensor == "stereo" else None
    keyframes = read_trajectory(run_dir / "keyframes.txt")
    index = _frame_indices(seq.timestamps, keyframes.timestamps, run_dir / "keyframes.txt")
    dynamics = create_dynamic_stage(cfg.dynamics, cfg.semantics, seq.camera, threaded=False)
    refs: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]] = []
    try:
        for k, (i, T_wc) in enumerate(zip(index, keyframes.poses)):
            frame = next(seq.frames(int(i), int(i) + 1))
            if stereo_depth is not None:  # a stereo run mapped the pair's depth
                fill_frame_depth(frame, stereo_depth)
            snap = _snapshot(k, frame, T_wc, dynamics, refs[-cfg.dynamics.multiview_keyframes:], seq.camera)
            if frame.depth is not None:
                refs.append(_reference(np.linalg.inv(T_wc), frame.depth, snap.dynamic))
            yield snap, k + 1, len(index)
    finally:
        if dynamics is not None:
            dynamics.close()


def _frame_indices(seq_stamps: NDArray[np.float64], kf_stamps: NDArray[np.float64], where: Path) -> NDArray[np.intp]:
    """The sequence frame of each keyframe (the same stamp: keyframes.txt keeps 6 decimals)."""
    i_kf, i_seq = match_timestamps(kf_stamps, seq_stamps, max_diff=1e-3)
    if len(i_kf) != len(kf_stamps):
        missing = np.setdiff1d(np.arange(len(kf_stamps)), i_kf)
        raise DataError(where, f"{len(missing)} keyframe timestamps are not frames of the sequence "
                               f"(first {kf_stamps[missing[0]]:.6f}): is it the sequence this run read?")
    return i_seq[np.argsort(i_kf)]


def _snapshot(k: int, frame: Frame, T_wc: NDArray[np.float64], dynamics: Any, refs: list[Any],
              camera: Any) -> KeyframeSnapshot:
    """The keyframe as the live run fed it: the semantic mask (+ SRM), the moving regions."""
    dynamic, labels = None, None
    if dynamics is not None:
        dynamics.prepare(frame)
        dynamic, _, _ = dynamics.before_extraction(FramePacket(frame))
        labels = dynamics.labels(frame.index)
        if frame.depth is not None and refs:
            regions = dynamics.after_pose(np.linalg.inv(T_wc), frame.depth, refs)
            if regions is not None:
                dynamic = regions.moving if dynamic is None else dynamic | regions.moving
    return KeyframeSnapshot(k, frame.timestamp, T_wc, frame.rgb, frame.depth, dynamic, labels, camera)


def _reference(T_cw: NDArray[np.float64], depth: NDArray[np.float32], dynamic: NDArray[np.bool_] | None
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]:
    """A keyframe as a multi-view reference: a grid of its static pixels with depth."""
    s = REFERENCE_GRID_PX
    d = depth[s // 2::s, s // 2::s]
    keep = np.isfinite(d) & (d > 0)
    if dynamic is not None:
        keep &= ~dynamic[s // 2::s, s // 2::s]
    v, u = np.nonzero(keep)
    xy = np.stack([u * s + s // 2, v * s + s // 2], axis=1).astype(np.float64)
    return T_cw, xy, d[v, u].astype(np.float32)
