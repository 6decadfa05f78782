"""Point clouds as binary PLY vertex lists (through ``plyfile``), with any per-point fields.

The maps write x y z (float), red green blue (uchar) and their own scalar fields (``label``,
``occupancy``, ...): Open3D reads the positions and colours and skips the rest, CloudCompare
shows every other property as a scalar field, and ``read_vertex_ply`` gives them all back::

    v = read_vertex_ply(path)
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1); labels = v["label"]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError


def write_vertex_ply(path: Path, columns: dict[str, NDArray[np.generic]]) -> None:
    """One vertex per row; each column keeps its dtype (float32, uint8, int32 ...)."""
    from plyfile import PlyData, PlyElement

    n = {len(a) for a in columns.values()}
    if len(n) > 1:
        raise ValueError(f"PLY columns of different lengths: { {k: len(a) for k, a in columns.items()} }")
    rows = np.empty(n.pop() if n else 0, dtype=[(name, np.asarray(a).dtype.newbyteorder("<")) for name, a in columns.items()])
    for name, a in columns.items():
        rows[name] = a
    path.parent.mkdir(parents=True, exist_ok=True)
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))


def read_vertex_ply(path: Path) -> dict[str, NDArray[np.generic]]:
    """Every vertex property of a PLY file by name; DataError naming the file if unreadable."""
    from plyfile import PlyData

    try:
        v = PlyData.read(str(path))["vertex"]
    except (OSError, KeyError, ValueError) as exc:
        raise DataError(path, f"cannot read the PLY vertices ({exc})") from None
    return {p.name: np.asarray(v[p.name]) for p in v.properties}


def xyz_of(vertices: dict[str, NDArray[np.generic]]) -> NDArray[np.float64]:
    """(N, 3) positions of ``read_vertex_ply``'s result."""
    return np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1).astype(np.float64)
