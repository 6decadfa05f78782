"""Rendering a whole synthetic sequence: scene, camera motion, people, sensor effects.

Each frame depends only on (config, frame index), with its own random streams, so frames
can be rendered in any order or in parallel and the output is byte-identical for the same
config.
"""

from __future__ import annotations

import functools
import json
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

import semslam
from semslam.synth import writer
from semslam.synth.atlas import Atlas, build_atlas
from semslam.synth.box_carry import carried_box
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.depth_noise import DEPTH_SCALE, Z_MAX, Z_MIN, kinect_depth
from semslam.synth.people import People
from semslam.synth.raycast import Buffers, Camera, cast_billboard, cast_box, sample_atlas
from semslam.synth.scene import Box, mover_box, static_boxes
from semslam.synth.sequences import SynthConfig

#: SynthConfig fields added after renders were first cached (absent there = default).
_ADDED_FIELDS = ("box_carrier",)
BLUR_SIGMA = 0.55  # optics/demosaicing softness; also anti-aliases geometry edges
VIGNETTE = 0.18  # relative darkening in the corners
NOISE_MARGIN = 48  # pixels of slack around the noise banks for random offsets


@dataclass
class Frame:
    rgb: NDArray[np.uint8]  # (H, W, 3) RGB
    depth: NDArray[np.uint16]  # (H, W) metres * 5000, 0 = none
    semantic: NDArray[np.uint8]  # (H, W) class ids
    z: NDArray[np.float32]  # exact z-depth (inf where nothing), for tests


@functools.lru_cache(maxsize=2)
def scene_for_seed(seed: int, carried: bool = False) -> tuple[list[Box], Atlas]:
    """Static boxes and the atlas, cached. The atlas also holds the mover's faces (after
    the static boxes) and, with ``carried``, the carried box's (last). The carried box
    casts no baked contact shadow (it does not stay where it stands at t = 0); the atlas
    of sequences without it is unchanged by its existence."""
    boxes = static_boxes()
    if not carried:
        return boxes, build_atlas(boxes + [mover_box(0.0)], seed)
    casters = boxes + [mover_box(0.0)]
    return boxes, build_atlas(casters + [carried_box(0.0)], seed, casters=casters)


class Renderer:
    """Renders frames of one :class:`SynthConfig`."""

    def __init__(self, cfg: SynthConfig) -> None:
        self.cfg = cfg.validate()
        fx, fy, cx, cy = cfg.intrinsics()
        self.cam = Camera(fx, fy, cx, cy, cfg.width, cfg.height)
        self.boxes, self.atlas = scene_for_seed(cfg.seed, cfg.box_carrier)
        self.times = np.arange(cfg.frames) / cfg.fps
        self.poses = camera_trajectory(cfg.motion, self.times, cfg.duration)
        self.people = People(
            cfg.people, cfg.people_mode, cfg.seed, cfg.people_dir, carrier=cfg.box_carrier
        )
        yy, xx = np.mgrid[0 : cfg.height, 0 : cfg.width].astype(np.float32)
        r2 = ((xx - cx) / (cfg.width / 2)) ** 2 + ((yy - cy) / (cfg.height / 2)) ** 2
        vig = (1.0 - VIGNETTE * r2 / 2.0).astype(np.float32)
        self.vignette = np.ascontiguousarray(np.repeat(vig[..., None], 3, axis=2))
        # Sensor noise is cut at random offsets out of two pre-drawn fields: drawing
        # ~1M normal samples per frame would cost more than the rest of the rendering.
        if cfg.noise:
            bank_rng = np.random.default_rng([cfg.seed, 99])
            shape = (2, cfg.height + NOISE_MARGIN, cfg.width + NOISE_MARGIN)
            self.rgb_noise = bank_rng.standard_normal(shape + (3,), dtype=np.float32)
            self.depth_noise = bank_rng.standard_normal(shape, dtype=np.float32)

    def render(self, i: int) -> Frame:
        cfg = self.cfg
        t = float(self.times[i])
        pose = self.poses[i]
        buf = Buffers(cfg.height, cfg.width)
        for box, table, ppm in zip(self.boxes, self.atlas.tables, self.atlas.ppm):
            cast_box(buf, self.cam, pose, box, table, ppm)
        if cfg.mover:
            k = len(self.boxes)  # the mover's atlas entry follows the static boxes
            cast_box(buf, self.cam, pose, mover_box(t), self.atlas.tables[k], self.atlas.ppm[k])
        if cfg.box_carrier:
            cast_box(buf, self.cam, pose, carried_box(t), self.atlas.tables[-1], self.atlas.ppm[-1])
        rgb8 = sample_atlas(self.atlas.levels, buf)
        for bb in self.people.billboards(t, pose[:3, 3]):
            cast_billboard(buf, rgb8, self.cam, pose, bb)
        rgb = cv2.GaussianBlur(rgb8, (0, 0), BLUR_SIGMA).astype(np.float32)
        rgb *= self.vignette
        rng = np.random.default_rng([cfg.seed, i, 5]) if cfg.noise else None
        depth_noise = None
        if rng is not None:  # read noise + shot noise
            rgb += (np.float32(1.2) + np.float32(0.012) * rgb) * self._noise(self.rgb_noise, rng)
            depth_noise = self._noise(self.depth_noise, rng)
        rgb += np.float32(0.5)
        np.clip(rgb, 0, 255, out=rgb)
        img = rgb.astype(np.uint8)
        depth = kinect_depth(buf.z, buf.cos, rng, depth_noise)
        return Frame(img, depth, buf.label, buf.z)

    def _noise(self, bank: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.float32]:
        """A frame-sized window of a noise bank at a random offset (with random flips)."""
        k = int(rng.integers(0, bank.shape[0]))
        dy, dx = (int(v) for v in rng.integers(0, NOISE_MARGIN, 2))
        win = bank[k, dy : dy + self.cfg.height, dx : dx + self.cfg.width]
        if rng.random() < 0.5:
            win = win[::-1]
        if rng.random() < 0.5:
            win = win[:, ::-1]
        return win


def _stamps(cfg: SynthConfig) -> tuple[list[str], list[str]]:
    """RGB at exactly ``fps``; depth 5..15 ms later with seeded jitter, like a Kinect."""
    t = cfg.start_time + np.arange(cfg.frames) / cfg.fps
    jitter = np.random.default_rng([cfg.seed, 17]).uniform(0.005, 0.015, cfg.frames)
    jitter = np.minimum(jitter, 0.45 / cfg.fps)  # stay nearest to the own RGB frame
    return [writer.stamp(v) for v in t], [writer.stamp(v) for v in t + jitter]


def render_sequence(
    cfg: SynthConfig, out_dir: str | Path, progress: bool = False, workers: int = 2
) -> Path:
    """Render ``cfg`` into a TUM RGB-D folder at ``out_dir``; return its path.

    ``workers`` frames are rendered concurrently in threads (numpy and OpenCV release the
    GIL); results do not depend on it.
    """
    out = Path(out_dir)
    renderer = Renderer(cfg)
    writer.prepare_dir(out)
    rgb_stamps, depth_stamps = _stamps(cfg)

    def job(i: int) -> int:
        fr = renderer.render(i)
        writer.write_png(out / "rgb" / f"{rgb_stamps[i]}.png", fr.rgb)
        writer.write_png(out / "depth" / f"{depth_stamps[i]}.png", fr.depth)
        writer.write_png(out / "semantic" / f"{rgb_stamps[i]}.png", fr.semantic)
        return i

    bar: Any = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.frames, unit="frame", desc=f"synth {out.name}", leave=False)
    try:
        if workers > 1:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                for _ in pool.map(job, range(cfg.frames)):
                    if bar is not None:
                        bar.update(1)
        else:
            for i in range(cfg.frames):
                job(i)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    writer.write_list(out / "rgb.txt", "color", rgb_stamps, "rgb")
    writer.write_list(out / "depth.txt", "depth", depth_stamps, "depth")
    writer.write_groundtruth(out / "groundtruth.txt", rgb_stamps, renderer.poses)
    writer.write_calib(out / "calib.txt", cfg.intrinsics())
    writer.write_json(out / "semantic" / "labels.json", writer.LABELS)
    writer.write_json(
        out / "sequence.json",
        {
            "generator": "semslam.synth",
            "semslam_version": semslam.__version__,
            "config": cfg.to_dict(),
            "people_source": renderer.people.source,
            "intrinsics": list(cfg.intrinsics()),
            "depth_scale": DEPTH_SCALE,
            "depth_range_m": [Z_MIN, Z_MAX],
            "depth_rendered_at": "rgb timestamp (registered to the RGB camera)",
            "labels": writer.LABELS,
        },
    )
    return out


def needs_render(seq_dir: Path, cfg: SynthConfig) -> bool:
    """True unless ``seq_dir`` holds this exact configuration, completely rendered."""
    meta = seq_dir / "sequence.json"
    if not meta.is_file() or not (seq_dir / "groundtruth.txt").is_file():
        return True
    try:
        saved = json.loads(meta.read_text())
    except (OSError, json.JSONDecodeError):
        return True
    wanted = json.loads(json.dumps(asdict(cfg)))
    have = saved.get("config", saved)
    if not isinstance(have, dict):
        return True
    # Fields added to SynthConfig later are absent from older renders: at their default
    # they do not change the images, so such a render is still this configuration.
    defaults = json.loads(json.dumps(asdict(SynthConfig())))
    have = {**{k: v for k, v in defaults.items() if k not in have and k in _ADDED_FIELDS}, **have}
    return have != wanted


def ensure_rendered(cfg: SynthConfig, seq_dir: str | Path, progress: bool = False) -> bool:
    """Render ``cfg`` into ``seq_dir`` unless it is already there; True if it rendered."""
    seq_dir = Path(seq_dir)
    if not needs_render(seq_dir, cfg):
        return False
    render_sequence(cfg, seq_dir, progress=progress)
    return True
