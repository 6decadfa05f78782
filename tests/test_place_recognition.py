"""Place recognition: the shipped ORB vocabulary, bags of words, the keyframe database and
ORB-SLAM2's loop / relocalisation candidate selection.

Retrieval is checked on images the vocabulary was not trained on: the real Kinect frames
(held out of training) and synthetic frames of seeds not used in training (``loop``).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.place import (
    BowVector,
    KeyframeDatabase,
    Vocabulary,
    detect_loop_candidates,
    detect_relocalisation_candidates,
    hamming,
    l1_score,
    load_default_vocabulary,
)
from semslam.place.train_vocab import kmajority, make_orb, orb_descriptors, to_gray, train_from_descriptors
from semslam.synth import SEQUENCES, Renderer

VOCAB_FILE = Path(__file__).resolve().parents[1] / "semslam" / "data" / "orb_vocab.npz"
N_LOOP = 12


@pytest.fixture(scope="module")
def vocab() -> Vocabulary:
    return load_default_vocabulary()


@pytest.fixture(scope="module")
def orb() -> cv2.ORB:
    return make_orb(1000)


@pytest.fixture(scope="module")
def loop_images() -> list[np.ndarray]:
    """12 grayscale frames spread along the full ``loop`` sequence (last pose = first)."""
    cfg = SEQUENCES["loop"]
    r = Renderer(cfg)
    idx = np.linspace(0, cfg.frames - 1, N_LOOP).round().astype(int)
    return [to_gray(r.render(int(i)).rgb) for i in idx]


@pytest.fixture(scope="module")
def image_set(loop_images: list[np.ndarray]) -> list[np.ndarray]:
    """20 different images: real Kinect/TUM frames (when present) + synthetic loop views."""
    from tests.conftest import SHARED_DATA

    real = []
    for pattern in ("kinect_rgbd_5frames/color/*.png", "images_people/*.png"):
        for f in sorted(SHARED_DATA.glob(pattern)):
            real.append(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
    return real + loop_images[: 20 - len(real)]


def _shift_brighten(gray: np.ndarray) -> np.ndarray:
    m = np.float32([[1, 0, 24], [0, 1, 12]])
    shifted = cv2.warpAffine(gray, m, (gray.shape[1], gray.shape[0]), borderMode=cv2.BORDER_REFLECT)
    return cv2.convertScaleAbs(shifted, alpha=1.15, beta=20)


# ------------------------------------------------------------------------- vocabulary
def test_shipped_vocabulary_loads_with_stated_shape(vocab: Vocabulary) -> None:
    assert VOCAB_FILE.stat().st_size <= 2_000_000
    assert load_default_vocabulary() is vocab  # cached
    assert (vocab.k, vocab.levels) == (8, 5)
    assert vocab.metadata["k"] == vocab.k and vocab.metadata["levels"] == vocab.levels
    assert 20_000 <= vocab.n_words <= vocab.k**vocab.levels
    assert vocab.metadata["n_images"] >= 100 and vocab.metadata["n_descriptors"] >= 100_000
    assert np.all(vocab.idf >= 0) and np.all(np.isfinite(vocab.idf))
    # Tree shape: every non-root node has one parent; leaves are exactly the words.
    kids = vocab.children[vocab.children >= 0]
    assert len(np.unique(kids)) == len(kids) == vocab.n_nodes - 1
    assert np.all(vocab.depth[vocab.word_node] <= vocab.levels)


def test_hamming_matches_bit_count() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (7, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    ref = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
    np.testing.assert_array_equal(hamming(a, b), ref)


def test_vectorised_descent_equals_one_by_one(vocab: Vocabulary, loop_images: list[np.ndarray], orb: cv2.ORB) -> None:
    desc = orb_descriptors(loop_images[0], orb)
    leaves = vocab.leaf_nodes(desc)
    for i in range(0, len(desc), 17):
        node = 0
        while (vocab.children[node] >= 0).any():
            ch = vocab.children[node][vocab.children[node] >= 0]
            node = int(ch[hamming(desc[i : i + 1], vocab.node_desc[ch])[0].argmin()])
        assert leaves[i] == node


def test_transform_is_deterministic_normalised_and_covers_features(
    vocab: Vocabulary, loop_images: list[np.ndarray], orb: cv2.ORB
) -> None:
    desc = orb_descriptors(loop_images[3], orb)
    bow, fv = vocab.transform(desc)
    bow2, fv2 = vocab.transform(desc.copy())
    np.testing.assert_array_equal(bow.words, bow2.words)
    np.testing.assert_array_equal(bow.weights, bow2.weights)
    assert np.all(np.diff(bow.words) > 0) and np.all(bow.weights > 0)
    assert bow.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert fv.keys() == fv2.keys()
    # Every feature exactly once, grouped under nodes at the feature-vector depth.
    all_idx = np.concatenate(list(fv.values()))
    np.testing.assert_array_equal(np.sort(all_idx), np.arange(len(desc)))
    assert list(fv) == sorted(fv)
    assert np.all(vocab.depth[list(fv)] <= vocab.feature_depth())
    words = vocab.words_of(desc)
    for node, idx in fv.items():  # each feature's leaf descends from its group node
        np.testing.assert_array_equal(vocab.ancestors_at(vocab.word_node[words[idx]], vocab.depth[node]), node)
    # levels_up as in DBoW2: 0 groups by leaf.
    _, fv_leaf = vocab.transform(desc, levels_up=0)
    assert set(fv_leaf) == set(vocab.word_node[words].tolist())
    assert vocab.bow(np.zeros((0, 32), np.uint8)).words.size == 0


def test_save_load_roundtrip(tmp_path: Path, vocab: Vocabulary, loop_images: list[np.ndarray], orb: cv2.ORB) -> None:
    path = tmp_path / "v.npz"
    vocab.save(path)
    again = Vocabulary.load(path)
    np.testing.assert_array_equal(again.node_desc, vocab.node_desc)
    np.testing.assert_array_equal(again.children, vocab.children)
    desc = orb_descriptors(loop_images[1], orb)
    np.testing.assert_allclose(again.bow(desc).weights, vocab.bow(desc).weights, rtol=1e-6)


# ------------------------------------------------------------------------- retrieval
def test_image_retrieves_itself_among_twenty(vocab: Vocabulary, image_set: list[np.ndarray], orb: cv2.ORB) -> None:
    bows = [vocab.bow(orb_descriptors(g, orb)) for g in image_set]
    db = KeyframeDatabase()
    for i, b in enumerate(bows):
        db.add(i, b)
    for i, b in enumerate(bows):
        (best, s1), (_, s2) = db.query(b, max_results=2)
        assert best == i and s1 == pytest.approx(1.0) and s2 < 0.7


def test_shifted_brightened_copy_finds_original(vocab: Vocabulary, image_set: list[np.ndarray], orb: cv2.ORB) -> None:
    db = KeyframeDatabase()
    for i, g in enumerate(image_set):
        db.add(i, vocab.bow(orb_descriptors(g, orb)))
    ratios = []
    for i, g in enumerate(image_set):
        (best, s1), (_, s2) = db.query(vocab.bow(orb_descriptors(_shift_brighten(g), orb)), max_results=2)
        assert best == i
        ratios.append(s1 / s2)
    assert min(ratios) > 1.15, ratios  # measured: >= 1.3, median ~2


def test_loop_sequence_closes_on_first_frames(vocab: Vocabulary, loop_images: list[np.ndarray], orb: cv2.ORB) -> None:
    """The camera ends where it started: the last frame's best non-neighbour is an early one."""
    bows = [vocab.bow(orb_descriptors(g, orb)) for g in loop_images]
    db = KeyframeDatabase()
    for i, b in enumerate(bows[:-1]):
        db.add(i, b)
    last = N_LOOP - 1
    neighbours = {last - 1, last - 2}
    ranked = db.query(bows[last], exclude=neighbours)
    assert ranked[0][0] in (0, 1), ranked[:3]

    def covisibles(kf: int, n: int) -> list[int]:  # a chain: covisible = temporal neighbours
        return [j for j in (kf - 1, kf + 1, kf - 2, kf + 2) if 0 <= j < last][:n]

    min_score = min(l1_score(bows[last], bows[j]) for j in neighbours)
    cands = detect_loop_candidates(db, last, bows[last], neighbours, min_score, covisibles)
    assert cands and cands[0] in (0, 1), cands
    assert not neighbours & set(cands)
    reloc = detect_relocalisation_candidates(db, bows[last], covisibles)
    assert reloc and set(reloc) <= {0, 1, last - 2, last - 1}


# ------------------------------------------------------------------------- database
def _random_bow(rng: np.random.Generator, n_words: int = 200, size: int = 40) -> BowVector:
    words = np.sort(rng.choice(n_words, size, replace=False)).astype(np.int32)
    w = rng.random(size) + 0.01
    return BowVector(words, w / w.sum())


def _dense(b: BowVector, n: int = 200) -> np.ndarray:
    v = np.zeros(n)
    v[b.words] = b.weights
    return v


def test_scores_match_dense_l1_and_erase_works() -> None:
    rng = np.random.default_rng(1)
    bows = {i * 3: _random_bow(rng) for i in range(30)}
    db = KeyframeDatabase()
    for k, b in bows.items():
        db.add(k, b)
    q = _random_bow(rng)
    for kf, score in db.query(q):
        dense = 1.0 - 0.5 * np.abs(_dense(q) - _dense(bows[kf])).sum()
        assert score == pytest.approx(dense, abs=1e-12)
        assert l1_score(q, bows[kf]) == pytest.approx(dense, abs=1e-12)
    ranked = db.query(q)
    assert [s for _, s in ranked] == sorted((s for _, s in ranked), reverse=True)
    assert len(db.query(q, max_results=5)) == 5
    assert all(s >= 0.2 for _, s in db.query(q, min_score=0.2))
    assert 6 not in [k for k, _ in db.query(q, exclude={6})]
    # Erase: gone from results, others unchanged, slot reused by a later add.
    before = dict(db.query(q))
    db.erase(6)
    db.erase(12345)  # unknown: ignored
    after = dict(db.query(q))
    assert 6 not in after and 6 not in db and len(db) == 29
    assert all(after[k] == pytest.approx(before[k]) for k in after)
    db.add(1000, bows[6])
    assert dict(db.query(q))[1000] == pytest.approx(before[6])
    db.add(1000, bows[9])  # re-adding replaces
    assert dict(db.query(q))[1000] == pytest.approx(before[9]) and len(db) == 30
    for k in list(db.ids()):
        db.erase(k)
    assert db.query(q) == [] and len(db) == 0


def test_loop_candidate_selection_follows_orbslam2() -> None:
    """Covisible keyframes are excluded, groups accumulate, weak groups are cut."""
    base = np.arange(0, 100, dtype=np.int32)

    def bow(words: np.ndarray) -> BowVector:
        return BowVector(words.astype(np.int32), np.full(len(words), 1.0 / len(words)))

    query = bow(base)
    db = KeyframeDatabase()
    db.add(1, bow(base[:95]))  # connected to the query: never a loop candidate
    db.add(10, bow(base[:90]))  # a group of 10, 11, 12 seeing the same place
    db.add(11, bow(base[1:92]))
    db.add(12, bow(base[4:90]))
    db.add(20, bow(base[:92]))  # strong single keyframe, no covisibles sharing words
    db.add(30, bow(base[:40]))  # too few common words (< 80 % of the best)
    groups = {10: [11, 12], 11: [10, 12], 12: [10, 11], 20: [], 30: [], 1: []}

    def covisibles(kf: int, n: int) -> list[int]:
        return groups.get(kf, [])[:n]

    cands = detect_loop_candidates(db, 99, query, covisible_ids=[1], min_score=0.5, covisibles=covisibles)
    # Scores are |words| / 100 here. Group {10,11,12} accumulates 0.90 + 0.91 + 0.86,
    # keyframe 20 alone 0.92 < 0.75 * 2.67: only the group's best keyframe (11) survives.
    assert cands == [11]
    assert detect_loop_candidates(db, 99, query, [1], min_score=0.5) == [20, 11, 10, 12]
    assert detect_loop_candidates(db, 99, query, [1], min_score=0.99) == []
    reloc = detect_relocalisation_candidates(db, query, covisibles)
    assert reloc == [11]  # keyframe 1 (0.95) alone is below 0.75 of the group's sum
    assert detect_relocalisation_candidates(KeyframeDatabase(), query) == []


# ------------------------------------------------------------------------- training
def test_kmajority_centres_are_bitwise_majorities() -> None:
    rng = np.random.default_rng(0)
    centres = rng.integers(0, 256, (3, 32), dtype=np.uint8)
    bits = np.unpackbits(centres, axis=1)
    noisy = np.repeat(bits, 40, axis=0) ^ (rng.random((120, 256)) < 0.05)
    desc = np.packbits(noisy.astype(np.uint8), axis=1)
    got, labels = kmajority(desc, 3, np.random.default_rng(1))
    assert len(got) == 3 and len(np.unique(labels)) == 3
    for c in range(3):
        members = np.unpackbits(desc[labels == c], axis=1)
        majority = (2 * members.sum(axis=0) >= len(members)).astype(np.uint8)
        np.testing.assert_array_equal(np.unpackbits(got[c]), majority)
    assert sorted(map(bytes, got)) == sorted(map(bytes, centres))  # recovers the true centres


def test_train_small_vocabulary_and_cli(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    per_image = [rng.integers(0, 256, (300, 32), dtype=np.uint8) for _ in range(6)]
    v = train_from_descriptors(per_image, k=4, levels=3, seed=0)
    assert v.n_words <= 4**3 and v.metadata["n_images"] == 6
    assert np.all(vocab_leaf_counts(v, np.concatenate(per_image)) > 0)
    v2 = train_from_descriptors(per_image, k=4, levels=3, seed=0)
    np.testing.assert_array_equal(v.node_desc, v2.node_desc)  # seeded: reproducible

    import typer

    from semslam.cli import train_cmd

    app = typer.Typer()
    train_cmd.register(app)
    train_cmd.register(app)  # idempotent
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(3):
        img = cv2.resize(rng.integers(0, 256, (60, 80), dtype=np.uint8), (320, 240), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(folder / f"{i}.png"), img)
    out = tmp_path / "voc.npz"
    res = CliRunner().invoke(app, ["train", "vocab", "--images", str(folder), "--out", str(out), "--k", "4", "--levels", "2", "-q"])
    assert res.exit_code == 0, res.output
    trained = Vocabulary.load(out)
    assert trained.k == 4 and trained.metadata["n_images"] == 3
    assert "semslam train vocab --images" in trained.metadata["command"]
    bad = CliRunner().invoke(app, ["train", "vocab", "--out", str(out)])
    assert bad.exit_code != 0


def vocab_leaf_counts(v: Vocabulary, desc: np.ndarray) -> np.ndarray:
    """How many training descriptors reach each word (every word should be reachable)."""
    return np.bincount(v.words_of(desc), minlength=v.n_words)
