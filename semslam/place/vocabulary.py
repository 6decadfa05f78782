"""Hierarchical vocabulary tree for 256-bit binary descriptors (DBoW2's design, own code).

ORB-SLAM recognises places with DBoW2: each ORB descriptor descends a k-ary tree of
k-majority cluster centres to a leaf (a *word*); an image becomes a sparse TF-IDF vector
over words (its bag of words), compared with the L1 score. The tree also yields the
*feature vector* (features grouped by a node a few levels above the leaves), which
restricts descriptor matching between two keyframes to features under the same node.

Everything here is vectorised: all descriptors of an image descend the tree together,
one level per step, with Hamming distances from XOR + a SWAR popcount on 64-bit lanes.
The tree is stored as a compact ``.npz``; training lives in
:mod:`semslam.place.train_vocab`.
"""

from __future__ import annotations

import functools
import io
import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from semslam.errors import DataError

DESCRIPTOR_BYTES = 32
FORMAT_VERSION = 1
DEFAULT_VOCABULARY = "orb_vocab.npz"
#: ORB-SLAM builds feature vectors 4 levels above the leaves of its 6-level tree, i.e.
#: at depth 2 below the root; ``transform`` uses that depth unless told otherwise.
FEATURE_VECTOR_DEPTH = 2

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1, _S2, _S4, _S56 = np.uint64(1), np.uint64(2), np.uint64(4), np.uint64(56)


def popcount64(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Bits set per uint64 element (numpy < 2 has no bitwise_count)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return (x * _H01) >> _S56


def as_u64(desc: NDArray[np.uint8]) -> NDArray[np.uint64]:
    """View N x 32 uint8 descriptors as N x 4 uint64 lanes (copies only if not contiguous)."""
    d = np.ascontiguousarray(desc, dtype=np.uint8)
    if d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES:
        raise ValueError(f"expected N x {DESCRIPTOR_BYTES} uint8 descriptors, got shape {d.shape}")
    return d.view(np.uint64)


def hamming(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Pairwise Hamming distances (len(a) x len(b)) between binary descriptors."""
    x = as_u64(a)[:, None, :] ^ as_u64(b)[None, :, :]
    return popcount64(x).sum(axis=2, dtype=np.int64)


@dataclass(frozen=True)
class BowVector:
    """Sparse bag of words: ascending word ids and their L1-normalised TF-IDF weights.

    Arrays rather than DBoW2's std::map so database scoring stays vectorised.
    """

    words: NDArray[np.int32]
    weights: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.words)

    def to_dict(self) -> dict[int, float]:
        return {int(w): float(v) for w, v in zip(self.words, self.weights)}

    @staticmethod
    def empty() -> BowVector:
        return BowVector(np.zeros(0, np.int32), np.zeros(0, np.float64))


#: DBoW2's FeatureVector: node id (at ``levels_up`` above the leaves) -> indices of the
#: features under that node, keys in ascending node order, indices ascending.
FeatureVector = dict[int, NDArray[np.int32]]


def l1_score(a: BowVector, b: BowVector) -> float:
    """DBoW2's L1 score ``1 - 0.5 * |a/|a| - b/|b||_1`` in [0, 1], over shared words only.

    For non-negative, L1-normalised vectors the sum over all words reduces to
    ``0.5 * sum_shared(|a_i| + |b_i| - |a_i - b_i|)`` (non-shared words cancel).
    """
    if len(a) == 0 or len(b) == 0:
        return 0.0
    _, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    va, vb = a.weights[ia], b.weights[ib]
    return float(0.5 * np.sum(np.abs(va) + np.abs(vb) - np.abs(va - vb)))


@dataclass
class Vocabulary:
    """A k-ary vocabulary tree of depth ``levels`` with IDF weights on its leaves.

    Nodes are in breadth-first order, node 0 is the root (no descriptor). ``children``
    holds up to ``k`` child ids per node (-1 = none); a node without children is a leaf
    and ``node_word`` gives its word id (-1 for inner nodes). Leaves can sit above the
    last level when a node had too few descriptors to split (as in DBoW2).
    """

    #: Tells places apart (relocalisation, loop closing); ``place.flat.FlatVocabulary`` does not.
    recognises_places: ClassVar[bool] = True

    k: int
    levels: int
    node_desc: NDArray[np.uint8]  # n_nodes x 32
    children: NDArray[np.int32]  # n_nodes x k
    node_word: NDArray[np.int32]  # n_nodes
    idf: NDArray[np.float64]  # n_words
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.node_desc = np.ascontiguousarray(self.node_desc, dtype=np.uint8)
        self.children = np.ascontiguousarray(self.children, dtype=np.int32)
        self.node_word = np.ascontiguousarray(self.node_word, dtype=np.int32)
        self.idf = np.ascontiguousarray(self.idf, dtype=np.float64)
        n = len(self.node_desc)
        if self.children.shape != (n, self.k) or self.node_word.shape != (n,):
            raise ValueError("vocabulary arrays disagree in size")
        leaves = np.flatnonzero(self.node_word >= 0)
        if not np.array_equal(np.sort(self.node_word[leaves]), np.arange(len(self.idf))):
            raise ValueError("node_word must number the leaves 0..n_words-1")
        self._desc64 = self.node_desc.view(np.uint64)
        self._valid = self.children >= 0
        self._is_leaf = ~self._valid.any(axis=1)
        self._children_safe = np.where(self._valid, self.children, 0)
        self._lanes = [np.ascontiguousarray(self._desc64[:, j]) for j in range(4)]
        self._penalty = np.where(self._valid, 0, 1024).astype(np.uint64)
        if not np.array_equal(self.node_word >= 0, self._is_leaf):
            raise ValueError("node_word must be set exactly on the childless nodes")
        # Parent and depth of each node (feature vectors group leaves by an ancestor).
        parent = np.full(n, -1, np.int32)
        rows, cols = np.nonzero(self._valid)
        parent[self.children[rows, cols]] = rows
        depth = np.zeros(n, np.int32)
        nonroot = parent >= 0
        for _ in range(self.levels):  # depth[c] = depth[parent[c]] + 1, settles in `levels` steps
            depth[nonroot] = depth[parent[nonroot]] + 1
        self.depth = depth
        self.parent = parent
        self.word_node = np.empty(len(self.idf), np.int32)
        self.word_node[self.node_word[leaves]] = leaves

    # ---------------------------------------------------------------- properties
    @property
    def n_words(self) -> int:
        return len(self.idf)

    @property
    def n_nodes(self) -> int:
        return len(self.node_desc)

    def __repr__(self) -> str:
        return f"Vocabulary(k={self.k}, levels={self.levels}, words={self.n_words}, nodes={self.n_nodes})"

    # ---------------------------------------------------------------- transform
    def leaf_nodes(self, desc: NDArray[np.uint8]) -> NDArray[np.int32]:
        """Leaf node reached by each descriptor: all descend together, one level a step.

        At each node the child with the smallest Hamming distance wins (ties: lowest
        child index, like DBoW2's strict ``<``). Distances are computed lane by lane
        (4 x 64 bit) with in-place SWAR popcount steps: ~4x faster than one 3-D array.
        """
        d64 = as_u64(desc)
        node = np.zeros(len(d64), np.int32)
        active = np.arange(len(d64))
        for _ in range(self.levels):
            active = active[~self._is_leaf[node[active]]]
            if active.size == 0:
                break
            cur = node[active]
            kids = self._children_safe[cur]  # A x k
            acc = np.zeros(kids.shape, np.uint64)
            for j in range(4):
                x = self._lanes[j][kids]
                x ^= d64[active, j][:, None]
                x -= (x >> _S1) & _M1
                x = (x & _M2) + ((x >> _S2) & _M2)
                x += x >> _S4
                x &= _M4
                acc += x  # per-byte counts stay <= 32: no carry between bytes
            acc *= _H01
            acc >>= _S56
            acc += self._penalty[cur]  # missing children never win
            node[active] = kids[np.arange(len(active)), acc.argmin(axis=1)]
        return node

    def words_of(self, desc: NDArray[np.uint8]) -> NDArray[np.int32]:
        """Word id of each descriptor."""
        return self.node_word[self.leaf_nodes(desc)]

    def ancestors_at(self, nodes: NDArray[np.int32], depth: int) -> NDArray[np.int32]:
        """Ancestor of each node at ``depth`` (the node itself if it is shallower)."""
        out = np.asarray(nodes, np.int32).copy()
        for _ in range(self.levels):
            deeper = self.depth[out] > depth
            if not deeper.any():
                break
            out[deeper] = self.parent[out[deeper]]
        return out

    def bow(self, desc: NDArray[np.uint8]) -> BowVector:
        """TF-IDF bag of words of one image's descriptors, L1-normalised."""
        return self._bow_from_words(self.words_of(desc))

    def _bow_from_words(self, words: NDArray[np.int32]) -> BowVector:
        if words.size == 0:
            return BowVector.empty()
        uniq, counts = np.unique(words, return_counts=True)
        w = counts * self.idf[uniq]
        keep = w > 0  # words seen in every training image carry no information (DBoW2)
        uniq, w = uniq[keep], w[keep]
        total = w.sum()
        if total <= 0:
            return BowVector.empty()
        return BowVector(uniq.astype(np.int32), w / total)

    def transform(
        self, desc: NDArray[np.uint8], levels_up: int | None = None
    ) -> tuple[BowVector, FeatureVector]:
        """Bag of words and DBoW2 feature vector of one image's descriptors.

        The feature vector groups every feature (each exactly once) by its ancestor
        ``levels_up`` levels above the leaves (a leaf above that depth stands for
        itself), so keyframe matching only compares features under the same node. The
        default puts the grouping nodes at depth 2 below the root, as ORB-SLAM does
        (levels_up=4 in its 6-level tree).
        """
        leaves = self.leaf_nodes(desc)
        bow = self._bow_from_words(self.node_word[leaves])
        return bow, self._feature_vector(leaves, levels_up)

    def feature_depth(self, levels_up: int | None = None) -> int:
        """Depth of the feature-vector nodes for ``levels_up`` (None: ORB-SLAM's 2)."""
        if levels_up is None:
            return min(FEATURE_VECTOR_DEPTH, self.levels)
        return max(self.levels - levels_up, 0)

    def _feature_vector(self, leaves: NDArray[np.int32], levels_up: int | None) -> FeatureVector:
        if leaves.size == 0:
            return {}
        groups = self.ancestors_at(leaves, self.feature_depth(levels_up))
        order = np.argsort(groups, kind="stable").astype(np.int32)
        g_sorted = groups[order]
        cuts = np.flatnonzero(g_sorted[1:] != g_sorted[:-1]) + 1
        keys = g_sorted[np.r_[0, cuts]].tolist()
        return dict(zip(keys, np.split(order, cuts)))

    @staticmethod
    def score(a: BowVector, b: BowVector) -> float:
        """DBoW2 L1 similarity of two bags of words (see :func:`l1_score`)."""
        return l1_score(a, b)

    # ---------------------------------------------------------------- persistence
    def save(self, path: str | Path) -> None:
        """Write a compressed ``.npz`` (descriptors packed as bytes, small int types)."""
        meta = dict(self.metadata)
        meta.update(format_version=FORMAT_VERSION, k=self.k, levels=self.levels, n_words=self.n_words)
        idx_t = np.int16 if self.n_nodes < 2**15 else np.int32
        np.savez_compressed(
            Path(path),
            k=np.int32(self.k),
            levels=np.int32(self.levels),
            node_desc=self.node_desc,
            children=self.children.astype(idx_t),
            node_word=self.node_word.astype(idx_t if self.n_words < 2**15 else np.int32),
            idf=self.idf.astype(np.float32),
            metadata=np.array(json.dumps(meta, sort_keys=True)),
        )

    @classmethod
    def load(cls, source: str | Path | io.BytesIO) -> Vocabulary:
        """Read a vocabulary written by :meth:`save`; :class:`DataError` if it is not one."""
        name = str(source) if not isinstance(source, io.BytesIO) else "<vocabulary bytes>"
        try:
            with np.load(source, allow_pickle=False) as z:
                return cls(
                    k=int(z["k"]),
                    levels=int(z["levels"]),
                    node_desc=z["node_desc"],
                    children=z["children"].astype(np.int32),
                    node_word=z["node_word"].astype(np.int32),
                    idf=z["idf"].astype(np.float64),
                    metadata=json.loads(str(z["metadata"])),
                )
        except FileNotFoundError:
            raise DataError(name, "vocabulary file not found") from None
        except (KeyError, ValueError, OSError) as exc:
            raise DataError(name, f"not a semslam vocabulary ({exc})") from None


@functools.lru_cache(maxsize=1)
def load_default_vocabulary() -> Vocabulary:
    """The ORB vocabulary shipped in ``semslam/data`` (read once per process)."""
    res = resources.files("semslam") / "data" / DEFAULT_VOCABULARY
    try:
        data = res.read_bytes()
    except FileNotFoundError:
        raise DataError(str(res), "the shipped vocabulary is missing; retrain it (semslam/data/README.md)") from None
    return Vocabulary.load(io.BytesIO(data))
