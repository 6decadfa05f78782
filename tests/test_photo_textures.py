"""Photo textures for SDFCNN's training renders (issue 40, item 4): a seeded share of the faces
shows the given photographs, the rest keep their procedural textures texel for texel (so the
default renders cannot change), the same seed gives the same atlas; a real camera's defects
(``sdf_dataset.camera_effects``) keep the geometry; the photo recipe never renders the rooms
held out for evaluation."""

from __future__ import annotations

import random
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.nets.recipes import PHOTOS, RECIPES
from semslam.nets.sdf_dataset import camera_effects
from semslam.synth import textures
from semslam.synth.layouts import get_layout
from semslam.synth.scene import mover_box
from semslam.synth.texture_atlas import PHOTO_SHARE, build_texture_atlas

RED = (255, 0, 0)


@pytest.fixture(scope="module")
def red_photos(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A folder with one photograph, pure red: any texel it reaches has its green and blue from
    the procedural texture underneath only."""
    folder = tmp_path_factory.mktemp("photos")
    img = np.zeros((60, 80, 3), np.uint8)
    img[...] = RED[::-1]  # written as BGR
    cv2.imwrite(str(folder / "red.png"), img)
    return str(folder)


@pytest.fixture(scope="module")
def boxes() -> list:
    """Room 5's smaller boxes (the big walls and floor would only make the atlas slow to build)."""
    small = [b for b in get_layout(5).boxes() if max(b.size) < 1.5]
    return small[:20] + [mover_box(0.0)]


def _atlas(boxes: list, seed: int, photos: str | None) -> np.ndarray:
    return build_texture_atlas(boxes, seed, lights=get_layout(5).lights, photo_textures=photos).levels[0]


def test_photo_faces_come_from_the_photos_and_the_rest_is_unchanged(boxes: list, red_photos: str) -> None:
    plain = _atlas(boxes, 11, None).astype(np.int32)
    photo = _atlas(boxes, 11, red_photos).astype(np.int32)
    assert plain.shape == photo.shape  # same faces, same packing
    changed = np.any(plain != photo, axis=2)
    share = changed.mean()
    assert 0.3 < share < 0.95, share  # PHOTO_SHARE of the faces, weighted by their sizes
    # Where a photo lies, green and blue are at most (1 - 0.7) of the procedural texel (+1 for
    # rounding), red is the photo's: the texels come from the red photograph.
    gb_plain, gb_photo = plain[changed][:, 1:], photo[changed][:, 1:]
    assert np.all(gb_photo <= 0.3 * gb_plain + 1)
    assert np.median(photo[changed][:, 0]) > np.median(plain[changed][:, 0])
    # The other texels are the procedural atlas's, byte for byte.
    assert np.array_equal(plain[~changed], photo[~changed])


def test_photo_choice_per_face_follows_the_share(boxes: list, red_photos: str) -> None:
    photos = textures.load_photos(red_photos)
    from semslam.synth.texture_atlas import _photo_face

    tex = np.full((8, 8, 3), 128, np.uint8)
    picked = [not np.array_equal(_photo_face(tex, 3, b, f, 100.0, photos), tex) for b in boxes for f in range(6)]
    n = len(picked)
    assert abs(np.mean(picked) - PHOTO_SHARE) < 3 * np.sqrt(PHOTO_SHARE * (1 - PHOTO_SHARE) / n) + 0.02


def test_photo_atlas_is_deterministic_per_seed(boxes: list, red_photos: str, tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    cv2.imwrite(str(tmp_path / "noise.png"), rng.integers(0, 256, (64, 64, 3), dtype=np.uint8))
    a, b = _atlas(boxes, 21, str(tmp_path)), _atlas(boxes, 21, str(tmp_path))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _atlas(boxes, 22, str(tmp_path)))


def test_photo_is_the_photo_at_its_physical_size() -> None:
    """A photo printed ``across`` texels wide (0.3-2 m at 100 texels/m): halves black | white,
    mirror-tiled as B W | W B | B W ..., so the transitions are one printed width apart, all
    equal (seed 5 draws no rotation)."""
    src = np.zeros((40, 80, 3), np.uint8)
    src[:, 40:] = 255
    out = textures.photo(np.random.default_rng(5), 600, 20, 100.0, (src,)).astype(np.float32)
    row = out[10, :, 0] > out[10, :, 0].max() / 2
    edges = np.flatnonzero(np.diff(row.astype(np.int8)))
    gaps = np.diff(edges)
    assert len(gaps) >= 2 and gaps.max() - gaps.min() <= 2
    assert 0.3 * 100 - 2 <= gaps.mean() <= 2.0 * 100 + 2


def test_missing_photos_are_an_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        textures.load_photos(str(tmp_path))


def test_camera_effects_keep_the_image_size_and_are_seeded() -> None:
    rgb = np.random.default_rng(1).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    a, b = camera_effects(rgb, random.Random(4)), camera_effects(rgb, random.Random(4))
    assert a.shape == rgb.shape and a.dtype == np.uint8 and np.array_equal(a, b)
    assert not np.array_equal(a, rgb)


def test_photo_recipe_never_renders_the_held_out_rooms() -> None:
    recipe = RECIPES["sdfcnn_photo"]
    layouts = {r.config(Path("/d")).layout for r in recipe.renders}
    assert not layouts & {1, 2, 3} and 50 in layouts
    photo = [r for r in recipe.renders if "photo_textures" in r.overrides]
    assert len(photo) == 16
    assert all(r.config(Path("/d")).photo_textures == str(Path("/d") / PHOTOS) for r in photo)
    assert all("--photo-textures" in r.argv(Path("/d")) for r in photo)
    finetune = next(s for s in recipe.steps if s.output == "sdfcnn.pt")
    data = {a.split("/", 1)[1] for a in finetune.argv if a.startswith("{data}/")}
    assert {r.name for r in photo} <= data and data <= {r.name for r in recipe.renders}
