"""Keyframe database with an inverted index (DBoW2 / ORB-SLAM2 KeyFrameDatabase).

Loop closing and relocalisation ask "which keyframes look like this bag of words?". The
inverted index maps each word to the keyframes containing it (with their weights), so a
query touches only keyframes sharing at least one word, and the L1 score is accumulated
over shared words only, vectorised over all postings at once.

This is a pure data structure: keyframes are integer ids and the covisibility graph is
passed in by the caller as ``covisibles(kf_id, n) -> list[int]`` (the ``n`` best
covisible keyframes), so the database never holds references into the map.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.place.vocabulary import BowVector

Covisibles = Callable[[int, int], list[int]]

#: ORB-SLAM2's constants: candidates need > 80 % of the best common-word count, groups
#: are a keyframe and its 10 best covisibles, groups scoring > 75 % of the best survive.
COMMON_WORDS_RATIO = 0.8
GROUP_SIZE = 10
GROUP_SCORE_RATIO = 0.75


class _Postings:
    """Growable (slot, weight) arrays of one word; erase swaps with the last entry."""

    __slots__ = ("slots", "weights", "n")

    def __init__(self) -> None:
        self.slots = np.empty(8, np.int32)
        self.weights = np.empty(8, np.float64)
        self.n = 0

    def append(self, slot: int, weight: float) -> None:
        if self.n == len(self.slots):
            self.slots = np.concatenate([self.slots, np.empty_like(self.slots)])
            self.weights = np.concatenate([self.weights, np.empty_like(self.weights)])
        self.slots[self.n] = slot
        self.weights[self.n] = weight
        self.n += 1

    def remove(self, slot: int) -> None:
        hits = np.flatnonzero(self.slots[: self.n] == slot)
        if hits.size:
            i, last = int(hits[0]), self.n - 1
            self.slots[i] = self.slots[last]
            self.weights[i] = self.weights[last]
            self.n = last


@dataclass(frozen=True)
class SharedWords:
    """Per keyframe sharing words with a query: ids, shared-word counts, L1 scores."""

    kf_ids: NDArray[np.int64]
    common: NDArray[np.int64]
    scores: NDArray[np.float64]


class KeyframeDatabase:
    """Inverted index word -> keyframes, with DBoW2 L1 scoring.

    Thread-safe as ORB-SLAM's KeyFrameDatabase (its mMutex): loop closing adds keyframes
    while tracking may query it to relocalise.
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._index: dict[int, _Postings] = {}
        self._bows: dict[int, BowVector] = {}
        self._slot_of: dict[int, int] = {}
        self._kf_of_slot: list[int] = []
        self._free: list[int] = []

    def __len__(self) -> int:
        return len(self._bows)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._bows

    def ids(self) -> list[int]:
        return list(self._bows)

    def bow(self, kf_id: int) -> BowVector:
        return self._bows[kf_id]

    def add(self, kf_id: int, bow: BowVector) -> None:
        """Index a keyframe's bag of words (re-adding an id replaces it)."""
        with self._lock:
            self._add(kf_id, bow)

    def _add(self, kf_id: int, bow: BowVector) -> None:
        if kf_id in self._bows:
            self._erase(kf_id)
        if self._free:
            slot = self._free.pop()
            self._kf_of_slot[slot] = kf_id
        else:
            slot = len(self._kf_of_slot)
            self._kf_of_slot.append(kf_id)
        self._slot_of[kf_id] = slot
        self._bows[kf_id] = bow
        index = self._index
        for w, v in zip(bow.words.tolist(), bow.weights.tolist()):
            post = index.get(w)
            if post is None:
                post = index[w] = _Postings()
            post.append(slot, v)

    def erase(self, kf_id: int) -> None:
        """Remove a keyframe (culled by the map); unknown ids are ignored."""
        with self._lock:
            self._erase(kf_id)

    def _erase(self, kf_id: int) -> None:
        bow = self._bows.pop(kf_id, None)
        if bow is None:
            return
        slot = self._slot_of.pop(kf_id)
        for w in bow.words.tolist():
            post = self._index.get(w)
            if post is not None:
                post.remove(slot)
                if post.n == 0:
                    del self._index[w]
        self._kf_of_slot[slot] = -1
        self._free.append(slot)

    def clear(self) -> None:
        self.__init__()  # type: ignore[misc]

    def shared_words(self, bow: BowVector, exclude: Collection[int] = ()) -> SharedWords:
        """Every keyframe sharing a word with ``bow``: common-word count and L1 score.

        L1 score over shared words: ``0.5 * sum(|a|+|b|-|a-b|)`` (DBoW2's L1Scoring).
        """
        with self._lock:
            return self._shared_words(bow, exclude)

    def _shared_words(self, bow: BowVector, exclude: Collection[int]) -> SharedWords:
        parts_s, parts_w, parts_q = [], [], []
        index = self._index
        for w, q in zip(bow.words.tolist(), bow.weights.tolist()):
            post = index.get(w)
            if post is not None:
                parts_s.append(post.slots[: post.n])
                parts_w.append(post.weights[: post.n])
                parts_q.append((q, post.n))
        if not parts_s:
            empty = np.zeros(0, np.int64)
            return SharedWords(empty, empty, np.zeros(0))
        slots = np.concatenate(parts_s)
        w = np.concatenate(parts_w)
        qv = np.repeat([q for q, _ in parts_q], [n for _, n in parts_q])
        n_slots = len(self._kf_of_slot)
        common = np.bincount(slots, minlength=n_slots)
        scores = 0.5 * np.bincount(slots, np.abs(qv) + np.abs(w) - np.abs(qv - w), minlength=n_slots)
        hit = np.flatnonzero(common)
        kf = np.asarray(self._kf_of_slot, np.int64)[hit]
        common, scores = common[hit], scores[hit]
        if exclude:
            keep = ~np.isin(kf, np.fromiter(exclude, np.int64, len(exclude)))
            kf, common, scores = kf[keep], common[keep], scores[keep]
        return SharedWords(kf, common.astype(np.int64), scores)

    def query(
        self,
        bow: BowVector,
        min_score: float = 0.0,
        max_results: int | None = None,
        exclude: Collection[int] = (),
    ) -> list[tuple[int, float]]:
        """Keyframes by decreasing L1 score (ties: lower id first), score >= min_score.

        Only keyframes sharing at least one word are returned (others score 0).
        """
        sw = self.shared_words(bow, exclude)
        keep = sw.scores >= min_score
        kf, sc = sw.kf_ids[keep], sw.scores[keep]
        order = np.lexsort((kf, -sc))
        if max_results is not None:
            order = order[:max_results]
        return [(int(kf[i]), float(sc[i])) for i in order]


def _group_candidates(
    sw: SharedWords,
    eligible: NDArray[np.bool_],
    min_score: float,
    covisibles: Covisibles | None,
    best_acc_init: float,
) -> list[int]:
    """ORB-SLAM2's common-word filter, covisibility-group accumulation and 75 % cut."""
    if not eligible.any():
        return []
    max_common = int(sw.common[eligible].max())
    min_common = COMMON_WORDS_RATIO * max_common
    scored = eligible & (sw.common > min_common)
    score_of = {int(k): float(s) for k, s in zip(sw.kf_ids[scored], sw.scores[scored])}
    matches = [(k, s) for k, s in score_of.items() if s >= min_score]
    if not matches:
        return []
    best_acc = best_acc_init
    groups: list[tuple[float, float, int]] = []  # (acc score, best score, best kf)
    for kf, s in matches:
        acc, best_s, best_kf = s, s, kf
        if covisibles is not None:
            for nb in covisibles(kf, GROUP_SIZE):
                s2 = score_of.get(nb)
                if s2 is None or nb == kf:
                    continue
                acc += s2
                if s2 > best_s:
                    best_s, best_kf = s2, nb
        groups.append((acc, best_s, best_kf))
        best_acc = max(best_acc, acc)
    cut = GROUP_SCORE_RATIO * best_acc
    out: list[int] = []
    seen: set[int] = set()
    for acc, _, kf in sorted(groups, key=lambda g: (-g[0], -g[1], g[2])):
        if acc > cut and kf not in seen:
            seen.add(kf)
            out.append(kf)
    return out


def detect_loop_candidates(
    db: KeyframeDatabase,
    kf_id: int,
    bow: BowVector,
    covisible_ids: Iterable[int],
    min_score: float,
    covisibles: Covisibles | None = None,
) -> list[int]:
    """Loop candidates for keyframe ``kf_id`` (ORB-SLAM2 DetectLoopCandidates).

    Keyframes sharing words with ``bow`` but not connected to the query
    (``covisible_ids``, and the query itself) are kept if they share more than 80 % of
    the best common-word count and score >= ``min_score`` (ORB-SLAM2 passes the lowest
    score of the query's covisibles). Each survivor's score is accumulated over its
    group of ``covisibles(kf, 10)`` (neighbours that passed the word filter); groups
    above 75 % of the best accumulated score give their best keyframe. Returned by
    decreasing group score, without duplicates. Without ``covisibles`` each group is
    the keyframe alone.
    """
    connected = set(covisible_ids)
    connected.add(kf_id)
    sw = db.shared_words(bow)
    eligible = ~np.isin(sw.kf_ids, np.fromiter(connected, np.int64, len(connected)))
    return _group_candidates(sw, eligible, min_score, covisibles, best_acc_init=min_score)


def detect_relocalisation_candidates(
    db: KeyframeDatabase, bow: BowVector, covisibles: Covisibles | None = None
) -> list[int]:
    """Relocalisation candidates for a lost frame (ORB-SLAM2 DetectRelocalizationCandidates).

    As :func:`detect_loop_candidates` with no keyframe excluded and no minimum score.
    (ORB-SLAM2 may add a stale score for a neighbour that failed the word filter; here
    such neighbours add nothing, as in its loop detection.)
    """
    sw = db.shared_words(bow)
    eligible = np.ones(len(sw.kf_ids), bool)
    return _group_candidates(sw, eligible, 0.0, covisibles, best_acc_init=0.0)
