"""Segmentation training data: TUM-layout folders with ``semantic/`` labels, and VOC folders.

Labels are mapped from dataset ids (VOC ids: 0 background, 15 person; the synthetic
sequences use the same: 0 background, 15 person, 21 unlabelled moving object) to train
indices 0..C-1 by a 256-entry lookup table built from a :class:`ClassSet`. Ids that are
not in the set become background by default (``other="background"``) or are ignored
(``"ignore"``, index 255). The default set is 2 classes, background/person, because a
person model is what can be trained on CPU here. Id 21 (the synthetic "moving object",
a textured box that is not a person) is therefore background by default: a person
segmenter must not fire on it, and a box has no appearance cue that it moves. The
synthetic sequences label the static scene with NYU-40 classes at ids 100..140; unless a
class set names them, they are background whatever ``other`` says, as when the whole
static scene was id 0 (ignoring it would leave a person net nothing to learn "not a
person" from).

Images are decoded once, resized so they fit the target size (640x480 -> 320x240) and
kept in memory (uint8), so an epoch costs only augmentation + the network. Augmentation
(training only) follows STDC/BiSeNet practice: random scale, random crop (padding with
ignore), horizontal flip, colour jitter (brightness, contrast, saturation, hue).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import cv2
import numpy as np
import torch
from numpy.typing import NDArray
from torch.utils.data import Dataset

from semslam.core.labels import NYU40_CLASSES, SYNTH_STATIC_OFFSET
from semslam.errors import ConfigError, DataError

IGNORE_INDEX = 255
#: ImageNet statistics, as used by STDC-Seg (and most PyTorch segmentation code).
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)

VOC_NAMES = (
    "background", "aeroplane", "bicycle", "bird", "boat", "bottle", "bus", "car", "cat", "chair",
    "cow", "diningtable", "dog", "horse", "motorbike", "person", "pottedplant", "sheep", "sofa",
    "train", "tvmonitor",
)


@dataclass(frozen=True)
class ClassSet:
    """Which dataset ids are classes (in train-index order) and what happens to the others."""

    ids: tuple[int, ...] = (0, 15)
    names: tuple[str, ...] = ("background", "person")
    other: str = "background"  # or "ignore"

    def __post_init__(self) -> None:
        if len(self.ids) != len(self.names) or len(self.ids) < 2:
            raise ConfigError("classes: need at least 2 classes, one name per id")
        if self.ids[0] != 0:
            raise ConfigError("classes: the first class must be background (id 0)")
        if len(set(self.ids)) != len(self.ids) or not all(0 <= i < 255 for i in self.ids):
            raise ConfigError(f"classes: ids must be distinct and in 0..254, got {self.ids}")
        if self.other not in ("background", "ignore"):
            raise ConfigError(f"classes: other must be 'background' or 'ignore', got {self.other!r}")

    @classmethod
    def parse(cls, spec: str, other: str = "background") -> ClassSet:
        """``"0:background,15:person"``, or ``"person"`` (background + VOC person), or ``"voc"``."""
        spec = spec.strip()
        if spec == "voc":
            return cls(tuple(range(21)), VOC_NAMES, other)
        items = []
        for part in spec.split(","):
            part = part.strip()
            if ":" in part:
                i, name = part.split(":", 1)
                items.append((int(i), name.strip()))
            elif part in VOC_NAMES:
                items.append((VOC_NAMES.index(part), part))
            else:
                raise ConfigError(f"classes: cannot parse {part!r} (use id:name or a VOC class name)")
        if not items or items[0][0] != 0:
            items.insert(0, (0, "background"))
        return cls(tuple(i for i, _ in items), tuple(n for _, n in items), other)

    @property
    def n_classes(self) -> int:
        return len(self.ids)

    def lut(self) -> NDArray[np.uint8]:
        """Dataset id -> train index (255 = ignore); id 255 stays ignore."""
        table = np.full(256, 0 if self.other == "background" else IGNORE_INDEX, np.uint8)
        table[IGNORE_INDEX] = IGNORE_INDEX
        # the synthetic static scene (NYU-40 ids at 100 + id) is background, as id 0 was
        table[SYNTH_STATIC_OFFSET + 1 : SYNTH_STATIC_OFFSET + len(NYU40_CLASSES) + 1] = 0
        for idx, i in enumerate(self.ids):
            table[i] = idx
        return table


@dataclass
class Sample:
    rgb: NDArray[np.uint8]  # (H, W, 3) RGB, resized to fit the target size
    label: NDArray[np.uint8]  # (H, W) train indices


def tum_pairs(root: Path) -> list[tuple[Path, Path]]:
    """(rgb, semantic label) paths of a TUM-layout folder, in ``rgb.txt`` order."""
    root = Path(root)
    listing = root / "rgb.txt"
    if not listing.is_file():
        raise DataError(listing, "no rgb.txt (expected a TUM-layout folder with semantic/)")
    pairs = []
    for line in listing.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        rel = line.split()[1]
        rgb = root / rel
        lab = root / "semantic" / Path(rel).name
        if not lab.is_file():
            raise DataError(lab, "label missing (every rgb frame needs semantic/<same name>)")
        pairs.append((rgb, lab))
    if not pairs:
        raise DataError(listing, "lists no frames")
    return pairs


def voc_pairs(root: Path, split: str | None = "train") -> list[tuple[Path, Path]]:
    """(JPEG, SegmentationClass PNG) pairs of a VOC folder (``split`` from ImageSets if present)."""
    root = Path(root)
    if (root / "VOC2012").is_dir() and not (root / "JPEGImages").is_dir():
        root = root / "VOC2012"
    seg = root / "SegmentationClass"
    if not seg.is_dir():
        raise DataError(seg, "not found (expected a VOC folder with JPEGImages/ and SegmentationClass/)")
    split_file = root / "ImageSets" / "Segmentation" / f"{split}.txt"
    if split and split_file.is_file():
        names = [s.strip() for s in split_file.read_text().split() if s.strip()]
    else:
        names = sorted(p.stem for p in seg.glob("*.png"))
    pairs = [(root / "JPEGImages" / f"{n}.jpg", seg / f"{n}.png") for n in names]
    missing = [p for p, _ in pairs if not p.is_file()]
    if missing:
        raise DataError(missing[0], f"image missing ({len(missing)} of {len(pairs)})")
    return pairs


def _voc_colormap() -> NDArray[np.uint8]:
    """The PASCAL VOC palette (index -> RGB), to decode labels saved as RGB."""
    cmap = np.zeros((256, 3), np.uint8)
    for i in range(256):
        c, r, g, b = i, 0, 0, 0
        for j in range(8):
            r |= ((c >> 0) & 1) << (7 - j)
            g |= ((c >> 1) & 1) << (7 - j)
            b |= ((c >> 2) & 1) << (7 - j)
            c >>= 3
        cmap[i] = (r, g, b)
    return cmap


def read_label(path: Path) -> NDArray[np.uint8]:
    """Class-id map of a label PNG: palette ("P") PNGs give their indices (OpenCV would
    turn them into colours, hence Pillow), grey PNGs their values, RGB ones are decoded
    with the VOC palette."""
    from PIL import Image

    with Image.open(path) as im:
        if im.mode in ("P", "L"):
            return np.array(im, dtype=np.uint8)
        rgb = np.array(im.convert("RGB"), dtype=np.uint8)
    key = (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[..., 2]
    cmap = _voc_colormap().astype(np.int32)
    lut = {int((r << 16) | (g << 8) | b): i for i, (r, g, b) in enumerate(cmap)}
    out = np.zeros(key.shape, np.uint8)
    for k in np.unique(key):
        out[key == k] = lut.get(int(k), IGNORE_INDEX)
    return out


def fit_size(w: int, h: int, size: tuple[int, int]) -> tuple[int, int]:
    """Size of a (w, h) image scaled to fit inside ``size`` (keeping the aspect ratio)."""
    s = min(size[0] / w, size[1] / h)
    return max(1, round(w * s)), max(1, round(h * s))


def load_sample(rgb_path: Path, label_path: Path, lut: NDArray[np.uint8], size: tuple[int, int]) -> Sample:
    bgr = cv2.imread(str(rgb_path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataError(rgb_path, "cannot read image")
    lab = read_label(label_path)
    if lab.shape != bgr.shape[:2]:
        raise DataError(label_path, f"label size {lab.shape[::-1]} differs from image {bgr.shape[1::-1]}")
    w, h = fit_size(bgr.shape[1], bgr.shape[0], size)
    rgb = cv2.cvtColor(cv2.resize(bgr, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
    lab = cv2.resize(lut[lab], (w, h), interpolation=cv2.INTER_NEAREST)
    return Sample(rgb, lab)


@dataclass
class Augment:
    """Random scale / crop / flip / colour jitter (the STDC training recipe, scaled down)."""

    crop: tuple[int, int] = (320, 240)  # (w, h)
    scale: tuple[float, float] = (0.5, 1.5)
    flip: bool = True
    brightness: float = 0.4
    contrast: float = 0.4
    saturation: float = 0.4
    hue: float = 0.05  # fraction of the hue circle

    def __call__(self, rgb: NDArray[np.uint8], lab: NDArray[np.uint8], rng: random.Random) -> tuple[NDArray, NDArray]:
        s = rng.uniform(*self.scale)
        h, w = lab.shape
        nw, nh = max(1, round(w * s)), max(1, round(h * s))
        rgb = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
        lab = cv2.resize(lab, (nw, nh), interpolation=cv2.INTER_NEAREST)
        cw, ch = self.crop
        if nw < cw or nh < ch:  # pad: image with its mean colour, label with ignore
            pw, ph = max(0, cw - nw), max(0, ch - nh)
            fill = [int(v) for v in rgb.reshape(-1, 3).mean(0)]
            rgb = cv2.copyMakeBorder(rgb, 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=fill)
            lab = cv2.copyMakeBorder(lab, 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=IGNORE_INDEX)
        y0 = rng.randint(0, lab.shape[0] - ch)
        x0 = rng.randint(0, lab.shape[1] - cw)
        rgb, lab = rgb[y0 : y0 + ch, x0 : x0 + cw], lab[y0 : y0 + ch, x0 : x0 + cw]
        if self.flip and rng.random() < 0.5:
            rgb, lab = rgb[:, ::-1], lab[:, ::-1]
        return self.jitter(np.ascontiguousarray(rgb), rng), np.ascontiguousarray(lab)

    def jitter(self, rgb: NDArray[np.uint8], rng: random.Random) -> NDArray[np.uint8]:
        img = rgb.astype(np.float32)
        img *= rng.uniform(1 - self.brightness, 1 + self.brightness)
        grey = img.mean()
        img = (img - grey) * rng.uniform(1 - self.contrast, 1 + self.contrast) + grey
        img = np.clip(img, 0, 255).astype(np.uint8)
        if self.saturation > 0 or self.hue > 0:
            hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV).astype(np.float32)
            hsv[..., 0] = (hsv[..., 0] + rng.uniform(-self.hue, self.hue) * 180.0) % 180.0
            hsv[..., 1] *= rng.uniform(1 - self.saturation, 1 + self.saturation)
            hsv[..., 1:] = np.clip(hsv[..., 1:], 0, 255)
            img = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)
        return img


def to_tensor(rgb: NDArray[np.uint8], mean: Sequence[float] = MEAN, std: Sequence[float] = STD) -> torch.Tensor:
    """(H, W, 3) uint8 RGB -> normalised (3, H, W) float tensor."""
    x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float().div_(255.0)
    m = torch.tensor(mean).view(3, 1, 1)
    s = torch.tensor(std).view(3, 1, 1)
    return (x - m) / s


@dataclass
class SegDataset(Dataset):
    """In-memory segmentation samples; ``augment=None`` gives the fixed-size validation view."""

    samples: list[Sample]
    augment: Augment | None = None
    seed: int = 0
    sources: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.samples[i]
        rgb, lab = (s.rgb, s.label) if self.augment is None else self.augment(s.rgb, s.label, self._rng)
        return to_tensor(rgb), torch.from_numpy(lab.astype(np.int64))


def load_samples(
    pairs: Iterable[tuple[Path, Path]], classes: ClassSet, size: tuple[int, int], every: int = 1
) -> list[Sample]:
    """Decode ``pairs`` (every ``every``-th), map labels to train indices, resize to fit ``size``."""
    lut = classes.lut()
    return [load_sample(r, lab, lut, size) for k, (r, lab) in enumerate(pairs) if k % every == 0]


def describe_sources(tum: Sequence[Path], voc: Sequence[Path]) -> list[str]:
    """Human-readable list of data sources for checkpoint metadata."""
    out = []
    for d in tum:
        meta = Path(d) / "sequence.json"
        extra = ""
        if meta.is_file():
            import json

            data = json.loads(meta.read_text())
            cfg = data.get("config", data)
            keys = ("motion", "frames", "people", "mover", "seed", "fps")
            extra = " (" + ", ".join(f"{k}={cfg[k]}" for k in keys if k in cfg) + ")"
        out.append(f"tum:{d}{extra}")
    out += [f"voc:{d}" for d in voc]
    return out
