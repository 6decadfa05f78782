"""Voxel arithmetic shared by the octree and the semantic cloud: functions of arrays only.

Voxel coordinates follow OctoMap's ``coordToKey``: ``floor(x / size)`` of the point as a
float32 (OctoMap stores points as floats), so a voxel here is the octree's leaf that the
same point lands in. Packed keys put the three coordinates in one int64 (21 bits each) so
that ``np.unique`` groups voxels fast.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


def voxel_coords(points: NDArray[np.floating], size: float) -> NDArray[np.int64]:
    """Integer voxel coordinates (N, 3) of points (N, 3), OctoMap's rounding."""
    p = np.asarray(points, np.float32).astype(np.float64)
    return np.floor(p * (1.0 / size)).astype(np.int64)


def voxel_centres(coords: NDArray[np.int64], size: float) -> NDArray[np.float64]:
    """Centres of integer voxel coordinates (N, 3)."""
    return (coords.astype(np.float64) + 0.5) * size


def pack(coords: NDArray[np.int64]) -> NDArray[np.int64]:
    """One int64 per voxel; ValueError beyond ±2^20 voxels (±52 km at 5 cm)."""
    c = coords + _OFFSET
    if len(c) and (c.min() < 0 or c.max() > _MASK):
        raise ValueError(f"voxel coordinates beyond ±{_OFFSET} voxels cannot be packed")
    return (c[:, 0] << (2 * _BITS)) | (c[:, 1] << _BITS) | c[:, 2]


def unpack(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """Inverse of ``pack``: (N, 3) voxel coordinates."""
    return np.stack([(keys >> (2 * _BITS)) & _MASK, (keys >> _BITS) & _MASK, keys & _MASK], axis=1) - _OFFSET


def sum_votes(keys: NDArray[np.int64], classes: NDArray[np.integer], weights: NDArray[np.floating] | None
              ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Total weight per distinct (voxel key, class) pair: (keys, classes, weights), sorted by key.
    Unit weights when ``weights`` is None."""
    cls = np.asarray(classes, np.int64)
    w = np.ones(len(keys)) if weights is None else np.asarray(weights, np.float64)
    if len(keys) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    order = np.lexsort((cls, keys))
    k, c, w = keys[order], cls[order], w[order]
    start = np.ones(len(k), bool)
    start[1:] = (k[1:] != k[:-1]) | (c[1:] != c[:-1])
    first = np.flatnonzero(start)
    return k[first], c[first], np.add.reduceat(w, first)


def majority(keys: NDArray[np.int64], classes: NDArray[np.integer], weights: NDArray[np.floating] | None,
             unknown: int = 0) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per distinct voxel key (sorted): the class with the largest total weight.

    ``unknown`` votes are an absence of evidence, not a class: they win a voxel only when it
    has no other vote. Ties go to the lower class index (deterministic)."""
    k, c, w = sum_votes(keys, classes, weights)
    if len(k) == 0:
        return k, c
    w = np.where(c == unknown, -1.0, w)  # any real vote outranks unknown
    # Within each voxel: highest weight last, and among equal weights the lowest class last.
    order = np.lexsort((-c, w, k))
    k, c = k[order], c[order]
    last = np.ones(len(k), bool)
    last[:-1] = k[1:] != k[:-1]
    return k[last], c[last]
