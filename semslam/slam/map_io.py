"""Save and load a map (keyframes with features, map points, spanning tree, loop edges)
as one compressed ``.npz`` file, so a later run can relocalise in it.

Covisibility is not stored: it is recomputed from the observations on load. The feature
spec (descriptor kind and size, pyramid) is stored, and a map only loads into a run whose
extractor makes the same features.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import semslam
from semslam.core.types import FeatureSpec, Keypoints
from semslam.errors import ConfigError, DataError
from semslam.slam.map import KeyFrame, Map

FORMAT = "semslam-map-1"


def save_map(slam_map: Map, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with slam_map.lock:
        kfs = slam_map.all_keyframes()
        pts = [p for p in slam_map.points.values() if not p.bad]
        pid_index = {p.id: i for i, p in enumerate(pts)}
        counts = np.array([len(k.keypoints) for k in kfs], np.int64)
        point_of_kp = np.concatenate([
            np.array([pid_index.get(p.id, -1) if p is not None and not p.bad else -1 for p in k.points], np.int64)
            for k in kfs]) if kfs else np.zeros(0, np.int64)
        kf_ids = np.array([k.id for k in kfs], np.int64)
        arrays = {
            "kf_id": kf_ids,
            "kf_frame_index": np.array([k.frame_index for k in kfs], np.int64),
            "kf_timestamp": np.array([k.timestamp for k in kfs], np.float64),
            "kf_T_cw": np.stack([k.T_cw for k in kfs]) if kfs else np.zeros((0, 4, 4)),
            "kf_parent": np.array([k.parent.id if k.parent is not None and not k.parent.bad else -1 for k in kfs], np.int64),
            "kf_n_keypoints": counts,
            "kf_loop_edges": np.array([(k.id, e.id) for k in kfs for e in k.loop_edges if not e.bad], np.int64).reshape(-1, 2),
            "kp_xy_raw": np.concatenate([k.keypoints.xy for k in kfs]) if kfs else np.zeros((0, 2), np.float32),
            "kp_xy": np.concatenate([k.xy for k in kfs]) if kfs else np.zeros((0, 2)),
            "kp_octave": np.concatenate([k.keypoints.octave for k in kfs]) if kfs else np.zeros(0, np.int32),
            "kp_response": np.concatenate([k.keypoints.response for k in kfs]) if kfs else np.zeros(0, np.float32),
            "kp_angle": np.concatenate([k.keypoints.angle for k in kfs]) if kfs else np.zeros(0, np.float32),
            "kp_descriptors": (np.concatenate([k.keypoints.descriptors for k in kfs]) if kfs
                               else np.zeros((0, slam_map.spec.dim), slam_map.spec.dtype)),
            "kp_depth": np.concatenate([k.depth for k in kfs]) if kfs else np.zeros(0, np.float32),
            "kp_ur": np.concatenate([k.ur for k in kfs]) if kfs else np.zeros(0),
            "kp_point": point_of_kp,
            "pt_id": np.array([p.id for p in pts], np.int64),
            "pt_pos": np.array([p.pos for p in pts]).reshape(-1, 3),
            "pt_descriptor": np.array([p.descriptor for p in pts],
                                      slam_map.spec.dtype).reshape(-1, slam_map.spec.dim),
            "pt_n_visible": np.array([p.n_visible for p in pts], np.int64),
            "pt_n_found": np.array([p.n_found for p in pts], np.int64),
            "pt_ref_kf": np.array([p.ref_kf.id for p in pts], np.int64),
            "pt_first_kf": np.array([p.first_kf_id for p in pts], np.int64),
        }
        meta = {"format": FORMAT, "semslam_version": semslam.__version__, "keyframes": len(kfs), "points": len(pts),
                "loops": slam_map.n_loops, "features": _spec_meta(slam_map.spec)}
    with open(path, "wb") as f:
        np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays)
    return path


def _spec_meta(spec: FeatureSpec) -> dict[str, object]:
    return {"kind": spec.kind.value, "dim": spec.dim, "scale_factor": spec.scale_factor,
            "n_levels": spec.n_levels}


def load_map(path: str | Path, spec: FeatureSpec) -> Map:
    """Read a map written by :func:`save_map` into a run whose extractor makes ``spec``'s
    features (ConfigError if the map's are others: they could not be matched)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "map file not found")
    try:
        data = np.load(path, allow_pickle=False)
        meta = json.loads(str(data["meta"]))
    except (OSError, ValueError, KeyError) as exc:
        raise DataError(path, f"not a semslam map ({exc})") from None
    if meta.get("format") != FORMAT:
        raise DataError(path, f"unsupported map format {meta.get('format')!r} (expected {FORMAT})")
    # Maps written before the spec was stored hold ORB-SLAM's ORB features.
    saved = meta.get("features", {"kind": "binary", "dim": 32, "scale_factor": spec.scale_factor,
                                  "n_levels": spec.n_levels})
    if saved != _spec_meta(spec):
        raise ConfigError(f"--load-map: {path} holds {saved} features, this run's extractor makes "
                          f"{_spec_meta(spec)}")
    m = Map(spec)
    offsets = np.r_[0, np.cumsum(data["kf_n_keypoints"])]
    kfs: dict[int, KeyFrame] = {}
    for i, kid in enumerate(data["kf_id"]):
        a, b = offsets[i], offsets[i + 1]
        kps = Keypoints(data["kp_xy_raw"][a:b], data["kp_octave"][a:b], data["kp_response"][a:b], data["kp_angle"][a:b],
                        data["kp_descriptors"][a:b])
        kf = KeyFrame(int(kid), int(data["kf_frame_index"][i]), float(data["kf_timestamp"][i]), data["kf_T_cw"][i].copy(),
                      kps, data["kp_xy"][a:b], data["kp_depth"][a:b], data["kp_ur"][a:b], [None] * (b - a))
        m.add_keyframe(kf)
        kfs[int(kid)] = kf
    points = []
    for j, pid in enumerate(data["pt_id"]):
        ref = kfs.get(int(data["pt_ref_kf"][j]))
        if ref is None:
            ref = next(iter(kfs.values()))
        p = m.new_point(data["pt_pos"][j], data["pt_descriptor"][j].copy(), ref)
        p.id = int(pid)
        p.n_visible, p.n_found = int(data["pt_n_visible"][j]), int(data["pt_n_found"][j])
        p.first_kf_id = int(data["pt_first_kf"][j])
        points.append(p)
    m.points = {p.id: p for p in points}
    m._next_pt = (max(m.points) + 1) if m.points else 0
    m._next_kf = (max(kfs) + 1) if kfs else 0
    for i, kid in enumerate(data["kf_id"]):
        kf = kfs[int(kid)]
        for k, j in enumerate(data["kp_point"][offsets[i]:offsets[i + 1]]):
            if j >= 0:
                kf.points[k] = points[j]
                points[j].add_observation(kf, k)
        parent = int(data["kf_parent"][i])
        if parent >= 0 and parent in kfs:
            kf.parent = kfs[parent]
            kfs[parent].children.add(kf)
    for a, b in data["kf_loop_edges"]:
        if int(a) in kfs and int(b) in kfs:
            kfs[int(a)].loop_edges.add(kfs[int(b)])
    for kf in m.all_keyframes():
        kf.update_connections()
    for p in points:
        p.update_normal_and_depth(spec.pyramid.scales)
    m.n_loops = int(meta.get("loops", 0))
    return m
