"""Measure matching thresholds for a float descriptor (``--other``, default ``sift``)
against ORB-SLAM's TH_LOW / TH_HIGH (50 / 100 bits of ORB).

Criterion: the same false-accept rate per comparison. Over all keypoint pairs of images
of *different* scenes (no true match among them: freiburg2_desk frames against the
fr3 office and Kinect frames), ORB's 50 / 100 bits accept a fraction of pairs; the
other descriptor's thresholds are its distances at the same fractions. This needs no
ground truth and does not depend on one scene.

Check: the fraction of *true* matches each keeps. Keypoints of frame A with depth are
moved into frame B (freiburg2_desk pairs ``--gaps`` frames apart) and projected; the
true match is B's only keypoint within ``--px`` px. The relative pose is the ground
truth's refined by PnP-RANSAC (2 px) on the ratio-test matches of both extractors: the
motion-capture poses reproject 1.5-4.5 px off here. Geometric coincidences (a different
feature within 2 px) stay in that set, so its upper quantiles are noise.

    python benchmarks/sift_thresholds.py [--gaps 3,10] [--other sift]

Prints JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from semslam.config import FeatureConfig
from semslam.features import create_extractor
from semslam.features.matching import matcher_for
from semslam.io.sequence import open_sequence
from semslam.io.trajectory import read_tum

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT_SEQ = SHARED / "rgbd_dataset_freiburg2_desk_first50"
OTHER_SCENES = ["images_people/*.png", "kinect_rgbd_5frames/color/*.png"]


def _unrelated_distances(extractor, seq_dir: Path) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Descriptor distances of all keypoint pairs between images of different scenes."""
    matcher = matcher_for(extractor.spec)
    def extract(path: Path):  # type: ignore[no-untyped-def]
        return extractor.extract(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))

    a = [extract(p) for p in sorted((seq_dir / "rgb").glob("*.png"))[::12]]
    b = [extract(p) for g in OTHER_SCENES for p in sorted(SHARED.glob(g))]
    out = []
    for ka in a:
        for kb in b:
            qa = np.repeat(np.arange(len(ka)), len(kb))
            tb = np.tile(np.arange(len(kb)), len(ka))
            out.append(matcher.distances(ka.descriptors[qa], kb.descriptors[tb]).astype(np.float64))
    return np.concatenate(out)


def _pairs(seq_dir: Path, gaps: list[int]):  # type: ignore[no-untyped-def]
    seq = open_sequence(seq_dir)
    gt = read_tum(seq.groundtruth_path)
    frames = list(seq.frames())
    pose = {}
    for f in frames:
        k = int(np.argmin(np.abs(gt.timestamps - f.timestamp)))
        if abs(gt.timestamps[k] - f.timestamp) < 0.02:
            pose[f.index] = gt.poses[k]
    for gap in gaps:
        for a in range(0, len(frames) - gap, max(1, gap // 2)):
            fa, fb = frames[a], frames[a + gap]
            if fa.index in pose and fb.index in pose:
                yield seq.camera, fa, fb, np.linalg.inv(pose[fb.index]) @ pose[fa.index]


def _depth_at(frame, xy: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    u, v = np.rint(xy[:, 0]).astype(int), np.rint(xy[:, 1]).astype(int)
    ok = (u >= 0) & (v >= 0) & (u < frame.depth.shape[1]) & (v < frame.depth.shape[0])
    z = np.zeros(len(xy))
    z[ok] = frame.depth[v[ok], u[ok]]
    return z


def _refine(camera, fa, fb, T_ba, keypoints) -> np.ndarray:  # type: ignore[no-untyped-def]
    """T_ba refined by PnP-RANSAC on the ratio-test matches of every extractor."""
    pts, uvs = [], []
    for spec, ka, kb in keypoints:
        qi, ti, _ = matcher_for(spec).match_brute_force(ka.descriptors, kb.descriptors, np.inf, 0.7)
        z = _depth_at(fa, ka.xy[qi])
        ok = z > 0
        pts.append(camera.backproject(camera.undistort_points(ka.xy[qi][ok]), z[ok]))
        uvs.append(camera.undistort_points(kb.xy[ti][ok]))
    rvec, _ = cv2.Rodrigues(T_ba[:3, :3])
    tvec = T_ba[:3, 3].reshape(3, 1).copy()
    cv2.setRNGSeed(0)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(np.concatenate(pts), np.concatenate(uvs), camera.K,
                                             None, rvec, tvec, useExtrinsicGuess=True,
                                             iterationsCount=500, reprojectionError=2.0)
    if not ok or inl is None or len(inl) < 50:
        return T_ba
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
    return T


def _true_distances(extractor, camera, fa, T_ba, px: float, ka, kb) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Descriptor distance of every keypoint of A to B's only keypoint within ``px`` of its
    projection."""
    matcher = matcher_for(extractor.spec)
    z = _depth_at(fa, ka.xy)
    idx = np.flatnonzero(z > 0)
    pc = camera.backproject(camera.undistort_points(ka.xy)[idx], z[idx])
    pc = pc @ T_ba[:3, :3].T + T_ba[:3, 3]
    front = pc[:, 2] > 0
    idx, uv = idx[front], camera.project(pc[front])
    near = cKDTree(camera.undistort_points(kb.xy)).query_ball_point(uv, px)
    one = np.array([len(n) == 1 for n in near], bool)
    if not one.any():
        return np.zeros(0)
    tb = np.array([n[0] for n, o in zip(near, one) if o], np.intp)
    return matcher.distances(ka.descriptors[idx[one]], kb.descriptors[tb]).astype(np.float64)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seq", type=Path, default=DEFAULT_SEQ)
    ap.add_argument("--gaps", default="3,10")
    ap.add_argument("--px", type=float, default=2.0)
    ap.add_argument("--other", default="sift")
    args = ap.parse_args(argv)
    gaps = [int(g) for g in args.gaps.split(",")]
    names = ["orb_slam2", args.other]
    exts = {n: create_extractor(FeatureConfig(extractor=n)) for n in names}
    dist: dict[str, list[np.ndarray]] = {n: [] for n in names}
    for camera, fa, fb, T_ba in _pairs(args.seq, gaps):
        kps = {n: (ex.extract(fa.gray), ex.extract(fb.gray)) for n, ex in exts.items()}
        T_ba = _refine(camera, fa, fb, T_ba, [(exts[n].spec, *kps[n]) for n in names])
        for n, ex in exts.items():
            dist[n].append(_true_distances(ex, camera, fa, T_ba, args.px, *kps[n]))
    true = {n: np.concatenate(dist[n]) for n in names}
    unrelated = {n: _unrelated_distances(exts[n], args.seq) for n in names}
    orb_th = {"th_low": 50.0, "th_high": 100.0}
    false_accept = {k: float((unrelated["orb_slam2"] <= v).mean()) for k, v in orb_th.items()}
    other_th = {k: float(np.quantile(unrelated[args.other], f)) for k, f in false_accept.items()}
    ths = {"orb_slam2": orb_th, args.other: other_th}
    out = {
        "sequence": str(args.seq), "gaps": gaps, "px": args.px,
        "unrelated_pairs": {n: len(unrelated[n]) for n in names},
        "orb_false_accept_rate": false_accept,
        f"{args.other}_thresholds_at_same_rate": other_th,
        "true_matches": {n: len(true[n]) for n in names},
        "true_matches_kept": {n: {k: float((true[n] <= v).mean()) for k, v in ths[n].items()}
                              for n in names},
        "true_quantiles": {n: {str(p): float(np.quantile(true[n], p))
                               for p in (0.25, 0.5, 0.75, 0.9)} for n in names},
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
