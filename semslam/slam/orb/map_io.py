"""Save and load a map (keyframes with features, map points, spanning tree, loop edges)
as one compressed ``.npz`` file, so a later run can relocalise in it.

Covisibility is not stored: it is recomputed from the observations on load. The feature
spec (descriptor kind and size, pyramid) is stored, and a map only loads into a run whose
extractor makes the same features.

Format 2 (issue 13): ``meta`` carries a SHA-256 over every array (name, dtype, shape, bytes),
checked on load, so a file whose arrays were changed (and the zip CRCs recomputed) is refused
rather than loaded; and the archive is written entry by entry in a fixed order with a fixed
date, so the same map gives the same bytes (save -> load -> save is byte-identical).
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import semslam
from semslam.core.types import FeatureSpec, Keypoints
from semslam.errors import ConfigError, DataError
from semslam.slam.orb.map import KeyFrame, Map, update_normals_and_depths

FORMAT = "semslam-map-2"
#: How a zip archive (an .npz) starts: a file record, or the end record of an empty archive.
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


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
            "kf_loop_edges": np.array([(k.id, e.id) for k in kfs for e in sorted(k.loop_edges, key=lambda e: e.id)
                                       if not e.bad], np.int64).reshape(-1, 2),
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
                "loops": slam_map.n_loops, "features": _spec_meta(slam_map.spec), "sha256": arrays_sha256(arrays)}
    _write_npz(path, {"meta": np.array(json.dumps(meta, sort_keys=True)), **arrays})
    return path


#: Date stamped on every zip entry (the zip format's earliest), instead of the time of
#: writing that ``np.savez_compressed`` stamps: the same map gives the same bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """An ``.npz`` that ``np.load`` reads, one deflated ``NAME.npy`` entry per array in the
    given order, with fixed dates and permissions; written to a temporary name and renamed,
    so an interrupted save never leaves half a map under the final name."""
    tmp = path.with_name(path.name + ".part")
    with zipfile.ZipFile(tmp, "w") as zf:
        for name, array in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(array, order="C"), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compresslevel=6)
    tmp.replace(path)


def arrays_sha256(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over the map's arrays in ``_ARRAYS`` order: each one's name, dtype, shape and
    C-order bytes. Independent of the zip (compression, dates), so it says whether the
    numbers are the ones that were saved."""
    h = hashlib.sha256()
    for name in _ARRAYS:
        a = np.asarray(arrays[name], order="C")
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _spec_meta(spec: FeatureSpec) -> dict[str, object]:
    return {"kind": spec.kind.value, "dim": spec.dim, "scale_factor": spec.scale_factor,
            "n_levels": spec.n_levels}


#: Every array a map file holds, with its shape: numbers are sizes, letters name the counts
#: (K keyframes, N keypoints over all keyframes, P points, E loop edges, D descriptor size).
_ARRAYS: dict[str, tuple[object, ...]] = {
    "kf_id": ("K",), "kf_frame_index": ("K",), "kf_timestamp": ("K",), "kf_T_cw": ("K", 4, 4), "kf_parent": ("K",),
    "kf_n_keypoints": ("K",), "kf_loop_edges": ("E", 2),
    "kp_xy_raw": ("N", 2), "kp_xy": ("N", 2), "kp_octave": ("N",), "kp_response": ("N",), "kp_angle": ("N",),
    "kp_descriptors": ("N", "D"), "kp_depth": ("N",), "kp_ur": ("N",), "kp_point": ("N",),
    "pt_id": ("P",), "pt_pos": ("P", 3), "pt_descriptor": ("P", "D"), "pt_n_visible": ("P",), "pt_n_found": ("P",),
    "pt_ref_kf": ("P",), "pt_first_kf": ("P",),
}


def _read_map_file(path: Path) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    """The file's metadata and every array, read in full now: a truncated or damaged file
    (zip CRC-32 per array) fails here, as one DataError, not halfway through building a map."""
    if not path.is_file():
        raise DataError(path, "map file not found")
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise DataError(path, f"cannot read the map ({exc.strerror or exc})") from None
    if magic not in _ZIP_MAGIC:
        raise DataError(path, "not a semslam map (not the .npz archive --save-map writes)")
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise DataError(path, "not a semslam map (one .npy array, not the .npz archive --save-map writes)")
        with loaded as data:
            names = set(data.files)
            if "meta" not in names:
                raise DataError(path, "not a semslam map (no 'meta' entry; maps are written by --save-map)")
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta, dict):
                raise DataError(path, "not a semslam map (its 'meta' entry is not a JSON object)")
            _check_format(path, meta)
            missing = sorted(set(_ARRAYS) - names)
            if missing:
                raise DataError(path, f"damaged map: no {', '.join(missing)}")
            arrays = {name: data[name] for name in _ARRAYS}
    except DataError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error) as exc:
        raise DataError(path, f"truncated or damaged map ({_first_line(exc)})") from None
    return meta, arrays


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _check_format(path: Path, meta: dict[str, object]) -> None:
    fmt = meta.get("format")
    if fmt != FORMAT:
        written = meta.get("semslam_version")
        by = f" (written by semslam {written})" if written else ""
        raise DataError(path, f"unsupported map format {fmt!r}{by}; semslam {semslam.__version__} reads {FORMAT}")


def _check_checksum(path: Path, meta: dict[str, object], arrays: dict[str, np.ndarray]) -> None:
    """The arrays are the ones that were saved (the zip's CRCs only catch damage to the
    compressed bytes, not arrays rewritten with new CRCs)."""
    saved = meta.get("sha256")
    if not isinstance(saved, str):
        raise DataError(path, "damaged map: its 'meta' entry has no sha256 checksum")
    actual = arrays_sha256(arrays)
    if actual != saved:
        raise DataError(path, f"damaged map: the arrays' SHA-256 {actual[:12]}… does not match the "
                              f"{saved[:12]}… saved with them")


def _check_arrays(path: Path, arrays: dict[str, np.ndarray], spec: FeatureSpec) -> None:
    """Shapes, types and cross-references of the arrays agree, so building the map cannot
    index out of range."""
    n_kp = arrays["kf_n_keypoints"]
    if n_kp.ndim != 1 or (n_kp.size and n_kp.min() < 0):
        raise DataError(path, "damaged map: kf_n_keypoints is not a list of counts")
    sizes = {"K": len(arrays["kf_id"]) if arrays["kf_id"].ndim == 1 else -1, "N": int(n_kp.sum()),
             "P": len(arrays["pt_id"]) if arrays["pt_id"].ndim == 1 else -1,
             "E": len(arrays["kf_loop_edges"]), "D": spec.dim}
    for name, shape in _ARRAYS.items():
        want = tuple(sizes[d] if isinstance(d, str) else d for d in shape)
        a = arrays[name]
        if a.shape != want:
            raise DataError(path, f"damaged map: {name} has shape {a.shape}, expected {want}")
        if a.dtype.kind not in "iuf":
            raise DataError(path, f"damaged map: {name} holds {a.dtype}, not numbers")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise DataError(path, f"damaged map: {name} holds NaN or inf")
    if sizes["K"] == 0:
        raise DataError(path, "the map holds no keyframes (its run never initialised): nothing to relocalise in")
    kf_ids, pt_ids = arrays["kf_id"], arrays["pt_id"]
    if len(np.unique(kf_ids)) != len(kf_ids) or len(np.unique(pt_ids)) != len(pt_ids):
        raise DataError(path, "damaged map: keyframe or point ids repeat")
    kp_point, octave = arrays["kp_point"], arrays["kp_octave"]
    if kp_point.size and (kp_point.min() < -1 or kp_point.max() >= sizes["P"]):
        raise DataError(path, "damaged map: kp_point refers to points the map does not hold")
    if octave.size and (octave.min() < 0 or octave.max() >= spec.n_levels):
        raise DataError(path, f"damaged map: kp_octave outside the {spec.n_levels} pyramid levels")
    if arrays["kp_descriptors"].dtype != spec.dtype or arrays["pt_descriptor"].dtype != spec.dtype:
        raise DataError(path, f"damaged map: descriptors are {arrays['kp_descriptors'].dtype}, "
                              f"the features are {np.dtype(spec.dtype)}")


def load_map(path: str | Path, spec: FeatureSpec) -> Map:
    """Read a map written by :func:`save_map` into a run whose extractor makes ``spec``'s
    features (ConfigError if the map's are others: they could not be matched). A file that
    is not such a map, is truncated or damaged, or comes from another format version is one
    DataError naming it."""
    path = Path(path)
    meta, data = _read_map_file(path)
    # Maps written before the spec was stored hold ORB-SLAM's ORB features.
    saved = meta.get("features", {"kind": "binary", "dim": 32, "scale_factor": spec.scale_factor,
                                  "n_levels": spec.n_levels})
    if saved != _spec_meta(spec):
        raise ConfigError(f"--load-map: {path} holds {saved} features, this run's extractor makes "
                          f"{_spec_meta(spec)}")
    _check_checksum(path, meta, data)
    _check_arrays(path, data, spec)
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
    update_normals_and_depths(points, spec.pyramid.scales)
    loops = meta.get("loops", 0)
    m.n_loops = loops if isinstance(loops, int) else 0
    return m
