"""Rendering a whole synthetic sequence: scene, camera motion, people, sensor effects.

Each frame depends only on (config, frame index), with its own random streams, so frames
can be rendered in any order or in parallel and the output is byte-identical for the same
config.

Besides the TUM folder, a sequence holds the ground truth for map metrics: ``scene.json``
(the static boxes and the class of each face) and ``movers.json`` (per frame, the boxes
the people and movers occupy), read by :mod:`semslam.synth.static_geometry`; with
``SynthConfig.background`` also ``background/rgb`` and ``background/depth``: every frame
without people and movers, the truth for inpainting.
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
from semslam.errors import ConfigError, DataError
from semslam.synth import euroc_writer, imaging, kitti_writer, occluder, stereo, writer
from semslam.synth.imu import SimulatedImu, simulate_imu
from semslam.synth.texture_atlas import TextureAtlas, build_texture_atlas
from semslam.synth.box_carry import carried_box
from semslam.synth.camera_motion import camera_trajectory
from semslam.synth.depth_noise import DEPTH_SCALE, Z_MAX, Z_MIN, kinect_depth
from semslam.synth.people import People
from semslam.synth.raycast import (
    Buffers,
    Camera,
    billboard_aabb,
    cast_billboard,
    cast_box,
    sample_atlas,
)
from semslam.synth.layouts import get_layout
from semslam.synth.scene import LABEL_PERSON, Box, mover_box
from semslam.synth.sequences import SynthConfig
from semslam.synth.static_geometry import MOVERS_FILE, SCENE_FILE, movers_json, scene_json

#: Written before a render's first frame and removed after its ``sequence.json``: what an
#: interrupted render was rendering, for ``render_sequence(resume=True)``.
IN_PROGRESS = ".rendering.json"
#: SynthConfig fields added after renders were first cached (absent there = default).
_ADDED_FIELDS = ("box_carrier", "background", "exposure_ms", "rolling_shutter_ms", "gain_swing", "depth_delay_ms",
                 "blackout_start_s", "blackout_s", "layout", "occluder_s", "occluder_start_s",
                 "occluder_kind", "white_balance_swing", "photo_textures", "stereo_baseline", "imu", "euroc_depth")
#: File layouts of a render: the TUM RGB-D folder (``rgb_right/`` added for stereo), EuRoC ASL or
#: KITTI odometry (stereo only).
LAYOUT_FORMATS = ("tum", "euroc", "kitti")
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
def scene_for_seed(seed: int, carried: bool = False, layout: int = 0,
                   photo_textures: str | None = None) -> tuple[list[Box], TextureAtlas]:
    """Static boxes of room ``layout`` and the atlas, cached. The atlas also holds the
    mover's faces (after the static boxes) and, with ``carried``, the carried box's (last).
    The carried box casts no baked contact shadow (it does not stay where it stands at
    t = 0); the atlas of sequences without it is unchanged by its existence."""
    room = get_layout(layout)
    boxes = room.boxes()
    if not carried:
        return boxes, build_texture_atlas(boxes + [mover_box(0.0)], seed, lights=room.lights,
                                          photo_textures=photo_textures)
    casters = boxes + [mover_box(0.0)]
    return boxes, build_texture_atlas(casters + [carried_box(0.0)], seed, casters=casters, lights=room.lights,
                                      photo_textures=photo_textures)


class Renderer:
    """Renders frames of one :class:`SynthConfig`."""

    def __init__(self, cfg: SynthConfig) -> None:
        self.cfg = cfg.validate()
        fx, fy, cx, cy = cfg.intrinsics()
        self.cam = Camera(fx, fy, cx, cy, cfg.width, cfg.height)
        self.boxes, self.atlas = scene_for_seed(cfg.seed, cfg.box_carrier, cfg.layout, cfg.photo_textures)
        self.times = np.arange(cfg.frames) / cfg.fps
        self.poses = camera_trajectory(cfg.motion, self.times, cfg.duration, cfg.seed)
        self.left_to_right = stereo.left_to_right(cfg.stereo_baseline)  # T_LR: right camera in the left's frame
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
        return self.render_with_background(i, background=False)[0]

    def render_with_background(self, i: int, background: bool = True) -> tuple[Frame, Frame | None]:
        """Frame ``i`` and, with ``background``, the same frame without people and movers.

        The background has the same RGB (same blur, vignette and noise draw, so it equals
        the frame wherever no mover is near) but exact depth: no noise and no holes, only
        the range limits and the 0.2 mm PNG step, because it is the truth for inpainting.
        It is rendered without the hard-imaging effects (``synth/imaging.py``).
        """
        cfg = self.cfg
        t = float(self.times[i])
        pose = self.poses[i]
        buf, rgb8, static = self._scene(t, pose, background)
        if self._hard:
            rgb8 = self._integrated_rgb(t, rgb8)
            delay = imaging.depth_delay_s(cfg.seed, i, cfg.depth_delay_ms / 1e3)
            if delay > 0:  # depth (and only depth) captured later, from where the camera is then
                later = self._pose_at(t + delay)
                depth_buf, _, _ = self._scene(t + delay, later, False)
                buf.z, buf.cos = depth_buf.z, depth_buf.cos
        img, rng, depth_noise, cover = self._exposed(t, i, rgb8)
        depth = kinect_depth(buf.z, buf.cos, rng, depth_noise)
        if cover is not None:
            depth = occluder.cover_depth(depth, cover[0])
        frame = Frame(img, depth, buf.label, buf.z)
        if self._blacked_out(t):  # lens covered
            frame = Frame(np.zeros_like(img), np.zeros_like(depth), buf.label, buf.z)
        if static is None:
            return frame, None
        bg_img, _, _ = self._sensor_rgb(sample_atlas(self.atlas.levels, static), i)
        bg_depth = kinect_depth(static.z, static.cos, None)
        return frame, Frame(bg_img, bg_depth, static.label, static.z)

    def render_right(self, i: int) -> Frame:
        """Frame ``i`` of the right camera of a stereo rig (``cfg.stereo_baseline``): the same
        scene state at the same instant (people face the left camera, the rig's reference),
        the same exposure, rolling shutter, gain, white balance, occluder and blackout, sensor
        noise from its own seeded stream. Its ``depth`` is exact (no depth sensor there)."""
        t = float(self.times[i])
        pose = self.poses[i]
        buf, rgb8, _ = self._scene(t, pose, False, eye=pose @ self.left_to_right)
        if self._hard:
            rgb8 = self._integrated_rgb(t, rgb8, right=True)
        # The occluder covers the whole rig, both lenses alike.
        img, _, _, _ = self._exposed(t, i, rgb8, stream=stereo.RIGHT_NOISE_STREAM)
        if self._blacked_out(t):
            img = np.zeros_like(img)
        return Frame(img, kinect_depth(buf.z, buf.cos, None), buf.label, buf.z)

    def _exposed(self, t: float, i: int, rgb8: NDArray[np.uint8], stream: int = 5
                 ) -> tuple[NDArray[np.uint8], Any, Any, tuple[NDArray[np.float32], NDArray[np.float32]] | None]:
        """What reaches the sensor at ``t``: the occluder over the scene, then the exposure gain
        and white balance, then the sensor (``_sensor_rgb`` with noise ``stream``); returns its
        image, noise generator and depth noise, and the occluder layer (None without one)."""
        cfg = self.cfg
        cover = self._occluder(t)
        if cover is not None:
            rgb8 = occluder.cover_rgb(rgb8, *cover)
        gain = imaging.exposure_gain(cfg.seed, t, cfg.gain_swing)
        gain = gain * imaging.white_balance_gains(cfg.seed, t, cfg.white_balance_swing)
        img, rng, depth_noise = self._sensor_rgb(rgb8, i, gain, stream=stream)
        return img, rng, depth_noise, cover

    def _blacked_out(self, t: float) -> bool:
        return self.cfg.blackout_start_s <= t < self.cfg.blackout_start_s + self.cfg.blackout_s

    def _occluder(self, t: float) -> tuple[NDArray[np.float32], NDArray[np.float32]] | None:
        """(alpha, colour) of what is over the lens at ``t``, or None."""
        start, end = self.cfg.occluder_window()
        if not start <= t < end:
            return None
        return occluder.occluder_layer(self.cfg.occluder_kind, self.cfg.seed, t - start,
                                       self.cfg.height, self.cfg.width)

    @property
    def _hard(self) -> bool:
        cfg = self.cfg
        return cfg.exposure_ms > 0 or cfg.rolling_shutter_ms > 0 or cfg.depth_delay_ms > 0

    def _pose_at(self, t: float) -> NDArray[np.float64]:
        return self.poses_at(np.array([t]))[0]

    def poses_at(self, times: NDArray[np.float64]) -> NDArray[np.float64]:
        """The (left) camera's T_WC at ``times`` (seconds from the first frame)."""
        return camera_trajectory(self.cfg.motion, np.asarray(times, np.float64), self.cfg.duration, self.cfg.seed)

    def _scene(self, t: float, pose: NDArray[np.float64], background: bool,
               eye: NDArray[np.float64] | None = None) -> tuple[Buffers, NDArray[np.uint8], Buffers | None]:
        """Everything at time ``t`` seen from ``pose``: the buffers (depth, labels), the
        textured RGB with people, and a copy of the static scene alone if asked. With ``eye``
        (a stereo rig's right camera) it is seen from there, the scene still that of ``pose``
        (people are billboards turned to it)."""
        cfg = self.cfg
        centre = pose[:3, 3]  # people face the rig's reference camera
        pose = pose if eye is None else eye
        buf = Buffers(cfg.height, cfg.width)
        for box, table, ppm in zip(self.boxes, self.atlas.tables, self.atlas.ppm):
            cast_box(buf, self.cam, pose, box, table, ppm)
        static = buf.copy() if background else None
        if cfg.mover:
            k = len(self.boxes)  # the mover's atlas entry follows the static boxes
            cast_box(buf, self.cam, pose, mover_box(t), self.atlas.tables[k], self.atlas.ppm[k])
        if cfg.box_carrier:
            cast_box(buf, self.cam, pose, carried_box(t), self.atlas.tables[-1], self.atlas.ppm[-1])
        rgb8 = sample_atlas(self.atlas.levels, buf)
        for bb in self.people.billboards(t, centre):
            cast_billboard(buf, rgb8, self.cam, pose, bb, centre)
        return buf, rgb8, static

    def _image_speed(self, t: float, span: float) -> float:
        """How fast the image moves around ``t`` (pixels per second, an upper estimate): the
        camera's rotation and its translation against a surface 1 m away over the window,
        and people walking (~1.4 m/s, 2 m away) when there are any."""
        a, b = camera_trajectory(self.cfg.motion, np.array([t - span / 2, t + span / 2]), self.cfg.duration,
                                 self.cfg.seed)
        rel = np.linalg.inv(a) @ b
        angle = float(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1.0, 1.0)))
        f = max(self.cam.fx, self.cam.fy)
        speed = f * (angle + float(np.linalg.norm(rel[:3, 3]))) / max(span, 1e-6)
        return max(speed, f * 0.7 if self.cfg.people or self.cfg.box_carrier or self.cfg.mover else 0.0)

    def _integrated_rgb(self, t: float, centre_rgb: NDArray[np.uint8], right: bool = False) -> NDArray[np.uint8]:
        """The RGB image exposed with the config's exposure and rolling-shutter readout (of the
        right camera with ``right``: same sub-frame times, shutters in sync)."""
        cfg = self.cfg
        exposure, readout = cfg.exposure_ms / 1e3, cfg.rolling_shutter_ms / 1e3
        offsets = imaging.sub_frame_offsets(exposure, readout, self._image_speed(t, exposure + readout))
        if len(offsets) == 1:
            return centre_rgb
        poses = self.poses_at(t + offsets)
        images = [self._scene(t + o, p, False, eye=p @ self.left_to_right if right else None)[1]
                  for o, p in zip(offsets, poses)]
        return imaging.blend_rows(images, imaging.row_weights(offsets, cfg.height, exposure, readout))

    def _sensor_rgb(
        self, rgb8: NDArray[np.uint8], i: int, gain: float | NDArray[np.float32] = 1.0, stream: int = 5
    ) -> tuple[NDArray[np.uint8], np.random.Generator | None, NDArray[np.float32] | None]:
        """Optics, exposure ``gain`` and sensor noise of frame ``i``: (RGB, the frame's random
        stream after the noise windows were drawn, the depth noise window); the same for any
        content. ``stream`` seeds the noise (another one for a stereo rig's right camera)."""
        rgb = cv2.GaussianBlur(rgb8, (0, 0), BLUR_SIGMA).astype(np.float32)
        rgb *= self.vignette
        if np.any(np.asarray(gain) != 1.0):  # a scalar, or per-channel gains (white balance)
            rgb *= np.asarray(gain, np.float32)
        rng = np.random.default_rng([self.cfg.seed, i, stream]) if self.cfg.noise else None
        depth_noise = None
        if rng is not None:  # read noise + shot noise
            rgb += (np.float32(1.2) + np.float32(0.012) * rgb) * self._noise(self.rgb_noise, rng)
            depth_noise = self._noise(self.depth_noise, rng)
        rgb += np.float32(0.5)
        np.clip(rgb, 0, 255, out=rgb)
        return rgb.astype(np.uint8), rng, depth_noise

    def mover_boxes(self, i: int) -> list[dict[str, Any]]:
        """World axis-aligned boxes of everything that moves in frame ``i`` (in view or
        not): each person's drawable volume, the mover, the carried box."""
        t = float(self.times[i])
        pose = self.poses[i]
        out: list[dict[str, Any]] = []
        for bb in self.people.billboards(t, pose[:3, 3]):
            box = billboard_aabb(bb, self.cam, pose)
            if box is not None:
                out.append({"name": "person", "label": LABEL_PERSON, "min": box[0], "max": box[1]})
        movers = ([mover_box(t)] if self.cfg.mover else []) + (
            [carried_box(t)] if self.cfg.box_carrier else []
        )
        for mb in movers:
            c = mb.corners()
            out.append({"name": mb.name, "label": mb.label, "min": c.min(0), "max": c.max(0)})
        return out

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


def _first_to_render(out: Path, cfg: SynthConfig, rgb_stamps: list[str], depth_stamps: list[str],
                     workers: int) -> int:
    """Where a resumed rendering starts: ``workers`` frames before the first frame with a file
    missing (frames are started in order and at most ``workers`` are in flight, so any frame
    whose last file an interruption may have cut short lies there), or 0 when ``out`` holds no
    rendering of the same configuration (finished: ``sequence.json``; interrupted: the
    :data:`IN_PROGRESS` file written before the first frame)."""
    have = saved_config(out, IN_PROGRESS) or saved_config(out)
    wanted = _as_saved(cfg)
    if have is None or {k: v for k, v in have.items() if k != "frames"} != {
            k: v for k, v in wanted.items() if k != "frames"}:
        return 0

    def complete(i: int) -> bool:
        names = [out / "rgb" / f"{rgb_stamps[i]}.png", out / "depth" / f"{depth_stamps[i]}.png",
                 out / "semantic" / f"{rgb_stamps[i]}.png"]
        if cfg.stereo_baseline > 0:
            names.append(out / stereo.RIGHT_DIR / f"{rgb_stamps[i]}.png")
        if cfg.background:
            names += [out / "background" / "rgb" / f"{rgb_stamps[i]}.png",
                      out / "background" / "depth" / f"{depth_stamps[i]}.png"]
        return all(n.is_file() for n in names)

    lo, hi = 0, cfg.frames  # frames [0, lo) complete; binary search for the first incomplete one
    while lo < hi:
        mid = (lo + hi) // 2
        if complete(mid):
            lo = mid + 1
        else:
            hi = mid
    return max(0, lo - max(1, workers))


def render_sequence(
    cfg: SynthConfig, out_dir: str | Path, progress: bool = False, workers: int = 2, resume: bool = False,
    layout_format: str = "tum",
) -> Path:
    """Render ``cfg`` into a TUM RGB-D folder at ``out_dir``; return its path.

    With ``cfg.stereo_baseline`` the right camera's images go to ``rgb_right/`` (listed in
    ``rgb_right.txt`` with the RGB stamps) and ``camera.yaml`` holds the rig as ORB-SLAM3
    settings (``synth/stereo.py``). ``layout_format="euroc"`` writes the EuRoC ASL layout
    instead (``synth/euroc_writer.py``: the cameras' images, no semantics, and the
    body's ground truth), with ``sequence.json``, ``scene.json`` and ``movers.json`` beside
    ``mav0``, and with ``cfg.imu`` a simulated 200 Hz IMU (``mav0/imu0``, ``synth/imu.py``) and
    with ``cfg.euroc_depth`` the depth registered to cam0 (``mav0/depth0``), both EuRoC only;
    ``layout_format="kitti"`` (a stereo render only) the KITTI odometry layout
    (``synth/kitti_writer.py``: grey ``image_0``/``image_1``, ``calib.txt``, ``times.txt`` and
    ``poses.txt`` relative to the first pose) in ``out_dir`` itself. Both render from the
    start (no ``resume``).

    ``workers`` frames are rendered concurrently in threads (numpy and OpenCV release the
    GIL); results do not depend on it. ``resume`` keeps the frames an earlier, interrupted or
    shorter, rendering of the same ``cfg`` left in ``out_dir`` (a frame depends on its index
    only, not on ``cfg.frames``) and renders from the first one missing: hours of rendering
    for a long benchmark are not lost to one interruption.
    """
    if layout_format not in LAYOUT_FORMATS:
        raise ConfigError(f"synth: unknown layout format {layout_format!r} (choose from {', '.join(LAYOUT_FORMATS)})")
    euroc, kitti = layout_format == "euroc", layout_format == "kitti"
    tum = not (euroc or kitti)
    if not tum and cfg.background:
        raise ConfigError(f"synth: background renders need the tum layout format ({layout_format} has no "
                          "background folder)")
    if not euroc and (cfg.imu or cfg.euroc_depth):
        what = "an IMU (--imu)" if cfg.imu else "depth0 (--depth)"
        raise ConfigError(f"synth: {what} is written in the euroc layout format only (--layout-format euroc), "
                          f"not {layout_format}")
    if kitti and cfg.stereo_baseline <= 0:
        raise ConfigError("synth: the kitti layout format is a stereo pair (image_0, image_1): it needs a stereo "
                          "baseline (--stereo-baseline METRES)")
    out = Path(out_dir)
    marks = {"tum": "rgb.txt", "euroc": euroc_writer.MAV, "kitti": kitti_writer.IMAGE_DIRS[0]}
    for other in (out / name for fmt, name in marks.items() if fmt != layout_format):
        if other.exists():  # two layouts in one folder would be read as whichever a reader tries first
            raise DataError(other, f"the output folder holds a render in another layout; {layout_format} "
                                   "renders go to a folder without it")
    renderer = Renderer(cfg)
    has_right = cfg.stereo_baseline > 0
    rgb_stamps, depth_stamps = _stamps(cfg)
    ns = euroc_writer.ns_stamps(cfg.start_time, cfg.frames, cfg.fps)
    first = _first_to_render(out, cfg, rgb_stamps, depth_stamps, workers) if resume and tum else 0
    imu = (simulate_imu(renderer.poses_at, euroc_writer.T_BS_CAM0, cfg.frames, cfg.fps, cfg.start_time, cfg.seed,
                        noisy=cfg.noise) if cfg.imu else None)
    if euroc:
        out.mkdir(parents=True, exist_ok=True)
        euroc_writer.prepare(out, 2 if has_right else 1, imu=cfg.imu, depth=cfg.euroc_depth)
    elif kitti:
        kitti_writer.prepare(out)
    elif first == 0:
        writer.prepare_dir(out, background=cfg.background, right=has_right)
    writer.write_json(out / IN_PROGRESS, {"config": cfg.to_dict()})

    def job(i: int) -> int:
        if euroc:  # left and right RGB, and the depth registered to cam0 if asked
            fr = renderer.render(i)
            euroc_writer.write_frame(out, 0, int(ns[i]), fr.rgb)
            if cfg.euroc_depth:
                euroc_writer.write_depth_frame(out, int(ns[i]), fr.depth)
            if has_right:
                euroc_writer.write_frame(out, 1, int(ns[i]), renderer.render_right(i).rgb)
            return i
        if kitti:  # grey left and right only
            kitti_writer.write_frame(out, 0, i, renderer.render(i).rgb)
            kitti_writer.write_frame(out, 1, i, renderer.render_right(i).rgb)
            return i
        fr, bg = renderer.render_with_background(i, cfg.background)
        if has_right:
            writer.write_png(out / stereo.RIGHT_DIR / f"{rgb_stamps[i]}.png", renderer.render_right(i).rgb)
        writer.write_png(out / "rgb" / f"{rgb_stamps[i]}.png", fr.rgb)
        writer.write_png(out / "depth" / f"{depth_stamps[i]}.png", fr.depth)
        writer.write_png(out / "semantic" / f"{rgb_stamps[i]}.png", fr.semantic)
        if bg is not None:  # same names as rgb/ and depth/
            writer.write_png(out / "background" / "rgb" / f"{rgb_stamps[i]}.png", bg.rgb)
            writer.write_png(out / "background" / "depth" / f"{depth_stamps[i]}.png", bg.depth)
        return i

    bar: Any = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.frames, initial=first, unit="frame", desc=f"synth {out.name}", leave=False)
    try:
        if workers > 1:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                for _ in pool.map(job, range(first, cfg.frames)):
                    if bar is not None:
                        bar.update(1)
        else:
            for i in range(first, cfg.frames):
                job(i)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    labels = writer.labels_for(renderer.boxes)
    if euroc:
        euroc_writer.write_layout(out, ns, renderer.poses, renderer.poses_at, renderer.times, cfg.intrinsics(),
                                  cfg.width, cfg.height, cfg.fps, cfg.stereo_baseline, imu=imu,
                                  depth=cfg.euroc_depth)
    elif kitti:
        kitti_writer.write_layout(out, renderer.times, renderer.poses, cfg.intrinsics(), cfg.stereo_baseline)
    else:
        writer.write_list(out / "rgb.txt", "color", rgb_stamps, "rgb")
        writer.write_list(out / "depth.txt", "depth", depth_stamps, "depth")
        writer.write_groundtruth(out / "groundtruth.txt", rgb_stamps, renderer.poses)
        writer.write_calib(out / "calib.txt", cfg.intrinsics())
        writer.write_json(out / "semantic" / "labels.json", labels)
    if has_right and tum:
        writer.write_list(out / stereo.RIGHT_LIST, "right color", rgb_stamps, stereo.RIGHT_DIR)
        stereo.write_settings(out / stereo.SETTINGS_FILE, cfg.intrinsics(), cfg.width, cfg.height, cfg.fps,
                              cfg.stereo_baseline)
    writer.write_json(out / SCENE_FILE, scene_json(renderer.boxes))
    movers = [renderer.mover_boxes(i) for i in range(cfg.frames)]
    writer.write_json(out / MOVERS_FILE, movers_json(rgb_stamps, movers), indent=None)
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
            "depth_rendered_at": (
                f"rgb timestamp + {imaging.DELAY_MIN_SHARE:.0%}-100 % of {cfg.depth_delay_ms} ms, seeded "
                "per frame (depth.txt stamps do not say so: an uncalibrated depth-colour offset)"
                if cfg.depth_delay_ms > 0 else "rgb timestamp (registered to the RGB camera)"),
            "labels": labels,
            **(
                {"background_depth": "exact: no noise, no holes (range limits, 0.2 mm steps)"}
                if cfg.background
                else {}
            ),
            **({"stereo": {"baseline_m": cfg.stereo_baseline, "right_camera": "left + baseline along the "
                           "left camera's x axis, same intrinsics and orientation (rectified)"}}
               if has_right else {}),
            **({"layout_format": "euroc", "euroc_T_BS_cam0": euroc_writer.T_BS_CAM0.tolist()} if euroc else {}),
            **({"imu0": _imu_info(imu)} if imu is not None else {}),
            **({"euroc_depth0": "depth registered to cam0 (same stamps, intrinsics and T_BS), metres x "
                f"{DEPTH_SCALE:g}, the depth/ of the tum layout"} if euroc and cfg.euroc_depth else {}),
            **({"layout_format": "kitti", "kitti_T_W_C0": renderer.poses[0].tolist()} if kitti else {}),
        },
    )
    (out / IN_PROGRESS).unlink(missing_ok=True)
    return out


def _imu_info(imu: SimulatedImu) -> dict[str, Any]:
    """What ``sequence.json`` says of the simulated IMU: its noise, the seeded initial biases
    (zero for an exact stream) and the span it covers."""
    return {
        "model": "ADIS16448 (EuRoC imu0); white noise sigma * sqrt(rate) per sample, bias random walk "
                 "sigma_rw / sqrt(rate) per step from a seeded constant (synth/imu.py)" if imu.noisy
                 else "exact: no noise, no bias",
        "noise": asdict(imu.calibration.noise),
        "initial_gyro_bias_rad_s": imu.gyro_bias[0].tolist(),
        "initial_acc_bias_m_s2": imu.acc_bias[0].tolist(),
        "T_BS_imu0": np.eye(4).tolist(),
        "span_s_from_first_frame": [float(imu.t_rel[0]), float(imu.t_rel[-1])],
        "samples": len(imu.t_rel),
    }


def _as_saved(cfg: SynthConfig) -> dict[str, Any]:
    """``cfg`` as ``sequence.json`` holds it after a JSON round trip (tuples as lists)."""
    return json.loads(json.dumps(asdict(cfg)))


def saved_config(seq_dir: Path, name: str = "sequence.json") -> dict[str, Any] | None:
    """The configuration a render in ``seq_dir`` was made with (``None`` if unreadable), with
    fields added to SynthConfig later filled in: absent from older renders, at their default
    they do not change the images, so such a render is still that configuration."""
    try:
        saved = json.loads((seq_dir / name).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    have = saved.get("config", saved) if isinstance(saved, dict) else None
    if not isinstance(have, dict):
        return None
    defaults = _as_saved(SynthConfig())
    return {**{k: v for k, v in defaults.items() if k not in have and k in _ADDED_FIELDS}, **have}


def needs_render(seq_dir: Path, cfg: SynthConfig) -> bool:
    """True unless ``seq_dir`` holds this exact configuration, completely rendered."""
    needed = ("groundtruth.txt", SCENE_FILE, MOVERS_FILE)  # no scene.json: labels before NYU-40
    if not all((seq_dir / f).is_file() for f in needed):
        return True
    return saved_config(seq_dir) != _as_saved(cfg)


def ensure_rendered(cfg: SynthConfig, seq_dir: str | Path, progress: bool = False) -> bool:
    """Render ``cfg`` into ``seq_dir`` unless it is already there; True if it rendered."""
    seq_dir = Path(seq_dir)
    if not needs_render(seq_dir, cfg):
        return False
    render_sequence(cfg, seq_dir, progress=progress)
    return True
