"""Rendered views of a map's point cloud for the HTML report: a top-down view (coloured by
class where the cloud has labels, else by colour) and a perspective view.

The world is SLAM's (the first camera: x right, y down, z forward), so "up" is -y and the
top-down view shows the x-z plane seen from above, higher points drawn over lower ones.
Plots use matplotlib's Agg canvas directly (no pyplot state), like ``eval/report.py``.

PLY input: ``x y z red green blue`` vertices, optionally a ``label`` (class id) per vertex
(``semantic_cloud.ply``); ``keyframe_cloud.ply`` has no labels.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.viz.palette import class_colour, class_colours, class_name

#: The clouds the report looks for in OUT/map/, best first.
CLOUD_FILES = ("semantic_cloud.ply", "keyframe_cloud.ply")
#: Points drawn per view (a random subset beyond this: the view looks the same, Agg is faster).
MAX_POINTS = 120_000


@dataclass
class Cloud:
    xyz: NDArray[np.float64]
    rgb: NDArray[np.uint8]
    labels: NDArray[np.int64] | None = None


def read_cloud(path: str | Path) -> Cloud:
    """A coloured (optionally labelled) point cloud from a PLY file; DataError naming the
    file when it cannot be read or lacks x y z red green blue."""
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    try:
        vertex = PlyData.read(str(path))["vertex"]
    except (OSError, KeyError, ValueError, EOFError, PlyParseError) as exc:
        raise DataError(path, f"cannot read a PLY point cloud ({exc})") from None
    names = set(vertex.data.dtype.names or ())
    missing = [f for f in ("x", "y", "z", "red", "green", "blue") if f not in names]
    if missing:
        raise DataError(path, f"PLY vertices lack {', '.join(missing)}")
    xyz = np.stack([vertex[a] for a in "xyz"], axis=1).astype(np.float64)
    rgb = np.stack([vertex[c] for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
    labels = np.asarray(vertex["label"]).astype(np.int64) if "label" in names else None
    return Cloud(xyz, rgb, labels)


def find_cloud(map_dir: str | Path) -> Path | None:
    """The map's cloud the report shows: the semantic cloud, else the keyframe cloud."""
    for name in CLOUD_FILES:
        if (Path(map_dir) / name).is_file():
            return Path(map_dir) / name
    return None


def _subset(cloud: Cloud, max_points: int, seed: int = 0) -> Cloud:
    if len(cloud.xyz) <= max_points:
        return cloud
    keep = np.sort(np.random.default_rng(seed).choice(len(cloud.xyz), max_points, replace=False))
    return Cloud(cloud.xyz[keep], cloud.rgb[keep], None if cloud.labels is None else cloud.labels[keep])


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def top_down_raster(xz: NDArray[np.float64], height: NDArray[np.float64], colours: NDArray[np.uint8],
                    cell_m: float) -> tuple[NDArray[np.float64], tuple[float, float, float, float]]:
    """An RGBA image of square ``cell_m`` cells over the x-z extent, each cell the colour of
    its highest point (what is seen from above; transparent where no point falls), and its
    extent (x0, x1, z0, z1) for ``imshow(origin="lower")``."""
    lo = xz.min(axis=0)
    n = np.floor((xz.max(axis=0) - lo) / cell_m).astype(int) + 1
    ij = np.minimum(np.floor((xz - lo) / cell_m).astype(int), n - 1)
    cell = ij[:, 1] * n[0] + ij[:, 0]
    order = np.argsort(-height, kind="stable")
    _, first = np.unique(cell[order], return_index=True)  # the highest point of every cell
    top = order[first]
    img = np.zeros((n[1], n[0], 4))
    img[ij[top, 1], ij[top, 0], :3] = colours[top] / 255.0
    img[ij[top, 1], ij[top, 0], 3] = 1.0
    return img, (lo[0], lo[0] + n[0] * cell_m, lo[1], lo[1] + n[1] * cell_m)


def top_down_png(cloud: Cloud, pixels: int = 400, min_cell_m: float = 0.02) -> bytes:
    """x-z seen from above (-y up), class colours with a legend of the commonest classes
    when labelled, the points' own colours otherwise. Cells are the extent / ``pixels``,
    at least ``min_cell_m`` (about the clouds' own spacing, so surfaces show no holes)."""
    c = cloud
    fig = Figure(figsize=(7, 6.5))
    ax = fig.add_subplot(1, 1, 1)
    if len(c.xyz):
        xz = c.xyz[:, [0, 2]]
        cell = max(float(np.ptp(xz, axis=0).max()) / pixels, min_cell_m)
        colours = class_colours(c.labels) if c.labels is not None else c.rgb
        img, extent = top_down_raster(xz, -c.xyz[:, 1], colours, cell)
        ax.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    if c.labels is not None and len(c.labels):
        ids, counts = np.unique(c.labels, return_counts=True)
        for i in ids[np.argsort(-counts)][:12]:
            ax.scatter([], [], color=np.array(class_colour(int(i))) / 255.0, s=30, label=class_name(i))
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title("top-down (x-z, seen from above)" + (", by class" if c.labels is not None else ""))
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def perspective_png(cloud: Cloud, max_points: int = MAX_POINTS, elev: float = 25.0, azim: float = -60.0) -> bytes:
    """The cloud in its own colours from above and to the side (matplotlib 3-D axes), far
    points drawn first (matplotlib has no depth buffer)."""
    c = _subset(cloud, max_points)
    p = np.column_stack([c.xyz[:, 0], c.xyz[:, 2], -c.xyz[:, 1]])  # plot axes: x, depth, up
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    if len(p):
        e, a = np.radians(elev), np.radians(azim)
        eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        span = np.maximum(np.ptp(p, axis=0), 1e-6)
        order = np.argsort(((p - p.min(axis=0)) / span) @ eye)  # toward the eye last
        ax.scatter(*p[order].T, c=c.rgb[order] / 255.0, s=1.5, marker=".", linewidths=0, depthshade=False)
        ax.set_box_aspect(tuple(np.maximum(span, 0.05 * span.max())))
    ax.view_init(elev=elev, azim=azim)
    ax.zaxis.set_major_locator(MaxNLocator(3))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_zlabel("up (-y) [m]")
    ax.set_title("perspective")
    fig.tight_layout()
    return _png(fig)


def write_views(cloud_path: str | Path, out_dir: str | Path | None = None) -> dict[str, Path]:
    """``map_top.png`` and ``map_perspective.png`` of a PLY cloud, next to it by default."""
    cloud_path = Path(cloud_path)
    out = Path(out_dir) if out_dir is not None else cloud_path.parent
    out.mkdir(parents=True, exist_ok=True)
    cloud = read_cloud(cloud_path)
    paths = {"map_top": out / "map_top.png", "map_perspective": out / "map_perspective.png"}
    paths["map_top"].write_bytes(top_down_png(cloud))
    paths["map_perspective"].write_bytes(perspective_png(cloud))
    return paths
