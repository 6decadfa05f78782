"""SDFCNN training data: TUM-layout folders with depth and ``semantic/`` labels, as
(image, NYU-40 train index, depth in metres) triples.

Label ids are mapped to the 40 NYU classes (train index k - 1 for NYU id k, 255 = ignored)
by a 256-entry lookup table:

* semslam's synthetic sequences (``sequence.json`` from ``semslam.synth``): static surfaces
  are 100 + NYU id; people (15) are NYU's own ``person`` (31), which the 40-class set has;
  the moving object (21: the unlabelled mover or the carried box, no fixed NYU class) and
  background 0 (nothing rendered) are ignored.
* any other folder is read as NYU-40 ids (0 unlabelled -> ignored, 1..40), the layout of
  NYU Depth v2 exported to TUM folders.

Frames come through ``io.sequence.TumRgbdSequence`` (rgb/depth association, depth scale);
labels through ``nets.datasets.read_label``. Everything is resized to one training size
(image: area, labels and depth: nearest, so no depth is invented across edges; 0 = no
depth stays 0) and kept in memory. Augmentation is horizontal flip and colour jitter, and
optionally (``camera`` > 0, that share of samples) a real camera's defects, :func:`camera_effects`;
no scaling or cropping: they would change what a pixel's depth means for the camera.
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import torch
from numpy.typing import NDArray
from torch.utils.data import Dataset

from semslam.core.labels import NYU40_CLASSES, SYNTH_MOVING_OBJECT, SYNTH_STATIC_OFFSET, VOC_PERSON
from semslam.errors import DataError
from semslam.io.sequence import TumRgbdSequence
from semslam.nets.datasets import IGNORE_INDEX, Augment, read_label, to_tensor

NYU_PERSON = 31
N_CLASSES = len(NYU40_CLASSES)


def nyu40_lut() -> NDArray[np.uint8]:
    """NYU-40 label images: id k (1..40) -> k - 1; 0 and everything else ignored."""
    lut = np.full(256, IGNORE_INDEX, np.uint8)
    lut[1 : N_CLASSES + 1] = np.arange(N_CLASSES)
    return lut


def synth_lut() -> NDArray[np.uint8]:
    """semslam.synth label images: 100 + k -> k - 1, person 15 -> NYU person; the rest ignored."""
    lut = np.full(256, IGNORE_INDEX, np.uint8)
    lut[SYNTH_STATIC_OFFSET + 1 : SYNTH_STATIC_OFFSET + N_CLASSES + 1] = np.arange(N_CLASSES)
    lut[VOC_PERSON] = NYU_PERSON - 1
    lut[SYNTH_MOVING_OBJECT] = IGNORE_INDEX
    return lut


def label_lut(root: Path) -> NDArray[np.uint8]:
    """The lookup table for a folder: synthetic if ``sequence.json`` says semslam.synth made it."""
    meta = Path(root) / "sequence.json"
    if meta.is_file():
        try:
            generator = json.loads(meta.read_text()).get("generator")
        except (OSError, ValueError) as exc:
            raise DataError(meta, f"cannot read: {exc}") from None
        if generator == "semslam.synth":
            return synth_lut()
    return nyu40_lut()


@dataclass
class DepthSample:
    rgb: NDArray[np.uint8]  # (H, W, 3) RGB
    label: NDArray[np.uint8]  # (H, W) train indices 0..39, 255 ignored
    depth: NDArray[np.float32]  # (H, W) metres, 0 = none


def load_folder(root: Path, size: tuple[int, int], every: int = 1, limit: int = 0) -> list[DepthSample]:
    """Every ``every``-th frame of a TUM folder (``limit`` > 0: at most that many), resized to ``size`` (w, h)."""
    seq = TumRgbdSequence(root)
    lut = label_lut(root)
    out: list[DepthSample] = []
    for k in range(0, len(seq), every):
        frame = seq.load(k)
        assert frame.rgb_path is not None and frame.depth is not None
        lab_path = Path(root) / "semantic" / frame.rgb_path.name
        if not lab_path.is_file():
            raise DataError(lab_path, "label missing (every rgb frame needs semantic/<same name>)")
        lab = read_label(lab_path)
        if lab.shape != frame.rgb.shape[:2]:
            raise DataError(lab_path, f"label size {lab.shape[::-1]} differs from image {frame.rgb.shape[1::-1]}")
        out.append(resize_sample(frame.rgb, lut[lab], frame.depth, size))
        if limit and len(out) >= limit:
            break
    if not out:
        raise DataError(root, "no frames")
    return out


def resize_sample(rgb: NDArray[np.uint8], label: NDArray[np.uint8], depth: NDArray[np.float32],
                  size: tuple[int, int]) -> DepthSample:
    """One sample at ``size`` (w, h): image by area, labels and depth by nearest neighbour."""
    if rgb.shape[1::-1] != tuple(size):
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        label = cv2.resize(label, size, interpolation=cv2.INTER_NEAREST)
        depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    return DepthSample(np.ascontiguousarray(rgb), np.ascontiguousarray(label), depth.astype(np.float32))


def camera_effects(rgb: NDArray[np.uint8], rng: random.Random) -> NDArray[np.uint8]:
    """What a real (Kinect-class) camera does to an image that the renders lack, each drawn at
    random: an exposure and tone curve (gain, gamma), a white-balance cast, defocus or motion
    blur, shot and read noise, and JPEG compression. Geometry is unchanged, so the depth and
    labels stay right."""
    img = rgb.astype(np.float32) / 255.0
    img = np.clip(img * rng.uniform(0.6, 1.5), 0, 1) ** rng.uniform(0.7, 1.4)
    img *= np.array([rng.uniform(0.85, 1.15) for _ in range(3)], np.float32)
    k = rng.random()
    if k < 0.35:
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 1.5))
    elif k < 0.6:  # linear motion blur along a random direction
        n = rng.randint(3, 7)
        kern = np.zeros((n, n), np.float32)
        kern[n // 2] = 1.0 / n
        rot = cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2), rng.uniform(0, 180), 1.0)
        kern = cv2.warpAffine(kern, rot, (n, n))
        img = cv2.filter2D(img, -1, kern / max(float(kern.sum()), 1e-6))
    nrng = np.random.default_rng(rng.getrandbits(32))
    shot, read = rng.uniform(0.0, 0.03), rng.uniform(0.002, 0.02)
    img = img + nrng.standard_normal(img.shape, dtype=np.float32) * np.sqrt(shot * np.clip(img, 0, 1) * 0.1
                                                                             + read**2)
    out = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if rng.random() < 0.7:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, rng.randint(30, 95)])
        out = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else out
    return out


class SdfDataset(Dataset):
    """In-memory (image tensor, label, depth) samples; ``augment`` adds flip + colour jitter and,
    for a share ``camera`` of the samples, :func:`camera_effects`."""

    def __init__(self, samples: Sequence[DepthSample], augment: bool = False, seed: int = 0,
                 camera: float = 0.0) -> None:
        self.samples = list(samples)
        self.augment = augment
        self.camera = camera
        self._jitter = Augment()
        self._rng = random.Random(seed)

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        s = self.samples[i]
        rgb, lab, depth = s.rgb, s.label, s.depth
        if self.augment:
            if self._rng.random() < 0.5:
                rgb, lab, depth = rgb[:, ::-1], lab[:, ::-1], depth[:, ::-1]
            rgb = self._jitter.jitter(np.ascontiguousarray(rgb), self._rng)
            if self.camera and self._rng.random() < self.camera:
                rgb = camera_effects(rgb, self._rng)
        return (to_tensor(rgb), torch.from_numpy(lab.astype(np.int64)),
                torch.from_numpy(np.ascontiguousarray(depth)))


def class_frequencies(samples: Sequence[DepthSample]) -> list[float]:
    """Fraction of labelled training pixels per class (for the checkpoint's metadata)."""
    counts = np.zeros(N_CLASSES)
    for s in samples:
        counts += np.bincount(s.label[s.label != IGNORE_INDEX].ravel(), minlength=N_CLASSES)[:N_CLASSES]
    return (counts / max(1.0, counts.sum())).tolist()
