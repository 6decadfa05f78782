"""Ground-truth geometry of a rendered synthetic sequence, for scoring maps against it.

Why: a map built from a synthetic sequence (points, voxels) can be scored against the
exact scene: how far its points lie from the true static surfaces and which class they
should carry (accuracy), how much of the surfaces it covers (completeness, from points
sampled on them), and how much of it lies where a person or a mover passed (ghosts).

``render_sequence`` writes two files that this module defines and reads:

- ``scene.json``: the static boxes (the room, seen from inside, and the furniture), each
  with centre, size, rotation (box to world), ``inside`` flag and the label id
  (100 + NYU-40 id) of each face in the order +x, -x, +y, -y, +z, -z of the box frame;
- ``movers.json``: per frame (rgb timestamp), the world axis-aligned box of every person
  and mover.

Both are in the world frame of ``groundtruth.txt`` (whose camera-to-world poses are those
the frames were rendered with): x right of the rest view, y away from it, z up, floor z=0.
Distances are analytic (point to oriented rectangle), vectorised over points and faces.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from semslam.core.labels import NYU40_CLASSES, SYNTH_STATIC_OFFSET
from semslam.errors import DataError
from semslam.synth.scene import Box

F64 = NDArray[np.float64]

SCENE_FILE = "scene.json"
MOVERS_FILE = "movers.json"
FORMAT = 1
FACE_ORDER = ("+x", "-x", "+y", "-y", "+z", "-z")
WORLD_FRAME = (
    "world frame of groundtruth.txt (camera-to-world poses): x right of the rest view, "
    "y away from it, z up, floor at z = 0; metres"
)
#: Points per block in :meth:`StaticGeometry.distance` (bounds memory: block x boxes x 6).
_BLOCK = 4096
#: Contact tolerance (m): a face point this close to another solid is hidden by it.
_CONTACT = 1e-4


# --------------------------------------------------------------------------- writing


def _floats(v: Any) -> list[Any]:
    return np.asarray(v, dtype=np.float64).tolist()


def scene_json(boxes: Sequence[Box]) -> dict[str, Any]:
    """The content of ``scene.json`` for the static ``boxes`` (the room among them)."""
    labels = sorted({c for b in boxes for c in b.classes})
    room = next((b for b in boxes if b.inside), None)
    return {
        "format": FORMAT,
        "frame": WORLD_FRAME,
        "face_order": list(FACE_ORDER),
        "labels": {str(i): NYU40_CLASSES[i - SYNTH_STATIC_OFFSET] for i in labels},
        "room": None
        if room is None
        else {"min": _floats(room.center - room.half), "max": _floats(room.center + room.half)},
        "boxes": [
            {
                "name": b.name,
                "center": _floats(b.center),
                "size": _floats(b.size),
                "rotation": _floats(b.rot),
                "inside": bool(b.inside),
                "face_classes": [int(c) for c in b.classes],
            }
            for b in boxes
        ],
    }


def movers_json(
    stamps: Sequence[str], per_frame: Sequence[Sequence[dict[str, Any]]]
) -> dict[str, Any]:
    """The content of ``movers.json``: per frame stamp, boxes ``{name, label, min, max}``."""
    return {
        "format": FORMAT,
        "frame": WORLD_FRAME,
        "frames": [
            {
                "stamp": s,
                "movers": [
                    {
                        "name": str(m["name"]),
                        "label": int(m["label"]),
                        "min": [round(float(v), 6) for v in m["min"]],
                        "max": [round(float(v), 6) for v in m["max"]],
                    }
                    for m in movers
                ],
            }
            for s, movers in zip(stamps, per_frame, strict=True)
        ],
    }


# --------------------------------------------------------------------------- static scene


@dataclass(frozen=True)
class StaticGeometry:
    """The static boxes as arrays: ``center``/``half`` (B, 3), ``rot`` (B, 3, 3) box to
    world, ``inside`` (B,) for the room, ``face_classes`` (B, 6) label ids."""

    names: tuple[str, ...]
    center: F64
    half: F64
    rot: F64
    inside: NDArray[np.bool_]
    face_classes: NDArray[np.int64]
    labels: dict[int, str]

    def _local(self, points: F64) -> F64:
        """Points (n, 3) in every box frame: (n, B, 3)."""
        return np.einsum("nbk,bkj->nbj", points[:, None, :] - self.center[None], self.rot)

    def distance(
        self, points: Any, classes: Iterable[int] | None = None
    ) -> tuple[F64, NDArray[np.int64]]:
        """Unsigned distance (m) from each point (N, 3) to the nearest static surface
        (a face of a furniture box or an inner face of the room) and that face's label id.

        ``classes`` restricts the surfaces to faces of these label ids (e.g. "how far is
        this point from the nearest wall"). Contact faces hidden by other boxes count.
        """
        p = _points(points)
        ok = np.ones(self.face_classes.shape, bool)
        if classes is not None:
            ok = np.isin(self.face_classes, np.fromiter(classes, np.int64))
            if not ok.any():
                raise ValueError(f"no static face has a class in {sorted(set(classes))}")
        flat_cls = self.face_classes.ravel()
        dist = np.empty(len(p))
        cls = np.empty(len(p), np.int64)
        for s in range(0, len(p), _BLOCK):
            q = self._local(p[s : s + _BLOCK])
            d2 = _face_dist2(q, self.half)
            d2[:, ~ok] = np.inf
            flat = d2.reshape(len(q), -1)
            best = np.argmin(flat, axis=1)
            dist[s : s + len(q)] = np.sqrt(flat[np.arange(len(q)), best])
            cls[s : s + len(q)] = flat_cls[best]
        return dist, cls

    def sample_surface(
        self, spacing_m: float, include_hidden: bool = False
    ) -> tuple[F64, NDArray[np.int64]]:
        """Points (M, 3) on every static face, at the centres of a grid of about
        ``spacing_m`` (each face split into ceil(side / spacing) cells per side), and their
        label ids (M,).

        Contact areas no camera can see (a box's base on the floor or desk, the wall behind
        a cabinet, faces inside another box) are left out unless ``include_hidden``.
        """
        if not spacing_m > 0:
            raise ValueError(f"spacing must be > 0, got {spacing_m}")
        pts, cls, owner = [], [], []
        for b in range(len(self.names)):
            h = self.half[b]
            for f, name in enumerate(FACE_ORDER):
                k = "xyz".index(name[1])
                j1, j2 = [j for j in range(3) if j != k]
                n1, n2 = (max(1, int(np.ceil(2 * h[j] / spacing_m))) for j in (j1, j2))
                u = -h[j1] + (np.arange(n1) + 0.5) * (2 * h[j1] / n1)
                v = -h[j2] + (np.arange(n2) + 0.5) * (2 * h[j2] / n2)
                uu, vv = np.meshgrid(u, v, indexing="ij")
                q = np.empty((uu.size, 3))
                q[:, k] = h[k] if name[0] == "+" else -h[k]
                q[:, j1], q[:, j2] = uu.ravel(), vv.ravel()
                pts.append(self.center[b] + q @ self.rot[b].T)
                cls.append(np.full(len(q), self.face_classes[b, f], np.int64))
                owner.append(np.full(len(q), b))
        points, classes, boxes = np.vstack(pts), np.concatenate(cls), np.concatenate(owner)
        if include_hidden:
            return points, classes
        keep = np.ones(len(points), bool)
        for s in range(0, len(points), _BLOCK):
            q = self._local(points[s : s + _BLOCK])
            gap = np.linalg.norm(np.maximum(np.abs(q) - self.half, 0.0), axis=2)  # to each solid
            depth_in = np.min(self.half - np.abs(q), axis=2)  # > 0: strictly inside
            own = boxes[s : s + _BLOCK, None] == np.arange(len(self.names))[None]
            solid = ~self.inside[None] & ~own
            hidden = np.any(solid & (gap <= _CONTACT), axis=1)
            # a furniture face lying on the room's boundary is against a wall or the floor
            room = self.inside[None] & ~own
            hidden |= np.any(room & (depth_in <= _CONTACT), axis=1)
            keep[s : s + len(q)] = ~hidden
        return points[keep], classes[keep]


def _points(points: Any) -> F64:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {p.shape}")
    return p


def _face_dist2(q: F64, half: F64) -> F64:
    """Squared distance from box-frame points ``q`` (n, B, 3) to the six face rectangles
    of each box: (n, B, 6) in +x, -x, +y, -y, +z, -z order. The face x = +h_x is the set
    {x = h_x, |y| <= h_y, |z| <= h_z}: the offset along x, plus how far y and z stick out."""
    out = np.maximum(np.abs(q) - half, 0.0) ** 2
    rest = out.sum(axis=2, keepdims=True) - out  # the other two axes, per axis
    d2 = np.empty(q.shape[:2] + (6,))
    d2[..., 0::2] = (q - half) ** 2 + rest
    d2[..., 1::2] = (q + half) ** 2 + rest
    return np.maximum(d2, 0.0)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(
            path, "not found (rendered by `semslam synth`; older renders lack it: render again)"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(path, f"cannot read ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise DataError(path, f"not a semslam synth file of format {FORMAT}")
    return data


def _array(path: Path, items: list[Any], key: str, shape: tuple[int, ...]) -> F64:
    try:
        arr = np.array([it[key] for it in items], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise DataError(path, f"every entry needs a numeric {key!r}") from None
    if arr.shape[1:] != shape or not np.all(np.isfinite(arr)):
        raise DataError(
            path, f"{key!r} must be finite with shape {shape} per entry, got {arr.shape[1:]}"
        )
    return arr


def load_static_geometry(seq_dir: str | Path) -> StaticGeometry:
    """The static scene of a rendered sequence, from its ``scene.json``."""
    path = Path(seq_dir) / SCENE_FILE
    data = _read_json(path)
    boxes = data.get("boxes")
    if not isinstance(boxes, list) or not boxes:
        raise DataError(path, "no 'boxes' list")
    center = _array(path, boxes, "center", (3,))
    size = _array(path, boxes, "size", (3,))
    rot = _array(path, boxes, "rotation", (3, 3))
    classes = _array(path, boxes, "face_classes", (6,)).astype(np.int64)
    if np.any(size <= 0):
        raise DataError(path, "box sizes must be > 0")
    if not np.allclose(np.einsum("bij,bik->bjk", rot, rot), np.eye(3), atol=1e-6):
        raise DataError(path, "rotations must be orthonormal")
    labels = {int(k): str(v) for k, v in data.get("labels", {}).items()}
    unknown = sorted(set(classes.ravel().tolist()) - set(labels))
    if unknown:
        raise DataError(path, f"face classes {unknown} are not named in 'labels'")
    return StaticGeometry(
        names=tuple(str(b.get("name", "")) for b in boxes),
        center=center,
        half=size / 2.0,
        rot=rot,
        inside=np.array([bool(b.get("inside", False)) for b in boxes]),
        face_classes=classes,
        labels=labels,
    )


# --------------------------------------------------------------------------- movers


@dataclass(frozen=True)
class MoverBoxes:
    """Every mover's box in every frame: ``lo``/``hi`` (M, 3) world corners, ``label``
    (M,) (15 person, 21 mover), ``frame`` (M,) index into ``stamps``."""

    stamps: tuple[str, ...]
    lo: F64
    hi: F64
    label: NDArray[np.int64]
    frame: NDArray[np.int64]

    def boxes(self) -> list[tuple[F64, F64]]:
        """(min xyz, max xyz) of every mover in every frame."""
        return list(zip(self.lo, self.hi))

    def in_any_mover(self, points: Any, margin: float = 0.0) -> NDArray[np.bool_]:
        """Whether each point (N, 3) lies in a box some mover occupied in some frame
        (boxes grown by ``margin`` metres). People stand on the floor, so floor points
        under their feet are inside too: leave out points on static surfaces first."""
        p = _points(points)
        mask = np.zeros(len(p), bool)
        if not len(self.lo):
            return mask
        lo, hi = self.lo - margin, self.hi + margin
        cand = np.flatnonzero(np.all((p >= lo.min(0)) & (p <= hi.max(0)), axis=1))
        pc, hit = p[cand], np.zeros(len(cand), bool)
        for a, b in zip(lo, hi):
            hit |= np.all((pc >= a) & (pc <= b), axis=1)
        mask[cand] = hit
        return mask


def load_movers(seq_dir: str | Path) -> MoverBoxes:
    """The movers' boxes of a rendered sequence, from its ``movers.json``."""
    path = Path(seq_dir) / MOVERS_FILE
    data = _read_json(path)
    frames = data.get("frames")
    if not isinstance(frames, list):
        raise DataError(path, "no 'frames' list")
    stamps, items, index = [], [], []
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("movers"), list):
            raise DataError(path, f"frame {i}: expected {{'stamp', 'movers': [...]}}")
        stamps.append(str(fr.get("stamp", "")))
        items += fr["movers"]
        index += [i] * len(fr["movers"])
    if not items:
        empty = np.zeros((0, 3))
        return MoverBoxes(tuple(stamps), empty, empty, np.zeros(0, np.int64), np.zeros(0, np.int64))
    lo, hi = _array(path, items, "min", (3,)), _array(path, items, "max", (3,))
    if np.any(hi < lo):
        raise DataError(path, "a mover box has max < min")
    label = np.array([int(it.get("label", 0)) for it in items], np.int64)
    return MoverBoxes(tuple(stamps), lo, hi, label, np.array(index, np.int64))


def mover_boxes(seq_dir: str | Path) -> list[tuple[F64, F64]]:
    """(min xyz, max xyz) of every person and mover in every frame of a rendered sequence."""
    return load_movers(seq_dir).boxes()
