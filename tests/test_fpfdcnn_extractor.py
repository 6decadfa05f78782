"""The ``fpfdcnn`` extractor backend: float 256-d descriptors behind the Extractor
protocol, one pyramid level, the mask honoured, weights loaded lazily with a one-line
error when missing; and a tiny training run (``semslam train fpfdcnn``) lowers both losses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from semslam.cli.main import main
from semslam.config import FeatureConfig
from semslam.core import protocols
from semslam.core.types import DescriptorKind
from semslam.errors import DataError
from semslam.features import create_extractor
from semslam.features.fpfdcnn import DEFAULT_WEIGHTS, FpfdcnnExtractor
from semslam.features.matching import L2Matcher, matcher_for
from semslam.nets.fpfdcnn import FPFDCNN, load_fpfdcnn, save_fpfdcnn
from semslam.nets.train_fpfdcnn import FPTrainData, _cell_labels, losses, repeatability
from tests.fpf_plane import CAM, write_plane_sequence


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    return save_fpfdcnn(tmp_path_factory.mktemp("fpf") / "tiny.pt", FPFDCNN(0.25), {"command": "test"})


def test_backend_is_registered_with_a_float_one_level_spec():
    ex = create_extractor(FeatureConfig(extractor="fpfdcnn", n_features=300))
    assert isinstance(ex, protocols.Extractor) and isinstance(ex, FpfdcnnExtractor)
    assert ex.spec.kind is DescriptorKind.FLOAT and ex.spec.dim == 256 and ex.spec.n_levels == 1
    assert ex.spec.dtype is np.float32 and ex.spec.distance == "l2" and 0 < ex.spec.th_low < ex.spec.th_high <= 2
    assert type(matcher_for(ex.spec)) is L2Matcher
    assert ex.weights == DEFAULT_WEIGHTS and ex._model is None  # nothing loaded yet


def test_features_weights_reach_the_extractor_and_only_fpfdcnn_takes_them(tiny_weights: Path):
    """``--set features.weights=my.pt`` runs other FPFDCNN weights; set for an extractor
    without weights it is refused rather than ignored."""
    from semslam.errors import ConfigError

    ex = create_extractor(FeatureConfig(extractor="fpfdcnn", n_features=50, weights=str(tiny_weights)))
    assert ex.weights == tiny_weights and len(ex.extract(np.full((64, 96), 0, np.uint8))) == 0
    assert ex.meta["command"] == "test"  # the tiny checkpoint's, not the shipped one's
    with pytest.raises(ConfigError, match="features.weights: only the fpfdcnn extractor"):
        FeatureConfig(extractor="orb_opencv", weights=str(tiny_weights)).check()


def test_missing_weights_are_one_clear_error(tmp_path: Path):
    ex = FpfdcnnExtractor(weights=tmp_path / "none.pt")
    with pytest.raises(DataError, match=r"none\.pt: FPFDCNN weights not found"):
        ex.extract(np.zeros((48, 64), np.uint8))


def test_extract_gives_float_keypoints_inside_the_mask(tiny_weights: Path):
    ex = FpfdcnnExtractor(n_features=80, weights=tiny_weights, threshold=0.0)
    gray = (np.random.default_rng(1).random((100, 130)) * 255).astype(np.uint8)  # not multiples of 16
    kp = ex.extract(gray)
    assert len(kp) == 80 and kp.descriptors.dtype == np.float32 and kp.descriptors.shape == (80, 256)
    assert (kp.xy >= 0).all() and (kp.xy[:, 0] < 130).all() and (kp.xy[:, 1] < 100).all()
    assert (np.diff(kp.response) <= 0).all() and (kp.octave == 0).all()
    np.testing.assert_allclose(np.linalg.norm(kp.descriptors, axis=1), 1.0, rtol=1e-5)
    mask = np.zeros_like(gray)
    mask[50:, :] = 1
    assert (ex.extract(gray, mask).xy[:, 1] >= 50).all()
    assert ex.meta["command"] == "test"


@pytest.mark.parametrize("target, repeat", [("harris", 0.0), ("corners", 0.0), ("harris", 1.0), ("cells", 1.0)])
def test_tiny_training_run_lowers_its_losses(tmp_path: Path, target: str, repeat: float):
    write_plane_sequence(tmp_path / "plane", [0.0, 0.03, 0.06, 0.09, 0.12])
    out = tmp_path / "fpf.pt"
    args = ["train", "fpfdcnn", "--data", str(tmp_path / "plane"), "--out", str(out), "--width", "0.125",
            "--steps", "60", "--batch", "2", "--crop", "128x96", "--gaps", "1,2", "--blur-p", "0",
            "--lr", "3e-3", "--target", target, "--pos-weight", "5", "--seed", "0", "-q",
            "--repeat-weight", str(repeat)]
    assert main(args) == 0
    trained, meta = load_fpfdcnn(out)
    assert meta["steps"] == 60 and meta["command"].startswith("semslam train fpfdcnn --data")
    assert meta["repeat_weight"] == repeat and ("--repeat-weight" in meta["command"]) == (repeat > 0)
    torch.manual_seed(0)
    initial = FPFDCNN(0.125)  # the training run's initial weights (same seed)
    data = FPTrainData([tmp_path / "plane"], (1, 2), target=target, dense=repeat > 0)
    batch = data.batch(np.random.default_rng(7), 4, (128, 96), 0.0, 64)
    with torch.no_grad():
        before = losses(initial, batch, 5.0)
        after = losses(trained, batch, 5.0)
    assert float(after.det) < 0.8 * float(before.det) and float(after.desc) < 0.8 * float(before.desc)
    if repeat:
        assert float(after.repeat) < float(before.repeat)


def test_cell_labels_keep_each_cells_strongest_corner_and_a_dustbin_elsewhere():
    corners = np.array([[3, 2], [10, 9], [5, 6], [30, 17]])  # strongest first; [5, 6] shares cell (0, 0)
    labels = _cell_labels(corners, 32, 24)
    assert labels.shape == (3, 4)
    assert labels[0, 0] == 2 * 8 + 3 and labels[1, 1] == 1 * 8 + 2 and labels[2, 3] == 1 * 8 + 6
    assert (np.delete(labels.ravel(), [0, 5, 11]) == 64).all()


def test_dense_warp_moves_every_pixel_by_f_t_over_z(tmp_path: Path):
    """The repeatability loss's warp on the analytic plane: frame j's crop pixel of frame
    i's pixel u is u - fx * shift / z (camera moving sideways by ``shift``)."""
    write_plane_sequence(tmp_path / "plane", [0.0, 0.04], z=2.0)
    data = FPTrainData([tmp_path / "plane"], (1,), dense=True)
    x0, y0, cw, ch = 96, 64, 128, 96
    grid, valid = data._dense_warp(data.pairs[0], x0, y0, cw, ch)
    u = (grid[..., 0] + 1) / 2 * cw - 0.5  # back from grid_sample's coordinates to crop pixels
    v = (grid[..., 1] + 1) / 2 * ch - 0.5
    du = CAM.fx * 0.04 / 2.0  # 10.7 px
    ok = valid > 0
    np.testing.assert_allclose(u[ok], (np.arange(cw)[None, :] - du).repeat(ch, 0)[ok], atol=1e-3)
    np.testing.assert_allclose(v[ok], np.arange(ch)[:, None].repeat(cw, 1)[ok], atol=1e-3)
    # Valid exactly where the moved pixel stays inside the crop (the plane has no occlusion).
    assert not ok[:, :int(np.ceil(du))].any() and ok[:, int(np.ceil(du)) + 1:].all()


def test_repeatability_rewards_sharp_agreeing_peaks_only():
    """Two views of the same sharp peaks (identity warp) agree; peaks moved by 3 px in the
    second view do not; flat maps (which a cosine of the two maps would call repeatable)
    score worst: log(64) for an 8x8 patch."""
    h, w = 32, 32
    first = torch.full((1, 1, h, w), -6.0)
    ys, xs = [6, 6, 22, 22], [5, 21, 6, 20]
    for y, x in zip(ys, xs):
        first[0, 0, y, x] = 3.0
    ys_g, xs_g = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    grid = torch.stack([(xs_g + 0.5) / w * 2 - 1, (ys_g + 0.5) / h * 2 - 1], dim=-1)[None].float()
    valid = torch.ones(1, 1, h, w)
    heat = (torch.cat([first, first]) > 0).float()  # the labels: patches holding a peak count
    same = repeatability(torch.cat([first, first]), heat, grid, valid, 8)
    moved = repeatability(torch.cat([first, torch.roll(first, 3, dims=3)]), heat, grid, valid, 8)
    flat = repeatability(torch.full((2, 1, h, w), -6.0), heat, grid, valid, 8)
    assert float(same) < 0.01 and float(moved) > 5.0 and abs(float(flat) - np.log(64)) < 1e-4


def test_no_keypoints_on_an_image_without_structure() -> None:
    """A covered lens or a blank wall: the detector's probabilities alone would still give
    points; the structure gate gives none, and a textured image keeps most of its area."""
    import numpy as np

    from semslam.config import FeatureConfig
    from semslam.features.fpfdcnn import create_extractor, structure_mask

    ex = create_extractor(FeatureConfig(extractor="fpfdcnn", n_features=500))
    for value in (0, 128, 255):
        assert len(ex.extract(np.full((96, 128), value, np.uint8))) == 0
    rng = np.random.default_rng(0)
    textured = rng.integers(0, 255, (96, 128), dtype=np.uint8)
    assert (structure_mask(textured) > 0).mean() > 0.9
    assert len(ex.extract(textured)) > 50


def test_init_continues_from_a_checkpoint_and_refuses_another_width(tmp_path: Path):
    """``--init``: the run starts from the checkpoint's weights (with lr 0 it writes them back
    unchanged, float16 round trip), records where they came from, and a width other than
    the checkpoint's is one clear error."""
    write_plane_sequence(tmp_path / "plane", [0.0, 0.03, 0.06, 0.09])
    base = ["train", "fpfdcnn", "--data", str(tmp_path / "plane"), "--width", "0.125", "--steps", "3",
            "--batch", "1", "--crop", "64x48", "--gaps", "1", "--blur-p", "0", "-q"]
    first, second = tmp_path / "a.pt", tmp_path / "b.pt"
    assert main([*base, "--out", str(first), "--lr", "3e-3"]) == 0
    assert main([*base, "--out", str(second), "--lr", "0", "--init", str(first)]) == 0
    a, meta_a = load_fpfdcnn(first)
    b, meta_b = load_fpfdcnn(second)
    for (name, wa), wb in zip(a.state_dict().items(), b.state_dict().values()):
        if wa.is_floating_point():
            assert torch.equal(wa, wb), name
    assert meta_b["init"]["path"] == str(first) and meta_b["init"]["command"] == meta_a["command"]
    assert "--init" in meta_b["command"]
    assert main([*base, "--out", str(tmp_path / "c.pt"), "--width", "0.25", "--init", str(first)]) == 2
