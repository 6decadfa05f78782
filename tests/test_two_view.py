"""Two-view initialisation (semslam.geometry.two_view, ORB-SLAM3's TwoViewReconstruction):
the estimators and scores against OpenCV and closed forms, the decompositions against
OpenCV's, whole reconstructions of synthetic scenes with known motion, the refusals (pure
rotation, too little parallax, too few matches), and the real TUM fr2_desk frames against
their motion-capture ground truth.

Measured (seeds/frames below, this machine): general scene, 1 px noise, 10 % outliers:
rotation 0.02-0.29 deg, translation direction 0.3-2.0 deg over 12 seeds (seeds 0-2: under
0.9 deg), map scale within 8 % and the shape as good as triangulating with the true pose;
tilted plane, 0.5 px: rotation < 0.1 deg, translation 0.1-1.2 deg. fr2_desk, frame 0 against
frames 18-46 (every 2nd): all succeed, rotation 0.23-0.66 deg, translation direction 0.2-3.1
deg, map depths (metres via the true baseline) within 2.6-7 % of the Kinect's (median); frame 10
(median parallax 0.6 deg) since R_H 0.50 and the multi-start E: rotation 0.17 deg, translation 1.4
deg, depths within 10.2 %.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.stats import norm

from semslam.geometry import two_view as tv
from semslam.geometry.se3 import invert, rotation_angle, so3_exp

K = np.array([[520.9, 0.0, 325.1], [0.0, 521.0, 249.7], [0.0, 0.0, 1.0]])
DIST = np.array([0.2312, -0.7849, -0.0033, -0.0001, 0.9172])
W, H = 640, 480
R_TRUE = so3_exp([0.02, -0.05, 0.01])  # 3.2 deg
T_TRUE = np.array([0.2, 0.03, 0.05])  # 0.21 m
# Over the plane the camera moves sideways: a forward component leaves the plane's two
# decompositions with points in front in both (Faugeras' ambiguity, refused as ambiguous).
T_PLANE = np.array([0.2, 0.03, 0.01])


def project(X: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Xc = X @ R.T + t
    p = Xc @ K.T
    return p[:, :2] / p[:, 2:3], Xc[:, 2]


def add_noise_and_outliers(rng: np.random.Generator, uv1: np.ndarray, uv2: np.ndarray, noise: float,
                           outliers: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    uv1 = uv1 + rng.normal(0.0, noise, uv1.shape)
    uv2 = uv2 + rng.normal(0.0, noise, uv2.shape)
    out = np.zeros(len(uv1), bool)
    out[rng.choice(len(uv1), int(outliers * len(uv1)), replace=False)] = True
    uv2[out] = rng.uniform([0, 0], [W, H], (out.sum(), 2))
    return uv1, uv2, out


def box_scene(rng: np.random.Generator, R: np.ndarray = R_TRUE, t: np.ndarray = T_TRUE, n: int = 400,
              noise: float = 1.0, outliers: float = 0.1):
    """Points in a box 2-6 m in front of view 1, seen in both views."""
    X = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.1, 1.1, n), rng.uniform(2, 6, n)])
    uv1, _ = project(X, np.eye(3), np.zeros(3))
    uv2, _ = project(X, R, t)
    return (X, *add_noise_and_outliers(rng, uv1, uv2, noise, outliers))


def plane_scene(rng: np.random.Generator, n: int = 400, noise: float = 0.5, outliers: float = 0.1,
                t: np.ndarray = T_PLANE):
    """A plane tilted 30 deg from fronto-parallel, 3 m away, filling view 1."""
    normal = np.array([0.2, -0.5, 1.0]) / np.linalg.norm([0.2, -0.5, 1.0])
    px = rng.uniform([10, 10], [W - 10, H - 10], (4 * n, 2))
    rays = np.column_stack([px, np.ones(len(px))]) @ np.linalg.inv(K).T
    X = rays * (3.0 / (rays @ normal))[:, None]
    uv2, z2 = project(X, R_TRUE, t)
    seen = (z2 > 0) & (uv2[:, 0] >= 0) & (uv2[:, 0] < W) & (uv2[:, 1] >= 0) & (uv2[:, 1] < H)
    X = X[seen][:n]
    uv1, _ = project(X, np.eye(3), np.zeros(3))
    return (X, *add_noise_and_outliers(rng, uv1, project(X, R_TRUE, t)[0], noise, outliers))


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def check_accuracy(r: tv.TwoViewResult, X: np.ndarray, uv1: np.ndarray, uv2: np.ndarray,
                   out: np.ndarray, t_true: np.ndarray = T_TRUE) -> None:
    """Pose within 0.5 deg / 2 deg; map in the truth's scale once |t| = 1 is undone; points no
    worse than triangulating the same matches with the true pose (the noise's own floor)."""
    assert r.ok, r.reason
    assert np.degrees(rotation_angle(r.R.T @ R_TRUE)) < 0.5
    assert angle_deg(r.t, t_true) < 2.0
    assert np.linalg.norm(r.t) == pytest.approx(1.0)
    tri = r.triangulated
    # F's 1-D gate at 3.841 keeps ~80 % of the true matches at 1 px; H's 2-D gate ~65 %.
    assert tri.sum() >= 0.9 * r.inliers.sum() and tri.sum() >= 0.6 * (~out).sum()
    assert out[tri].sum() <= 2  # random matches are not mapped
    est = r.points[tri] * np.linalg.norm(t_true)
    truth = X[tri]
    # The map's scale: |t| = 1 makes the median depth ratio 1 up to the pose's error (a
    # 0.2 deg rotation error against 2-5 deg of parallax moves depths by ~5 %).
    scale = np.median(truth[:, 2] / est[:, 2])
    assert scale == pytest.approx(1.0, abs=0.1)
    P1 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = K @ np.hstack([R_TRUE, t_true.reshape(3, 1)])
    Xh = cv2.triangulatePoints(P1, P2, uv1[tri].T, uv2[tri].T)
    oracle = (Xh[:3] / Xh[3]).T
    # The shape, once that scale is removed: no worse than the noise's floor.
    err = np.median(np.linalg.norm(scale * est - truth, axis=1) / truth[:, 2])
    floor = np.median(np.linalg.norm(oracle - truth, axis=1) / truth[:, 2])
    assert err < 1.3 * floor + 0.005, (err, floor)
    assert err < 1.5 * floor + 0.01, (err, floor)


# --------------------------------------------------------------------------------------
# estimators, scores and decompositions against independent references


def test_dlts_match_opencv_on_exact_data() -> None:
    rng = np.random.default_rng(0)
    X, uv1, uv2, _ = box_scene(rng, noise=0.0, outliers=0.0)
    n1, T1 = tv.normalise_points(uv1)
    n2, T2 = tv.normalise_points(uv2)
    assert np.allclose(np.abs(n1).mean(0), 1.0) and np.allclose(n1.mean(0), 0.0)
    F = T2.T @ tv.fundamental_dlt(n1, n2) @ T1
    F_cv, _ = cv2.findFundamentalMat(uv1, uv2, cv2.FM_8POINT)
    assert np.allclose(F / F[2, 2], F_cv / F_cv[2, 2], atol=1e-6)
    assert np.linalg.matrix_rank(F, tol=1e-9 * np.abs(F).max()) == 2
    _, uv1p, uv2p, _ = plane_scene(rng, noise=0.0, outliers=0.0)
    Hm = np.linalg.inv(tv.normalise_points(uv2p)[1]) @ tv.homography_dlt(
        tv.normalise_points(uv1p)[0], tv.normalise_points(uv2p)[0]) @ tv.normalise_points(uv1p)[1]
    H_cv, _ = cv2.findHomography(uv1p, uv2p, 0)
    assert np.allclose(Hm / Hm[2, 2], H_cv / H_cv[2, 2], atol=1e-8)


def test_scores_of_exact_models_are_the_full_bonus() -> None:
    """A model that fits every match exactly scores 2 x 5.991 per match (ORB-SLAM's bonus in
    both views); a match off by 3 px along x fails both gates."""
    rng = np.random.default_rng(1)
    _, uv1, uv2, _ = box_scene(rng, noise=0.0, outliers=0.0)
    tx = np.array([[0, -T_TRUE[2], T_TRUE[1]], [T_TRUE[2], 0, -T_TRUE[0]], [-T_TRUE[1], T_TRUE[0], 0]])
    F = np.linalg.inv(K).T @ tx @ R_TRUE @ np.linalg.inv(K)
    score, inl = tv.score_fundamental(F, uv1, uv2)
    assert score == pytest.approx(2 * 5.991 * len(uv1), rel=1e-9) and inl.all()
    _, uv1p, uv2p, _ = plane_scene(rng, noise=0.0, outliers=0.0)
    Hm, _ = cv2.findHomography(uv1p, uv2p, 0)
    bad = uv2p.copy()
    bad[0, 0] += 3.0  # 9 px^2 > 5.991 in view 2; its transfer to view 1 is ~3 px off too
    score, inl = tv.score_homography(Hm, uv1p, bad)
    assert not inl[0] and inl[1:].all()
    assert score == pytest.approx(2 * 5.991 * (len(uv1p) - 1), rel=1e-6)


def test_score_ratio_of_a_plane_follows_the_noise_model() -> None:
    """On a plane both models fit (F is degenerate), and ORB-SLAM's scores then favour F
    because its distances are 1-D. Closed form, noise sigma per coordinate in both views:
    H's transfer error^2 ~ Exp(mean 4 sigma^2) per view, F's epipolar distance^2 ~ 2 sigma^2
    chi2(1). sigma = 1: R_H = 0.409, right at ORB-SLAM2's 0.40; sigma = 0.5: 0.477, over 0.40
    and 0.45 but under ORB-SLAM3's 0.50 (a plane goes to F first, where its two motions are
    found not unique, and then to H at ORB-SLAM2's 0.40)."""
    for sigma, expected in ((1.0, 0.409), (0.5, 0.477)):
        m = 4 * sigma**2
        e_h = 5.991 - m * (1 - np.exp(-5.991 / m))
        a = np.sqrt(3.841 / (2 * sigma**2))
        p = 2 * norm.cdf(a) - 1
        e_f = 5.991 * p - 2 * sigma**2 * (p - 2 * a * norm.pdf(a))
        assert e_h / (e_h + e_f) == pytest.approx(expected, abs=1e-3)
        ratios = []
        for seed in range(3):
            rng = np.random.default_rng(seed)
            _, uv1, uv2, _ = plane_scene(rng, noise=sigma, outliers=0.0)
            sets = tv.sample_sets(len(uv1), 200, rng)
            sh = tv.find_homography(uv1, uv2, sets).score
            sf = tv.find_fundamental(uv1, uv2, sets).score
            ratios.append(sh / (sh + sf))
        assert np.mean(ratios) == pytest.approx(expected, abs=0.015), ratios


def test_homography_decomposition_contains_opencvs_and_the_truth() -> None:
    rng = np.random.default_rng(2)
    _, uv1, uv2, _ = plane_scene(rng, noise=0.0, outliers=0.0)
    Hm, _ = cv2.findHomography(uv1, uv2, 0)
    Rs, ts = tv.decompose_homography(Hm, K)
    assert len(Rs) == 8
    for R in Rs:
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)

    def among_ours(R: np.ndarray, t: np.ndarray) -> bool:
        return any(np.allclose(R, Ri, atol=1e-6) and np.allclose(t / np.linalg.norm(t), ti, atol=1e-6)
                   for Ri, ti in zip(Rs, ts))

    n_cv, Rc, tc, _ = cv2.decomposeHomographyMat(Hm, K)
    assert n_cv == 4
    assert all(among_ours(R, t.ravel()) for R, t in zip(Rc, tc))
    assert among_ours(R_TRUE, T_PLANE)
    # A pure rotation's homography has equal singular values: no decomposition.
    assert tv.decompose_homography(K @ R_TRUE @ np.linalg.inv(K), K) is None


def test_essential_decomposition_gives_four_and_the_truth() -> None:
    tx = np.array([[0, -T_TRUE[2], T_TRUE[1]], [T_TRUE[2], 0, -T_TRUE[0]], [-T_TRUE[1], T_TRUE[0], 0]])
    Rs, ts = tv.decompose_essential(tx @ R_TRUE)
    hits = [np.allclose(R, R_TRUE, atol=1e-9) and np.allclose(t, T_TRUE / np.linalg.norm(T_TRUE))
            for R, t in zip(Rs, ts)]
    assert len(Rs) == 4 and sum(hits) == 1


# --------------------------------------------------------------------------------------
# whole reconstructions


@pytest.mark.parametrize("seed", range(3))
def test_general_scene_chooses_fundamental(seed: int) -> None:
    rng = np.random.default_rng(seed)
    X, uv1, uv2, out = box_scene(rng)
    r = tv.reconstruct(uv1, uv2, K, seed)
    assert r.model == tv.FUNDAMENTAL and r.ratio_h < 0.3
    assert len(r.n_good) == 4
    check_accuracy(r, X, uv1, uv2, out)
    assert r.parallax_orb_deg >= r.parallax_deg >= 1.0  # 51st-largest >= median on 300 points


@pytest.mark.parametrize("seed", range(3))
def test_tilted_plane_chooses_homography(seed: int) -> None:
    rng = np.random.default_rng(seed)
    X, uv1, uv2, out = plane_scene(rng, noise=0.5)
    r = tv.reconstruct(uv1, uv2, K, seed)
    assert r.model == tv.HOMOGRAPHY and r.ratio_h > 0.45
    assert len(r.n_good) == 8
    check_accuracy(r, X, uv1, uv2, out, T_PLANE)
    # All points on one plane: n.X = 3 m, once the map is in metres.
    normal = np.array([0.2, -0.5, 1.0]) / np.linalg.norm([0.2, -0.5, 1.0])
    dist = r.points[r.triangulated] @ normal
    assert np.std(dist) / np.median(dist) < 0.03


def test_plane_with_1px_noise_never_gives_a_wrong_map() -> None:
    """At 1 px the plane's R_H (0.41) straddles the threshold; either route must refuse or be
    right (F on a plane is degenerate: its decomposition is ambiguous or without parallax)."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        X, uv1, uv2, out = plane_scene(rng, noise=1.0)
        r = tv.reconstruct(uv1, uv2, K, seed)
        if r.ok:
            assert np.degrees(rotation_angle(r.R.T @ R_TRUE)) < 1.0
            assert angle_deg(r.t, T_PLANE) < 5.0
        else:
            assert r.reason in tv.REASONS


def test_a_planes_two_motions_are_not_unique_and_a_box_has_one() -> None:
    """The refined essential matrices reached from F's and H's starts: on a plane (1 px, moving
    forwards) the plane's two motions are both there, 70-85 deg apart in translation, scoring
    within 4 % of each other (8 % on one seed of 10), so the F route's motion is not unique; on a general scene every
    start ends at one motion (or a far worse one)."""
    ambiguous = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        _, uv1, uv2, _ = plane_scene(rng, noise=1.0, t=T_TRUE)
        sets = tv.sample_sets(len(uv1), 200, np.random.default_rng(seed))
        fit_h, fit_f = tv.find_homography(uv1, uv2, sets), tv.find_fundamental(uv1, uv2, sets)
        optima = tv.essential_optima(fit_f.matrix, fit_h.matrix, uv1, uv2, K)
        far = [m for m in optima if min(angle_deg(m.t, optima[0].t), angle_deg(-m.t, optima[0].t)) > 60.0]
        assert far and max(m.score for m in far) > 0.9 * optima[0].score, seed
        ambiguous += not tv.unique_motion(optima, 0.95, 15.0)
        rng = np.random.default_rng(seed)
        _, uv1, uv2, _ = box_scene(rng)
        sets = tv.sample_sets(len(uv1), 200, np.random.default_rng(seed))
        fit_h, fit_f = tv.find_homography(uv1, uv2, sets), tv.find_fundamental(uv1, uv2, sets)
        optima = tv.essential_optima(fit_f.matrix, fit_h.matrix, uv1, uv2, K)
        assert tv.unique_motion(optima, 0.95, 15.0), seed
        assert min(angle_deg(optima[0].t, T_TRUE), angle_deg(-optima[0].t, T_TRUE)) < 2.0  # sign: cheirality's
    assert ambiguous >= 9, ambiguous  # seed 9: the other motion at 0.92 of the best


def test_plane_moving_forwards_is_refused_or_right() -> None:
    """Over a plane moving forwards both routes are ambiguous (the plane's two motions have
    points in front): refused, or (1 of 24 cases measured: seed 9, 1 px, 5.6 deg) F's best
    motion, never the plane's other one (70-85 deg away)."""
    refused = 0
    for seed in range(12):
        for noise in (0.5, 1.0):
            rng = np.random.default_rng(seed)
            _, uv1, uv2, _ = plane_scene(rng, noise=noise, t=T_TRUE)
            r = tv.reconstruct(uv1, uv2, K, seed)
            if r.ok:
                assert angle_deg(r.t, T_TRUE) < 8.0 and np.degrees(rotation_angle(r.R.T @ R_TRUE)) < 1.0
            else:
                refused += 1
                assert r.reason in (tv.AMBIGUOUS, tv.PLANAR), r.reason
    assert refused >= 20, refused


def test_pure_rotation_is_refused() -> None:
    for seed in range(3):
        rng = np.random.default_rng(seed)
        _, uv1, uv2, _ = box_scene(rng, R=so3_exp([0.03, -0.08, 0.02]), t=np.zeros(3))
        r = tv.reconstruct(uv1, uv2, K, seed)
        assert not r.ok
        assert r.reason in (tv.DEGENERATE_HOMOGRAPHY, tv.AMBIGUOUS, tv.LOW_PARALLAX,
                            tv.TOO_FEW_TRIANGULATED), r.reason
        assert not r.triangulated.any() and np.isnan(r.points).all()


def test_too_little_parallax_is_refused() -> None:
    """3 mm of baseline at 2-6 m: under 0.1 deg of parallax."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        _, uv1, uv2, _ = box_scene(rng, t=np.array([0.003, 0.0, 0.0]))
        r = tv.reconstruct(uv1, uv2, K, seed)
        assert not r.ok and r.reason in (tv.LOW_PARALLAX, tv.AMBIGUOUS, tv.DEGENERATE_HOMOGRAPHY), r.reason


def test_too_few_matches() -> None:
    rng = np.random.default_rng(0)
    _, uv1, uv2, _ = box_scene(rng, n=49, outliers=0.0)
    r = tv.reconstruct(uv1, uv2, K, 0)
    assert not r.ok and r.reason == tv.TOO_FEW_MATCHES and r.points.shape == (49, 3)
    with pytest.raises(ValueError):
        tv.reconstruct(uv1, uv2[:-1], K, 0)


def test_reconstruct_is_deterministic_for_a_seed() -> None:
    rng = np.random.default_rng(4)
    _, uv1, uv2, _ = box_scene(rng)
    a, b = tv.reconstruct(uv1, uv2, K, 7), tv.reconstruct(uv1, uv2, K, np.random.default_rng(7))
    assert a.ok and np.array_equal(a.R, b.R) and np.array_equal(a.triangulated, b.triangulated)


def test_normalise_initial_map() -> None:
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.normal(size=(101, 2)), rng.uniform(2, 6, 101)])
    pts[5] = np.nan
    T = np.eye(4)
    T[:3, 3] = [0.6, 0.0, 0.8]
    med = np.nanmedian(pts[:, 2])
    p, T2, s = tv.normalise_initial_map(pts, T)
    assert s == pytest.approx(1 / med)
    assert np.nanmedian(p[:, 2]) == pytest.approx(1.0)
    assert np.isnan(p[5]).all()
    assert np.allclose(T2[:3, 3], T[:3, 3] / med) and np.array_equal(T2[:3, :3], T[:3, :3])
    # Reprojection is unchanged by the scaling: the map is only rescaled.
    Xc = np.vstack([p[:5], p[6:]]) @ T2[:3, :3].T + T2[:3, 3]
    Xo = np.vstack([pts[:5], pts[6:]]) @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(Xc[:, :2] / Xc[:, 2:], Xo[:, :2] / Xo[:, 2:])
    with pytest.raises(ValueError):
        tv.normalise_initial_map(-pts, T)
    with pytest.raises(ValueError):
        tv.normalise_initial_map(np.full((3, 3), np.nan), T)


# --------------------------------------------------------------------------------------
# real frames


FR2_DESK = "rgbd_dataset_freiburg2_desk_first50"


def _listed(path: Path) -> list[tuple[float, str]]:
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return [(float(r[0]), r[1]) for r in rows]


def test_real_fr2_desk_against_ground_truth(shared_data: Path) -> None:
    """ORB features of frame 0 and frame k (ratio-tested Hamming matches, undistorted with
    the fr2 calibration) against the motion-capture relative pose. Also the map: its depths,
    in metres via the true baseline, against the Kinect depth of frame 0."""
    from semslam.io.trajectory import read_tum

    seq = shared_data / FR2_DESK
    if not seq.is_dir():
        pytest.skip(f"{seq} not found")
    frames = _listed(seq / "rgb.txt")
    depths = _listed(seq / "depth.txt")
    gt = read_tum(seq / "groundtruth.txt")

    def pose(i: int) -> np.ndarray:
        return gt.poses[int(np.argmin(np.abs(gt.timestamps - frames[i][0])))]

    orb = cv2.ORB_create(2000)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    img0 = cv2.imread(str(seq / frames[0][1]), cv2.IMREAD_GRAYSCALE)
    kp0, d0 = orb.detectAndCompute(img0, None)
    depth0 = cv2.imread(str(seq / depths[0][1]), cv2.IMREAD_UNCHANGED).astype(np.float64) / 5000.0
    results = {}
    for k in (10, 20, 30, 40):
        kp, d = orb.detectAndCompute(cv2.imread(str(seq / frames[k][1]), cv2.IMREAD_GRAYSCALE), None)
        good = [a for a, b in matcher.knnMatch(d0, d, k=2) if a.distance < 0.8 * b.distance]
        p1 = np.float64([kp0[m.queryIdx].pt for m in good])
        p2 = np.float64([kp[m.trainIdx].pt for m in good])
        uv1 = cv2.undistortPoints(p1.reshape(-1, 1, 2), K, DIST, P=K).reshape(-1, 2)
        uv2 = cv2.undistortPoints(p2.reshape(-1, 1, 2), K, DIST, P=K).reshape(-1, 2)
        T21 = invert(pose(k)) @ pose(0)
        r = tv.reconstruct(uv1, uv2, K, 0)
        results[k] = r
        if not r.ok:
            continue
        rot = np.degrees(rotation_angle(r.R.T @ T21[:3, :3]))
        tdir = angle_deg(r.t, T21[:3, 3])
        assert rot < 1.5, (k, rot)
        assert tdir < 5.0, (k, tdir)
        # Map depths (metres through the true baseline) against the sensor's, at the
        # distorted keypoints of frame 0.
        px = np.round(p1[r.triangulated]).astype(int)
        z_sensor = depth0[px[:, 1], px[:, 0]]
        z_map = r.points[r.triangulated, 2] * np.linalg.norm(T21[:3, 3])
        has = z_sensor > 0
        assert has.sum() > 100
        rel = np.abs(z_map[has] / z_sensor[has] - 1.0)
        # Frame 10, the least parallax accepted (median 0.6 deg): 10.2 %.
        assert np.median(rel) < 0.12, (k, np.median(rel))
        print(f"fr2_desk 0-{k}: {r.model} R_H {r.ratio_h:.2f} rot {rot:.2f} deg, t dir {tdir:.2f} deg, "
              f"{r.triangulated.sum()} points, parallax {r.parallax_deg:.1f} deg, depth error {np.median(rel):.3f}")
    assert any(results[k].ok for k in (10, 20, 30)), {k: r.reason for k, r in results.items()}
    # Where it refuses, it says why.
    assert all(r.ok or r.reason in tv.REASONS for r in results.values())
