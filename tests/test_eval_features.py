"""Tables 6 and 7 (SDF-SLAM V-B): the correct-match rule and eqs. 11-14 on exact
correspondences, and ``semslam eval-features`` on a small render."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from semslam.cli.main import main
from semslam.eval.feature_eval import correct_matches, lookup_depth, pose_errors, relative_pose_pnp, table6_targets
from semslam.geometry.se3 import invert, make_pose, so3_exp
from semslam.nets.fp_dataset import FPSequence
from semslam.nets.fpfdcnn import FPFDCNN, save_fpfdcnn
from semslam.synth import SEQUENCES, render_sequence
from tests.fpf_plane import write_plane_sequence


def test_correct_within_5_px_and_exact_matches_give_the_true_pose(tmp_path: Path):
    write_plane_sequence(tmp_path / "plane", [0.0, 0.1])
    p = FPSequence(tmp_path / "plane").pair(0, 1)
    xy1, xy2 = p.xy1[p.valid], p.xy2[p.valid]
    off = np.zeros_like(xy2)
    off[::3, 0], off[1::3, 1] = 5.0, -5.5  # on the +-5 px border: correct; beyond: wrong
    judged, correct = correct_matches(xy1, xy2 + off, p.depth1, p.camera, p.T_wc1, p.T_wc2)
    assert judged.all() and correct[::3].all() and not correct[1::3].any() and correct[2::3].all()
    T_true = invert(p.T_wc2) @ p.T_wc1
    T_est, n_in = relative_pose_pnp(xy1, lookup_depth(p.depth1, xy1), xy2, p.camera)
    assert n_in == len(xy1)
    err = pose_errors(T_est, T_true)
    assert err.trans_err_m < 1e-6 and err.rot_err_deg < 1e-4 and err.err_t < 1e-6 and err.err_r < 1e-6


def test_pose_errors_follow_eqs_11_to_14():
    T_true = make_pose(np.eye(3), [0.1, 0.0, 0.0])
    dR = so3_exp([0.0, 0.0, np.radians(2.0)])
    T_est = invert(make_pose(dR, [0.0, 0.01, 0.0])) @ T_true  # T_true = ΔT PT with a known ΔT
    e = pose_errors(T_est, T_true)
    assert e.rot_err_deg == pytest.approx(2.0) and e.trans_err_m == pytest.approx(0.01)
    assert e.err_r == pytest.approx(np.linalg.norm(dR - np.eye(3)))
    assert e.trans_err_pct == pytest.approx(10.0) and e.rot_err_deg_per_m == pytest.approx(20.0)


def test_table6_targets_need_blurred_at_least_orb_and_clear_within_2_points():
    def row(method, scenario, rate):
        return {"method": method, "scenario": scenario, "correct_rate": rate}

    rows = [row("orb+bf", "clear", 0.902), row("orb+bf", "blurred", 0.726),
            row("a", "clear", 0.8821), row("a", "blurred", 0.726),  # 2.0 points below; level
            row("b", "clear", 0.8819), row("b", "blurred", 0.7259)]  # just beyond both
    a = {t["scenario"]: t for t in table6_targets(rows, "a")}
    b = {t["scenario"]: t for t in table6_targets(rows, "b")}
    assert a["clear"]["met"] and a["blurred"]["met"] and not b["clear"]["met"] and not b["blurred"]["met"]
    assert a["clear"]["gap_points"] == pytest.approx(-1.99) and a["blurred"]["reference_pct"] == pytest.approx(72.6)
    assert table6_targets(rows[:2], "a") == []  # no row of the method: nothing judged


def test_eval_features_cli_on_a_small_render(tmp_path: Path):
    seq = render_sequence(SEQUENCES["static_xyz"].replace(frames=7, fps=10.0), tmp_path / "render", workers=1)
    torch.manual_seed(0)
    weights = save_fpfdcnn(tmp_path / "w.pt", FPFDCNN(0.25), {"command": "test"})
    out = tmp_path / "t.json"
    assert main(["eval-features", str(seq), "--gap", "2", "--every", "2", "--weights", str(weights),
                 "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    rows = {(r["method"], r["scenario"]): r for r in res["rows"]}
    assert set(rows) == {(m, s) for m in ("orb+bf", "fpfdcnn+range", "fpfdcnn+range+mutual")
                         for s in ("clear", "blurred")}
    orb = rows[("orb+bf", "clear")]
    assert orb["pairs"] == 3 and orb["correct_rate"] > 0.8 and orb["trans_err_m"] < 0.02  # ORB works on clear frames
    fp = rows[("fpfdcnn+range", "clear")]
    assert fp["matches"] > 0 and fp["points_per_image"] == 500
    judged = [t for t in res["targets"] if t["judged"]]  # the mutual row, clear and blurred
    assert {(t["method"], t["scenario"]) for t in judged} == {("fpfdcnn+range+mutual", s) for s in ("clear", "blurred")}
    assert len(res["targets"]) == 4
    assert main(["eval-features", str(tmp_path / "nope")]) == 2
