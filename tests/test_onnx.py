"""The shipped networks through ONNX Runtime (``semslam/data/*.onnx``) equal them in torch
(``*.pt``, the checkpoints they were exported from), and inference needs no torch.

References are independent of the ONNX path: each torch output is computed as the code
before ONNX did (the checkpoint's model, normalisation and ``F.interpolate`` /
``F.grid_sample`` / ``F.max_pool2d`` written out here), on a real TUM frame and on a
synthetic render. Tolerance 1e-4 on every output whose values are probabilities, metres
or descriptors. SDFCNN's segmentation logits (values up to ~22) are compared as the
probabilities they stand for and within 1e-4 of their range: their absolute differences
are 8e-5 on these frames (up to 1.4e-4 on freiburg2_desk frames), which is float32 noise
(torch's own float32 result is 8.6e-5 from a float64 evaluation of the same weights).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from semslam.nets import outputs
from semslam.nets.onnx_load import load_net
from semslam.nets.onnx_runtime import OnnxNet, intra_op_threads

torch = pytest.importorskip("torch")
import torch.nn.functional as F  # noqa: E402

pytestmark = pytest.mark.usefixtures("torch_one_thread")

DATA = Path(__file__).resolve().parents[1] / "semslam" / "data"
SHIPPED = {"stdc_person": "stdc1", "dunet_person": "dunet", "sdfcnn": "sdfcnn", "fpfdcnn": "fpfdcnn"}
TOL = 1e-4


@pytest.fixture(scope="module", params=["real", "synthetic"])
def frame(request: pytest.FixtureRequest) -> np.ndarray:
    """640x480 RGB: TUM fr3 walking (a person in view) or a held-out synthetic render."""
    if request.param == "real":
        shared = request.getfixturevalue("shared_data")
        return cv2.cvtColor(cv2.imread(str(shared / "images_people" / "fr3_walking_person.png")), cv2.COLOR_BGR2RGB)
    from semslam.synth import SEQUENCES, Renderer

    return Renderer(SEQUENCES["walking_halfsphere"].replace(frames=80, seed=204, fps=3.0)).render(40).rgb


def _torch_segmentation(stem: str, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """STDC / DUNet as the torch backend computed them: (probabilities at the network's
    size, probabilities at the frame's size, meta)."""
    from semslam.nets.models import load_checkpoint

    model, meta = load_checkpoint(DATA / f"{stem}.pt")
    small = cv2.resize(rgb, tuple(meta["input_size"]), interpolation=cv2.INTER_AREA)
    x = torch.from_numpy(small).permute(2, 0, 1)[None].float().div(255.0)
    x = (x - torch.tensor(meta["mean"]).view(1, 3, 1, 1)) / torch.tensor(meta["std"]).view(1, 3, 1, 1)
    with torch.inference_mode():
        prob = torch.softmax(model(x), dim=1)
        full = F.interpolate(prob, rgb.shape[:2], mode="bilinear", align_corners=False)
    return prob.numpy(), full[0].numpy(), meta


@pytest.mark.parametrize("stem", ["stdc_person", "dunet_person"])
def test_segmenters_equal_torch(stem: str, frame: np.ndarray) -> None:
    from semslam.nets.segmenters import DunetSegmenter, StdcSegmenter

    ref_small, ref_full, meta = _torch_segmentation(stem, frame)
    small = cv2.resize(frame, tuple(meta["input_size"]), interpolation=cv2.INTER_AREA)
    (prob,) = OnnxNet(DATA / f"{stem}.onnx").run(small[None])
    np.testing.assert_allclose(prob, ref_small, rtol=0, atol=TOL)
    seg = (StdcSegmenter if stem.startswith("stdc") else DunetSegmenter)()  # the shipped .onnx
    assert seg.weights_path.suffix == ".onnx"
    np.testing.assert_allclose(seg.probabilities(frame), ref_full, rtol=0, atol=TOL)
    labels, names, conf = seg.segment_with_confidence(frame)
    person = ref_full[1] > seg.threshold
    clear = np.abs(ref_full[1] - seg.threshold) > TOL  # pixels not on the threshold itself
    assert ((labels == 15) == person)[clear].all() and names == {0: "background", 15: "person"}
    np.testing.assert_allclose(conf, np.where(person, ref_full[1], ref_full[0]), rtol=0, atol=TOL)
    assert person.mean() > 0.01  # both frames show people: the comparison covers both classes


def test_sdfcnn_equals_torch(frame: np.ndarray) -> None:
    from semslam.nets.models import load_checkpoint
    from semslam.nets.sdfcnn import normalise
    from semslam.semantics.sdfcnn_backend import SdfcnnPredictor

    model, _ = load_checkpoint(DATA / "sdfcnn.pt")
    with torch.inference_mode():
        seg_ref, depth_ref = model.heads(normalise(torch.from_numpy(frame).permute(2, 0, 1)[None]))
    seg, depth = OnnxNet(DATA / "sdfcnn.onnx").run(frame[None])
    np.testing.assert_allclose(depth, depth_ref.numpy(), rtol=0, atol=TOL)
    np.testing.assert_allclose(torch.softmax(torch.from_numpy(seg), 1).numpy(), torch.softmax(seg_ref, 1).numpy(),
                               rtol=0, atol=TOL)
    scale = float(seg_ref.abs().max())
    assert np.abs(seg - seg_ref.numpy()).max() <= TOL * scale  # see the module doc
    pred = SdfcnnPredictor().predict(frame)  # the shipped .onnx through the backend
    ref_labels = outputs.upsampled_argmax(seg_ref[0].numpy(), (640, 480)) + 1  # NYU ids 1..40
    assert (pred.labels() == ref_labels).mean() > 0.9999  # at most a few tie pixels on class borders
    ref_depth = F.interpolate(depth_ref, (480, 640), mode="bilinear", align_corners=False)[0, 0].clamp(min=0)
    np.testing.assert_allclose(pred.depth(), ref_depth.numpy(), rtol=0, atol=TOL)


def test_fpfdcnn_equals_torch(frame: np.ndarray) -> None:
    from semslam.features.fpfdcnn import FpfdcnnExtractor
    from semslam.nets.fpfdcnn import load_fpfdcnn, sample_descriptors, to_tensor

    gray = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    model, _ = load_fpfdcnn(DATA / "fpfdcnn.pt")
    with torch.inference_mode():
        prob_ref, coarse_ref = model(to_tensor(gray))
    prob, coarse = OnnxNet(DATA / "fpfdcnn.onnx").run(gray[None, None])
    np.testing.assert_allclose(prob, prob_ref.numpy(), rtol=0, atol=TOL)
    np.testing.assert_allclose(coarse, coarse_ref.numpy(), rtol=0, atol=TOL)
    onnx_kp = FpfdcnnExtractor(500).extract(gray)  # the shipped .onnx
    torch_kp = FpfdcnnExtractor(500, weights=DATA / "fpfdcnn.pt").extract(gray)
    assert len(onnx_kp) == 500 and len(torch_kp) == 500
    same = {tuple(p) for p in onnx_kp.xy.tolist()} & {tuple(p) for p in torch_kp.xy.tolist()}
    assert len(same) >= 498  # the 500th point may swap with a near-equal one
    with torch.inference_mode():
        desc_ref = sample_descriptors(coarse_ref, torch.from_numpy(onnx_kp.xy)[None])[0].numpy()
    np.testing.assert_allclose(onnx_kp.descriptors, desc_ref, rtol=0, atol=TOL)


def test_shipped_onnx_files_come_from_the_shipped_checkpoints() -> None:
    """Each .onnx records the checkpoint it was exported from; a retrained .pt needs a new export."""
    import onnx

    for stem, arch in SHIPPED.items():
        path = DATA / f"{stem}.onnx"
        meta = load_net(path, arch).meta
        digest = hashlib.sha256((DATA / f"{stem}.pt").read_bytes()).hexdigest()
        assert meta["onnx_export"]["source_sha256"] == digest, f"{path.name} is stale: run `semslam export-onnx`"
        assert meta["arch"] == arch and meta["parameters"] > 0 and path.stat().st_size < 3e6
        inits = onnx.load(str(path)).graph.initializer
        half = sum(i.data_type == onnx.TensorProto.FLOAT16 for i in inits)
        assert half > 0.9 * sum(i.data_type in (onnx.TensorProto.FLOAT16, onnx.TensorProto.FLOAT) for i in inits)


# ------------------------------------------------------------------- output layers

@pytest.mark.parametrize("size", [(640, 480), (97, 61), (20, 15)])
def test_upsample_equals_interpolate(size: tuple[int, int]) -> None:
    maps = torch.rand(1, 5, 15, 20)
    ref = F.interpolate(maps, size[::-1], mode="bilinear", align_corners=False)[0].numpy()
    np.testing.assert_allclose(outputs.upsample(maps[0].numpy(), size), ref, rtol=0, atol=1e-5)


def test_nms_equals_max_pooling() -> None:
    prob = np.round(np.random.default_rng(3).random((37, 53)).astype(np.float32), 2)  # with ties
    t = torch.from_numpy(prob)[None, None]
    ref = (t == F.max_pool2d(t, 9, stride=1, padding=4))[0, 0].numpy()
    assert (outputs.nms_points(prob, 4) == ref).all()


def test_descriptors_at_equals_grid_sample() -> None:
    from semslam.nets.fpfdcnn import sample_descriptors

    coarse = torch.randn(1, 256, 6, 8)
    xy = np.array([[0, 0], [127, 95], [5, 90], [64, 33], [100, 7], [7.5, 8.25]], np.float32)
    ref = sample_descriptors(coarse, torch.from_numpy(xy)[None])[0].numpy()
    np.testing.assert_allclose(outputs.descriptors_at(coarse[0].numpy(), xy), ref, rtol=0, atol=1e-6)


# ------------------------------------------------------------------------- export

def test_export_command_writes_an_equal_network(tmp_path: Path) -> None:
    """``semslam export-onnx`` on a freshly trained-format checkpoint (random STDC, float16
    weights as saved): the .onnx holds its meta and gives torch's outputs at two sizes."""
    from semslam.cli.main import main
    from semslam.nets.models import build_model, save_checkpoint
    from semslam.nets.onnx_graphs import TorchNet

    torch.manual_seed(0)
    meta = {"arch": "stdc1", "width": 0.125, "class_ids": [0, 15], "class_names": ["background", "person"],
            "input_size": [64, 48], "mean": [0.485, 0.456, 0.406], "std": [0.229, 0.224, 0.225], "note": "test"}
    pt = save_checkpoint(tmp_path / "tiny.pt", build_model("stdc1", 2, 0.125), meta)
    assert main(["export-onnx", str(pt), "--out", str(tmp_path / "onnx")]) == 0
    net = load_net(tmp_path / "onnx" / "tiny.onnx", "stdc1")
    assert net.meta["note"] == "test" and net.meta["onnx_export"]["source"] == "tiny.pt"
    ref = TorchNet(pt, "stdc1")
    for w, h in ((64, 48), (96, 72)):  # the export size and another (dynamic axes)
        x = np.random.default_rng(w).integers(0, 256, (1, h, w, 3), dtype=np.uint8)
        np.testing.assert_allclose(net.run(x)[0], ref.run(x)[0], rtol=0, atol=TOL)


def test_wrong_architecture_and_bad_file_are_one_line_errors(tmp_path: Path) -> None:
    from semslam.errors import DataError

    with pytest.raises(DataError, match=r"sdfcnn\.onnx: holds a sdfcnn network, not fpfdcnn"):
        load_net(DATA / "sdfcnn.onnx", "fpfdcnn")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(DataError, match=r"bad\.onnx: cannot load ONNX network"):
        load_net(bad, "stdc1")


def test_session_threads_follow_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("SEMSLAM_ONNX_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # what runtime.limit_threads sets for the CLI
    assert intra_op_threads() == 1
    monkeypatch.setenv("SEMSLAM_ONNX_THREADS", "3")
    assert intra_op_threads() == 3
    monkeypatch.delenv("SEMSLAM_ONNX_THREADS")
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert intra_op_threads() == 0  # ONNX Runtime's default, as torch's


# --------------------------------------------------------------- without torch

NO_TORCH = textwrap.dedent('''
    import importlib.abc, json, sys, time

    class NoTorch(importlib.abc.MetaPathFinder):
        """As if torch were not installed (in this process: worker processes do not re-run this script)."""
        def find_spec(self, name, path, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, NoTorch())
    import open3d  # noqa: F401 - the mesh builder's library (the runs skip the mesh: see the test)
    from semslam.cli.main import main

    if __name__ == "__main__":
        seq, out, pt = sys.argv[1:4]
        runs = {p: [] for p in ("orb", "f2kf", "default", "ddl", "stdc", "sdf_paper", "sdf_rgbd")}
        runs["stdc+net"] = ["--preset", "stdc", "--set", "semantics.backend=stdc"]
        runs["ddl+net"] = ["--preset", "ddl", "--set", "semantics.backend=dunet", "--set", "semantics.input_width=160"]
        codes, seconds = {}, {}
        for name, args in runs.items():
            args = args or ["--preset", name]
            t0 = time.perf_counter()
            codes[name] = main(["run", seq, "--out", f"{out}/{name}", "-q", "--no-report", "--map", "none", *args])
            seconds[name] = round(time.perf_counter() - t0, 1)
        # A user's .pt needs torch: one line, exit 2.
        codes["pt"] = main(["run", seq, "--out", f"{out}/pt", "-q", "--preset", "stdc", "--set",
                            "semantics.backend=stdc", "--set", f"semantics.weights={pt}"])
        print(json.dumps({"codes": codes, "seconds": seconds, "torch_loaded": "torch" in sys.modules}))
''')


@pytest.mark.slow
def test_every_preset_runs_without_torch(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:
    """``semslam run`` with every preset (and the stdc / dunet backends) in a process where
    torch cannot be imported: all finish, torch is never loaded, and a .pt is refused in one line.
    No maps (``--map none``): their worker process costs seconds per run, and in a run this
    short (one keyframe) the mesh builder fails on an empty mesh (as on main); Open3D, the
    mesh's library, is imported in the process all the same. ``make wheel-test`` runs the
    presets with their maps in an environment without torch."""
    from semslam.synth import SEQUENCES, render_sequence

    seq = render_sequence(SEQUENCES["walking_xyz"].replace(frames=6, width=320, height=240),
                          tmp_path_factory.mktemp("notorch") / "walk", progress=False, workers=1)
    script = tmp_path / "no_torch.py"
    script.write_text(NO_TORCH)
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(script), str(seq), str(tmp_path / "runs"), str(DATA / "stdc_person.pt")],
                          capture_output=True, text=True, cwd=root, env=_env(root), timeout=600)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["torch_loaded"] is False, proc.stderr[-2000:]
    codes = result["codes"]
    assert codes.pop("pt") == 2 and "needs torch" in proc.stderr
    assert codes == {name: 0 for name in codes}, (result["seconds"], proc.stderr[-3000:])
    for name in codes:
        assert len((tmp_path / "runs" / name / "trajectory.txt").read_text().splitlines()) >= 5


def _env(root: Path) -> dict[str, str]:
    import os

    return {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
