"""Training an ORB vocabulary tree (DBoW2's hierarchical k-majority, own code).

No ORB vocabulary can be installed from PyPI, so the project trains its own from images
it may redistribute a derivative of, and ships the result (``semslam/data``). Descriptors
come from the same ``cv2.ORB`` settings as the SLAM extractor, so words seen at run time
are the ones the tree was built on.

Clustering follows DBoW2: at every node, k-means++ seeding with Hamming distances, then
k-majority iterations (assign to the nearest centre, centre = bitwise majority of its
members, FORB's rule); recurse until ``levels`` or until a node has one distinct
descriptor left. IDF weights are ``log(N_images / n_i)`` over the training images.
"""

from __future__ import annotations

import datetime as _dt
import fnmatch
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError
from semslam.place.vocabulary import DESCRIPTOR_BYTES, Vocabulary, as_u64, popcount64

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")
#: Images smaller than this (either side) are icons or masks, not scenes.
MIN_IMAGE_SIDE = 96
#: Images giving fewer ORB features than this add nothing useful (flat masks, logos).
MIN_FEATURES = 50

ImageLike = str | Path | NDArray[np.uint8]
Progress = Callable[[str], None]


# ---------------------------------------------------------------------------- features
def make_orb(n_features: int = 1000) -> cv2.ORB:
    """cv2.ORB with the SLAM extractor's settings (8 levels, scale 1.2, FAST 20)."""
    return cv2.ORB_create(
        nfeatures=n_features, scaleFactor=1.2, nlevels=8, fastThreshold=20, edgeThreshold=19, patchSize=31
    )


def to_gray(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """8-bit grayscale from gray/RGB/RGBA (channel order barely matters for gray)."""
    if img.ndim == 2:
        return img if img.dtype == np.uint8 else cv2.convertScaleAbs(img)
    if img.shape[2] == 4:
        img = img[:, :, :3]
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)


def orb_descriptors(gray: NDArray[np.uint8], orb: cv2.ORB) -> NDArray[np.uint8]:
    """N x 32 ORB descriptors of a grayscale image (0 x 32 if none)."""
    _, desc = orb.detectAndCompute(gray, None)
    return desc if desc is not None else np.zeros((0, DESCRIPTOR_BYTES), np.uint8)


# ---------------------------------------------------------------------------- sources
def iter_image_files(dirs: Iterable[str | Path], recursive: bool = True) -> list[Path]:
    """Image files in ``dirs`` (or the files themselves), sorted for reproducibility."""
    out: list[Path] = []
    for d in map(Path, dirs):
        if d.is_file():
            out.append(d)
            continue
        if not d.is_dir():
            raise DataError(d, "image folder not found")
        pattern = "**/*" if recursive else "*"
        out.extend(p for p in sorted(d.glob(pattern)) if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
    return out


def read_image(path: str | Path) -> NDArray[np.uint8] | None:
    """Grayscale image, or None when unreadable or too small to be a scene."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None or min(img.shape[:2]) < MIN_IMAGE_SIDE:
        return None
    return img


def iter_video_frames(path: str | Path, every: int) -> Iterator[NDArray[np.uint8]]:
    """Every ``every``-th frame of a video, grayscale (consecutive frames are near copies)."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise DataError(path, "cannot open video")
    try:
        i = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if i % max(every, 1) == 0:
                yield cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            i += 1
    finally:
        cap.release()


def iter_synthetic_frames(names: Iterable[str], per_sequence: int) -> Iterator[NDArray[np.uint8]]:
    """``per_sequence`` frames spread along each named synthetic sequence (project renderer)."""
    from semslam.synth import Renderer, get_sequence

    for name in names:
        cfg = get_sequence(name)
        renderer = Renderer(cfg)
        for i in np.linspace(0, cfg.frames - 1, per_sequence).round().astype(int):
            yield to_gray(renderer.render(int(i)).rgb)


@dataclass
class TrainingSources:
    """Where training images come from, recorded in the vocabulary's metadata.

    Folders are searched recursively; ``exclude`` holds shell patterns matched against
    the full path (masks, logos and silhouettes are not scenes). Videos give every
    ``every``-th frame; synthetic sequences give ``synth_frames`` frames each.
    """

    image_dirs: list[Path] = field(default_factory=list)
    exclude: list[str] = field(default_factory=list)
    videos: list[Path] = field(default_factory=list)
    every: int = 30
    synth: list[str] = field(default_factory=list)
    synth_frames: int = 5
    counts: dict[str, int] = field(default_factory=dict)

    def image_files(self) -> list[Path]:
        files = iter_image_files(self.image_dirs)
        return [f for f in files if not any(fnmatch.fnmatch(f.as_posix(), pat) for pat in self.exclude)]

    def iter_images(self) -> Iterator[ImageLike]:
        """All training images in a fixed order; counts what each source yields."""
        self.counts.clear()
        for f in self.image_files():
            self.counts["image files"] = self.counts.get("image files", 0) + 1
            yield f
        for v in self.videos:
            for frame in iter_video_frames(v, self.every):
                self.counts[f"video {Path(v).name}"] = self.counts.get(f"video {Path(v).name}", 0) + 1
                yield frame
        if self.synth:
            for frame in iter_synthetic_frames(self.synth, self.synth_frames):
                self.counts["synthetic frames"] = self.counts.get("synthetic frames", 0) + 1
                yield frame

    def describe(self) -> dict[str, Any]:
        return {
            "image_dirs": [str(d) for d in self.image_dirs],
            "exclude": list(self.exclude),
            "videos": [str(v) for v in self.videos],
            "video_every": self.every,
            "synthetic_sequences": list(self.synth),
            "synthetic_frames_per_sequence": self.synth_frames,
            "images_per_source": dict(self.counts),
        }


# ---------------------------------------------------------------------------- clustering
def _hamming_to(d64: NDArray[np.uint64], centres64: NDArray[np.uint64], chunk: int = 65536) -> NDArray[np.int32]:
    """n x c Hamming distances, chunked to bound the temporary n x c x 4 arrays."""
    out = np.empty((len(d64), len(centres64)), np.int32)
    for s in range(0, len(d64), chunk):
        x = d64[s : s + chunk, None, :] ^ centres64[None, :, :]
        out[s : s + chunk] = popcount64(x).sum(axis=2)
    return out


def _kmeanspp(d64: NDArray[np.uint64], k: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """k-means++ seeds (indices), sampling with probability ~ squared Hamming distance."""
    n = len(d64)
    seeds = [int(rng.integers(n))]
    mind = _hamming_to(d64, d64[seeds[0] : seeds[0] + 1])[:, 0].astype(np.float64)
    for _ in range(1, k):
        p = mind * mind
        total = p.sum()
        if total <= 0:
            break
        j = int(rng.choice(n, p=p / total))
        seeds.append(j)
        np.minimum(mind, _hamming_to(d64, d64[j : j + 1])[:, 0], out=mind)
    return np.asarray(seeds)


def kmajority(
    desc: NDArray[np.uint8], k: int, rng: np.random.Generator, max_iter: int = 25
) -> tuple[NDArray[np.uint8], NDArray[np.intp]]:
    """Cluster binary descriptors into <= k groups: (centres c x 32, label per descriptor).

    Centres are bitwise majorities (a bit is set when at least half the members have it,
    as in DBoW2's FORB::meanValue); empty clusters are dropped. With <= k distinct
    descriptors each distinct one is its own centre.
    """
    uniq, inverse = np.unique(desc, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(uniq) <= k:
        return uniq, inverse
    d64 = as_u64(desc)
    centres = desc[_kmeanspp(d64, k, rng)]
    bits = np.unpackbits(desc, axis=1)
    labels = np.full(len(desc), -1, np.intp)
    for _ in range(max_iter):
        new = _hamming_to(d64, as_u64(centres)).argmin(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
        order = np.argsort(labels, kind="stable")
        counts = np.bincount(labels, minlength=len(centres))
        present = np.flatnonzero(counts)
        starts = np.r_[0, np.cumsum(counts)[:-1]][present]
        sums = np.add.reduceat(bits[order], starts, axis=0, dtype=np.int32)
        majority = (2 * sums >= counts[present, None]).astype(np.uint8)
        centres = np.packbits(majority, axis=1)
        if len(present) < counts.size:  # relabel to the surviving clusters
            remap = np.full(counts.size, -1, np.intp)
            remap[present] = np.arange(len(present))
            labels = remap[labels]
    else:
        labels = _hamming_to(d64, as_u64(centres)).argmin(axis=1)
    # Final assignment may leave a centre empty; drop it so every child holds data.
    counts = np.bincount(labels, minlength=len(centres))
    present = np.flatnonzero(counts)
    if len(present) < len(centres):
        remap = np.full(len(centres), -1, np.intp)
        remap[present] = np.arange(len(present))
        centres, labels = centres[present], remap[labels]
    return centres, labels


def build_tree(
    desc: NDArray[np.uint8],
    k: int,
    levels: int,
    rng: np.random.Generator,
    progress: Progress | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.int32], NDArray[np.int32]]:
    """Hierarchical k-majority, breadth first: (node descriptors, children, node -> word)."""
    node_desc: list[NDArray[np.uint8]] = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    children: list[list[int]] = [[-1] * k]
    queue: deque[tuple[int, NDArray[np.intp], int]] = deque([(0, np.arange(len(desc)), 0)])
    last_depth = -1
    t0 = time.perf_counter()
    while queue:
        node, idx, depth = queue.popleft()
        if depth != last_depth and progress is not None:
            progress(f"level {depth}: {len(node_desc)} nodes so far ({time.perf_counter() - t0:.1f} s)")
        last_depth = depth
        if depth >= levels or len(idx) <= 1:
            continue
        centres, labels = kmajority(desc[idx], k, rng)
        if len(centres) <= 1 and depth > 0:
            continue  # all members identical: this node is already a word
        order = np.argsort(labels, kind="stable")
        bounds = np.r_[0, np.cumsum(np.bincount(labels, minlength=len(centres)))]
        for c in range(len(centres)):
            child = len(node_desc)
            node_desc.append(centres[c])
            children.append([-1] * k)
            children[node][c] = child
            queue.append((child, idx[order[bounds[c] : bounds[c + 1]]], depth + 1))
    ch = np.asarray(children, np.int32)
    is_leaf = (ch < 0).all(axis=1)
    is_leaf[0] = False if len(ch) > 1 else True
    node_word = np.full(len(ch), -1, np.int32)
    node_word[is_leaf] = np.arange(int(is_leaf.sum()), dtype=np.int32)
    return np.asarray(node_desc, np.uint8), ch, node_word


def compute_idf(vocab_words: list[NDArray[np.int32]], n_words: int) -> NDArray[np.float64]:
    """IDF ``log(N / n_i)`` per word from the word ids of each training image.

    A word no training image reaches gets ``log(N)`` (as rare as a word can be).
    """
    n_images = len(vocab_words)
    ni = np.zeros(n_words, np.int64)
    for w in vocab_words:
        ni[np.unique(w)] += 1
    return np.log(n_images / np.maximum(ni, 1)).astype(np.float64)


def train_from_descriptors(
    per_image: list[NDArray[np.uint8]],
    k: int = 10,
    levels: int = 4,
    seed: int = 0,
    max_descriptors: int | None = 300_000,
    metadata: dict[str, Any] | None = None,
    progress: Progress | None = None,
) -> Vocabulary:
    """Vocabulary from per-image descriptor arrays.

    The tree is clustered on at most ``max_descriptors`` (a uniform random subset, to keep
    training to minutes on 2 cores); IDF uses every descriptor of every image.
    """
    if k < 2 or levels < 1:
        raise ValueError("need k >= 2 and levels >= 1")
    per_image = [d for d in per_image if len(d)]
    if not per_image:
        raise DataError("<training images>", "no ORB descriptors in the training images")
    rng = np.random.default_rng(seed)
    all_desc = np.concatenate(per_image)
    train = all_desc
    if max_descriptors is not None and len(all_desc) > max_descriptors:
        train = all_desc[np.sort(rng.choice(len(all_desc), max_descriptors, replace=False))]
    t0 = time.perf_counter()
    node_desc, children, node_word = build_tree(train, k, levels, rng, progress)
    n_words = int((node_word >= 0).sum())
    tree_s = time.perf_counter() - t0
    vocab = Vocabulary(k, levels, node_desc, children, node_word, np.ones(n_words))
    vocab.idf = compute_idf([vocab.words_of(d) for d in per_image], n_words)
    meta = dict(metadata or {})
    meta.update(
        n_images=len(per_image),
        n_descriptors=int(len(all_desc)),
        n_descriptors_clustered=int(len(train)),
        seed=seed,
        tree_seconds=round(tree_s, 1),
        trained_at=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        algorithm="hierarchical k-majority (k-means++ seeding, Hamming), TF-IDF, L1 score",
        descriptor="cv2.ORB rBRIEF 256 bit (nlevels=8, scaleFactor=1.2, fastThreshold=20)",
    )
    vocab.metadata = meta
    return vocab


def train_vocabulary(
    images: Iterable[ImageLike],
    k: int = 10,
    levels: int = 4,
    n_features: int = 1000,
    seed: int = 0,
    max_descriptors: int | None = 300_000,
    metadata: dict[str, Any] | None = None,
    progress: Progress | None = None,
) -> Vocabulary:
    """Train a vocabulary on images (paths or arrays) with the SLAM extractor's ORB.

    Unreadable, tiny (< 96 px) or nearly featureless (< 50 ORB features) images are
    skipped; the number used is recorded in the metadata.
    """
    orb = make_orb(n_features)
    per_image: list[NDArray[np.uint8]] = []
    skipped = 0
    for item in images:
        gray = read_image(item) if isinstance(item, (str, Path)) else to_gray(np.asarray(item))
        desc = orb_descriptors(gray, orb) if gray is not None else None
        if desc is None or len(desc) < MIN_FEATURES:
            skipped += 1
            continue
        per_image.append(desc)
    if progress is not None:
        n = sum(len(d) for d in per_image)
        progress(f"{len(per_image)} images, {n} descriptors ({skipped} images skipped)")
    meta = dict(metadata or {})
    meta.update(n_features=n_features, images_skipped=skipped, k=k, levels=levels)
    return train_from_descriptors(per_image, k, levels, seed, max_descriptors, meta, progress)
