"""The config tree: one dataclass per component, each the ``section:`` of a preset.

Components receive their own section (``FeatureConfig`` for an extractor, ``SlamConfig``
for the ORB-SLAM core, ...), never the whole tree, unless they wire other components.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from semslam.core.labels import DDL_SLAM_DYNAMIC_CLASSES
from semslam.errors import ConfigError

#: slam.depth_odometry's methods (backend/depth_odometry.py): photometric (``rgbd``), depth
#: ICP (``icp``) or both (``rgbd_icp``).
DEPTH_ODOMETRY_METHODS = ("rgbd", "icp", "rgbd_icp")

#: Sensors the schema knows; a tracker refuses the ones it cannot run yet.
SENSORS = ("rgbd", "mono", "stereo")
#: When a stereo run computes a dense depth image from the pair (depth.stereo_dense).
STEREO_DENSE = ("auto", "always", "never")
#: Values of features.matcher.
FEATURE_MATCHERS = ("default", "range")


@dataclass
class FeatureConfig:
    """Keypoint extractor. Defaults are ORB-SLAM2's for 640x480 RGB-D."""

    extractor: str = "orb_opencv"
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20
    fast_min_threshold: int = 7
    # Frame-to-frame matcher: "default" (the descriptor kind's matcher) or "range"
    # (SDF-SLAM's eq. 8 window matcher, float descriptors; features.range_matcher).
    matcher: str = "default"
    # Weights of a learned extractor we train (fpfdcnn: a .pt checkpoint of `semslam train
    # fpfdcnn` or an .onnx of `semslam export-onnx`); empty = the shipped ones.
    weights: str = ""

    def check(self) -> None:
        """Raise ConfigError on a matcher name no tracker knows, or weights for an extractor
        that takes none (they would be silently ignored)."""
        if self.matcher not in FEATURE_MATCHERS:
            raise ConfigError(f"features.matcher: unknown matcher {self.matcher!r} (known: {', '.join(FEATURE_MATCHERS)})")
        if self.weights and self.extractor != "fpfdcnn":
            raise ConfigError(f"features.weights: only the fpfdcnn extractor takes weights, not {self.extractor!r}")


@dataclass
class TrackingConfig:
    """Which tracker runs (a registry name: ``orb_slam``, ``frame_to_keyframe``)."""

    method: str = "frame_to_keyframe"


@dataclass
class FrameToKeyframeConfig:
    """The foundation tracker (preset ``f2kf``): PnP-RANSAC on depth-backed keyframe points."""

    # Hamming distances: ORB-SLAM uses TH_LOW=50 for guided search, TH_HIGH=100 otherwise.
    max_hamming: int = 64
    ratio: float = 0.8
    # Search radius in pixels around the motion-model prediction (ORB-SLAM: 7-15 px x scale).
    search_radius_px: float = 24.0
    # After an unguided pose, re-match by projection within this radius (ORB-SLAM: 10 px).
    refine_radius_px: float = 10.0
    ransac_reprojection_px: float = 3.0
    ransac_iterations: int = 200
    ransac_confidence: float = 0.999
    # A matched point whose measured depth disagrees with the estimated pose by more than
    # this (metres, plus 3 % of depth for Kinect noise) is an outlier.
    depth_check_m: float = 0.05
    min_inliers: int = 20
    # Without a motion prior a wrong pose can gather a few dozen inliers; ORB-SLAM's
    # relocalisation asks for 50.
    min_inliers_unguided: int = 50
    min_depth_m: float = 0.2
    max_depth_m: float = 6.0
    # New keyframe when the tracked points fall below this or the camera moved this far.
    keyframe_min_inliers: int = 200
    keyframe_max_translation_m: float = 0.25
    keyframe_max_rotation_deg: float = 15.0


@dataclass
class SdfSlamConfig:
    """The monocular SDF-SLAM tracker (tracking.method = sdf_slam, ``slam/trackers/sdf_slam.py``):
    PnP-RANSAC on the depth source's depth of a reference, global and local data correction."""

    # What a frame is matched to: the last keyframe ("keyframe": less drift) or the previous
    # frame (the paper's "two adjacent frames"). The other is tried when the first fails.
    reference: str = "keyframe"
    ratio: float = 0.8
    # Guided matching: candidates within this radius (px) of the motion model's projection.
    search_radius_px: float = 30.0
    ransac_reprojection_px: float = 3.0
    ransac_iterations: int = 300
    ransac_confidence: float = 0.999
    min_inliers: int = 25
    # Keypoints whose predicted depth lies outside this range get no 3D point.
    min_depth_m: float = 0.1
    max_depth_m: float = 10.0
    # New keyframe when the inliers fall below this or the camera moved / turned this far.
    keyframe_min_inliers: int = 150
    keyframe_max_translation_m: float = 0.15
    keyframe_max_rotation_deg: float = 10.0
    # Lost this many frames in a row: a new keyframe at the constant-velocity prediction.
    reanchor_after: int = 5
    # Global data correction: every ``global_every`` keyframes, PnP between up to
    # ``global_pairs`` sampled keyframe pairs (at least 2 keyframes apart, cameras within
    # ``global_max_distance_m`` and ``global_max_angle_deg``) adds constraints to a pose graph.
    global_correction: bool = True
    global_every: int = 5
    global_pairs: int = 12
    global_max_distance_m: float = 1.0
    global_max_angle_deg: float = 35.0
    global_min_inliers: int = 40
    # Local data correction: one world position per feature track, the median of its
    # observations' back-projections; tracking uses it for the reference's points.
    local_correction: bool = True
    # ... or, for a track whose keyframe rays spread at least this many degrees, the rays'
    # least-squares intersection (multi-view geometry; not in the paper). 0: the median only.
    min_parallax_deg: float = 0.0
    # Depth alignment (not in the paper): each tracked frame's predicted depth is fitted to
    # the map's depth of its PnP inliers, and its new points and depth map take the fitted
    # depth, so that keyframes keep the map's scale (metric through the first keyframe) instead
    # of each frame's own. "scale": the median ratio; "power": z_map = c * z ** p (scale and
    # depth contrast, fitted in log depth); "none": the paper's raw depth. Needs at least
    # ``alignment_min_points`` inliers with depth; else the last fit is kept.
    depth_alignment: str = "none"
    alignment_min_points: int = 50


@dataclass
class SlamConfig:
    """ORB-SLAM2-class core (tracking.method = orb_slam). Defaults are ORB-SLAM2's TUM RGB-D settings."""

    # Virtual stereo baseline x fx (ORB-SLAM TUM yaml Camera.bf = 40): ur = u - bf / z.
    bf: float = 40.0
    # Rolling shutter readout (top row to bottom row, ms; 0 = global shutter), a camera
    # calibration value: keypoints are moved to the middle row's time with the motion
    # model's velocity before tracking (geometry/rolling_shutter.py).
    rolling_shutter_ms: float = 0.0
    # With a rolling shutter: the depth image is a global frame at the colour frame's
    # timestamp (RGB-D sensors), so keypoints' depths are read where they land after the move,
    # not under their raw pixel (which held another point then).
    rolling_shutter_global_depth: bool = True
    # With a rolling shutter: once the frame has a pose from the motion model, redo the move
    # with the velocity that pose gives (the previous frame's is wrong when a turn starts or
    # stops) before searching the local map.
    rolling_shutter_refine: bool = True
    # With a rolling shutter: that velocity fitted with the pose to the raw matches (each row
    # its own pose, backend/rolling_shutter_pose.py), after the first match and again after
    # the local map.
    rolling_shutter_solve: bool = True
    # Motion blur: a frame whose features track weakly (local-map inliers below
    # depth_odometry_below, or none) or that turns faster than depth_odometry_turn_deg a
    # frame (predicted or tracked) gets its rotation from dense alignment against the last
    # frame (backend/depth_odometry.py: rgbd = photometric, icp = depth ICP, rgbd_icp = both;
    # none = ORB-SLAM2), its camera centre moved on at the velocity of the last well-tracked
    # frames. Features within depth_odometry_max_deg of it keep their pose (so a sharp
    # sequence tracks as without it); else the local map is searched again from the aligned
    # pose, and unless the frame is sharp (turning slower than depth_odometry_turn_deg) and
    # tracks, or then agrees, it keeps the aligned pose and makes no keyframe unless it
    # turns slower than depth_odometry_keyframe_deg a frame (a new, unmapped view).
    depth_odometry: str = "none"
    depth_odometry_below: int = 200
    depth_odometry_turn_deg: float = 1.0
    depth_odometry_max_deg: float = 0.3
    depth_odometry_keyframe_deg: float = 1.0
    # Optional (0 = off, as measured best on walking_hard): a frame whose sharpness (mean
    # |Laplacian| / mean intensity) is at least this ratio of the sharpest of the last 10
    # tracked frames is not aligned unless its features fail, and its re-searched features
    # are believed. 0.6 keeps a rolling shutter without blur as it tracks without the
    # alignment (whose rotation the skew biases), but breaks walking_hard (README).
    depth_odometry_sharp_ratio: float = 0.0
    # Motion blur without dense alignment: a frame whose sharpness is below
    # blur_coast_sharp_ratio x the sharpest of the last 10 tracked frames gets its turn
    # measured from the shift of small images (frontend/shift_rotation.py, PTAM-style), which
    # seeds the search when it says faster than blur_coast_turn_deg a frame. Such a frame
    # (or one whose features put its centre > 3 cm off the steady motion, or find no pose)
    # "coasts": it keeps its camera centre on the motion of the last steady frames and takes
    # only its rotation from its matches (geometry/rotation_about_centre.py: on a blurred
    # frame a 6-DoF fit slides along a far wall). It is not lost and makes no keyframe (its
    # keypoints, smeared along the streak, would put points centimetres off; the third sharp,
    # slowly turning coasted frame in a row does, slam/orb/motion_priors/blur_coast.py COAST_SETTLED_FRAMES), for at most
    # blur_coast_max_frames in a row; once features track again the coasted centres are
    # re-interpolated between the steady frames either side. Until a frame is blurred nothing
    # changes (a sequence without blur gives the same bytes). 0 = off (ORB-SLAM2); `default`
    # sets 0.6.
    blur_coast_sharp_ratio: float = 0.0
    blur_coast_turn_deg: float = 1.0
    blur_coast_max_frames: int = 15
    # Close/far depth threshold in baselines (ThDepth = 40): close if z < th_depth * bf / fx.
    th_depth: float = 40.0
    # Keyframe insertion: at most every max_frames frames without one (ORB-SLAM: fps).
    min_frames: int = 0
    max_frames: int = 30
    # ORB-SLAM2 refuses a keyframe while local mapping has 3 queued. On fast turns tracking
    # then runs out of points (a new keyframe's points come from its depth at once, whatever
    # local mapping's backlog), so when tracking is weak (< 25 % of the reference keyframe's
    # points, or too few close points) a keyframe is taken up to this many queued; local
    # mapping skips fusion and BA while it has a backlog and catches up after the turn.
    max_queued_keyframes_when_weak: int = 12
    min_init_keypoints: int = 500
    local_mapping: bool = True
    local_ba: bool = True
    # ORB-SLAM optimises all covisible keyframes; when keyframes pile up (a large mover
    # makes tracking weak), that grew to seconds per BA here. Cap the window (best
    # covisibles first) and the fixed keyframes (most observations first).
    local_ba_max_keyframes: int = 20
    local_ba_max_fixed: int = 20
    triangulation: bool = True
    keyframe_culling: bool = True
    loop_closing: bool = True
    global_ba: bool = True
    # Loop detection: keyframes since the last loop before a new one is searched.
    loop_min_keyframes: int = 10
    loop_consistency: int = 3
    loop_min_matches: int = 40
    vocabulary: str = "default"
    # Run local mapping and loop closing as threads (ORB-SLAM) or inline (deterministic).
    sequential: bool = False
    # Feed frames at the rate of their timestamps, as a live camera does (and ORB-SLAM3's
    # TUM examples, which sleep until the next frame is due): frames are not segmented or
    # tracked before their time, and each frame's latency is reported. Off: as fast as
    # frames decode.
    realtime: bool = False
    # The thread that tracks on a CPU of its own, every other thread and worker process on
    # the rest (Linux, 2+ CPUs; runs at once each take their own CPU, see
    # runtime.tracking_core; not with semantics.schedule: every). Off by default: on 2
    # cores it removes tracking's 3-4 ms a frame of waiting for a core (`default` on
    # walking_xyz, -1 to -4 ms median), but the rest of the pipeline then shares one core:
    # map-lock waits p95 1.6-3.0 ms instead of 0.05-2.2, and with local mapping at full
    # priority there the reader fell behind (wall time +10-30 %).
    pin_tracking: bool = False
    # Local mapping starts each step once tracking has finished its frame, waiting at most
    # this long (0: never waits).
    yield_to_tracking_ms: float = 15.0
    localization_only: bool = False
    # Multi-map atlas (ORB-SLAM3): once tracking has been lost and relocalisation has failed
    # for this long (frame timestamps), a new map starts at the next frame with depth; maps
    # merge when one sees a place of another. 0 or negative: ORB-SLAM2, stay lost.
    new_map_after_s: float = 1.0


@dataclass
class DynamicsConfig:
    """What to do about moving content (DDL-SLAM, STDC-SLAM). Off in the plain presets."""

    # Reject keypoints on a-priori dynamic classes found by the segmenter (semantics: section).
    semantic: bool = False
    # Reject keypoints in a band this wide around dynamic masks (DDL-SLAM: mask borders).
    border_px: int = 8
    # DDL-SLAM's multi-view geometry check against the best-overlapping keyframes.
    multiview: bool = False
    multiview_keyframes: int = 5
    # Reference keyframes younger than this (seconds) are used only when too few older ones
    # overlap: a check against views a frame or two old cannot see a slow or just-started
    # mover (the depth threshold below needs it to have moved ~0.2 m since). 0: the
    # best-overlapping keyframes whatever their age (DDL-SLAM / DynaSLAM as written).
    multiview_min_age_s: float = 0.0
    # Points seen under a larger parallax are skipped (likely self-occlusion, DynaSLAM).
    parallax_deg: float = 30.0
    # A measured depth this much in front of the projected one marks a seed. Kinect-like
    # noise is ~2 cm at 3 m; people and pushed objects stand 0.3-2 m in front of the
    # background they hide, so 0.15 m + 3 % of depth separates the two.
    depth_threshold_m: float = 0.15
    depth_threshold_rel: float = 0.03
    # Region growing: neighbouring pixels further apart than this in depth split regions;
    # a region is dynamic with >= min_seeds seeds making >= min_dynamic_ratio of its tested
    # points; growing runs at 1/downscale resolution.
    edge_m: float = 0.05
    min_seeds: int = 3
    min_dynamic_ratio: float = 0.3
    downscale: int = 2


SEMANTIC_SCHEDULES = ("every", "when_behind", "latest")
MASK_WARPS = ("pose", "none")


@dataclass
class SemanticsConfig:
    """Segmenter backend, the a-priori dynamic classes and STDC-SLAM's refinement (SRM)."""

    # Registered backend: mediapipe_person (bundled person model, offline, ~10 ms/frame),
    # mediapipe_person_fast (~3 ms, misses people cut by the border), ground_truth (the
    # sequence's own semantic/ labels: an oracle for ablations and tests).
    backend: str = "mediapipe_person"
    # Class names treated as dynamic a priori. Default: DDL-SLAM's movable PASCAL VOC classes.
    dynamic_classes: list[str] = field(default_factory=lambda: list(DDL_SLAM_DYNAMIC_CLASSES))
    # Weights file for trained networks (unused by mediapipe_person / ground_truth).
    weights: str = ""
    # A pixel is labelled with a class when the backend's confidence exceeds this.
    threshold: float = 0.5
    # STDC-SLAM Segmentation Refinement Module: grow the dynamic mask along continuous depth.
    srm: bool = False
    srm_window: int = 17
    srm_tau_m: float = 0.1
    # Resize to this width before inference (0 = native resolution); masks come back native.
    input_width: int = 0
    # Which frames are segmented. "every": all, tracking waits for a mask that is late.
    # "when_behind": a frame decoded while the previous one is still being segmented is
    # skipped (threaded runs only); it gets the last segmented mask, warped to it.
    # "latest": skips the same way, and tracking never waits while an earlier mask is
    # ready: a frame whose segmentation is unfinished gets the newest finished mask, warped.
    schedule: str = "every"
    # Segment only frames whose index is a multiple of this (1 = all), warp the others:
    # falling behind forced, deterministic, to measure what the warp costs.
    stride: int = 1
    # A skipped frame's mask: "pose" (forward-warped with the segmented frame's depth and
    # the motion model's relative pose, dynamics/warp.py) or "none" (as it was).
    warp: str = "pose"
    # Growth (px) of a warped mask per frame since the segmented one, for the people's own
    # motion, which no pose explains (~10 px/frame on the walking renders). With "pose",
    # 8 px covered 98.6-99.4 % of the next frame's true person pixels (4 px: 95.5-96.6 %)
    # for 2.5-3.5 % of the image masked in excess (benchmarks/mask_warp.py).
    warp_margin_px: int = 8

    def check(self) -> None:
        """What the per-field rules (``config/checks.py``) cannot say: a list of names, an
        odd window."""
        if not isinstance(self.dynamic_classes, list) or not all(isinstance(c, str) for c in self.dynamic_classes):
            raise ConfigError(
                f"semantics.dynamic_classes: expected a list of class names, got {self.dynamic_classes!r}"
            )
        if self.srm_window % 2 == 0:
            raise ConfigError(f"semantics.srm_window: expected an odd window size >= 1, got {self.srm_window}")


@dataclass
class DepthConfig:
    """Where metric depth comes from (a registry name): the sensor's depth image for RGB-D."""

    source: str = "sensor"
    # Weights file of a depth network (sdfcnn: an .onnx from `semslam export-onnx` or a .pt
    # checkpoint). Empty: semantics.weights when the segmenter is the same network
    # (semantics.backend == source, one forward pass gives both), else the shipped weights.
    weights: str = ""
    # How the ORB core uses a depth network's depth with a monocular camera: "measurement"
    # (it stands in for a sensor's depth: pseudo-RGB-D) or "prior" (monocular geometry first;
    # the depth scales the initial map and is a weak, checked prior in local BA:
    # slam/orb/depth_prior.py). The sensor's own depth is always a measurement.
    use: str = "measurement"
    # The prior's relative depth uncertainty (1 sigma at the map's median depth).
    prior_sigma: float = 0.2
    # Checks that drop the prior: the robust spread of log(map depth / predicted depth) over
    # a keyframe's points (or the initial pair's) above this, or a keyframe's median log ratio
    # this far from the running scale.
    prior_max_spread: float = 0.25
    prior_max_jump: float = 0.3
    # ... or the ratios' spread above this share of the spread of the map's log depths (the
    # prediction must explain the structure, not only the mean depth).
    prior_max_unexplained: float = 0.5
    # A stereo camera's depth image, computed from the rectified pair (OpenCV's SGBM,
    # frontend/stereo_depth.py) for what reads one: SRM, the multi-view check, the dynamic
    # stage's mask warping, depth odometry, inpainting and the maps. "auto": only when one
    # of them is on; "always"; "never" (keypoints' depths come from ORB-SLAM2's sparse stereo
    # matching either way). Computed at 1/stereo_downscale of the image size.
    stereo_dense: str = "auto"
    stereo_downscale: int = 3

    def resolved(self, semantics: SemanticsConfig) -> DepthConfig:
        """This config with ``weights`` filled in from the segmenter's when it is the same network."""
        if self.weights or semantics.backend != self.source:
            return self
        return replace(self, weights=semantics.weights)


@dataclass
class InpaintingConfig:
    """DDL-SLAM's background inpainting (III-E) before the maps: each keyframe's dynamic
    pixels are filled with the static background the last ``keyframes`` keyframes saw."""

    enabled: bool = True
    keyframes: int = 15
    # A projected source pixel fills a target pixel only if the source's depth agrees with
    # the z-buffer there within this (metres, plus 2 % of the depth for sensor noise).
    depth_tolerance_m: float = 0.03
    # Reject a filled pixel that another remembered keyframe saw through: its point lies in
    # space that keyframe observed as free (its static depth there, the least of a 3x3
    # window, is farther by more than the tolerance). Background cannot be seen through; a
    # mover the masks missed in one keyframe, which another keyframe saw past, can.
    reject_seen_through: bool = True
    # Second stage (DDL-SLAM's future work): holes no keyframe saw, up to this radius in
    # pixels, are filled by OpenCV's image inpainting and marked synthesised (0 = off).
    hole_fill_px: int = 0


@dataclass
class MapsConfig:
    """Map builders fed with keyframe snapshots (registry names: octree, cloud, mesh,
    keyframe_cloud); they run in a mapping thread of their own and write OUT/map/."""

    builders: list[str] = field(default_factory=list)
    # Octree leaf size (OctoMap resolution), metres.
    octree_resolution_m: float = 0.05
    # OctoMap's sensor model: probability of a hit / a miss (a ray passing through), and the
    # upper clamp of a voxel's occupancy. With OctoMap's defaults (0.7 / 0.4 / 0.971) a voxel
    # hit often needs ~9 rays through it before it is free again; with 0.35 / 0.9, ~4, so
    # what a mover left where the masks missed it is carved sooner. Measured (300 frames,
    # benchmarks/maps.py runs rebuilt with `semslam map`): ghost voxels walking_box 547 ->
    # 378, walking_halfsphere 168 -> 140; precision +0.2..+1.4 points, recall -0.1..-0.4.
    octree_prob_hit: float = 0.7
    octree_prob_miss: float = 0.35
    octree_clamping_max: float = 0.9
    # Samples landing in a voxel the octree already holds as free (occupancy below this; with
    # the miss probability above, 0.3 takes two net misses) are not inserted: a static
    # surface cannot appear where earlier rays passed through it, a mover the masks missed
    # can (0 = insert everything). Measured on the maps benchmark's runs rebuilt with
    # `semslam map`: ghost voxels walking_box 502 -> 6, walking_halfsphere 190 -> 164 (0.4:
    # 108), octree recall -0.5..-0.9 points (0.4: -1.3..-1.8), precision up to +3.2.
    octree_appear_free_below: float = 0.3
    # Voxel size of the semantic cloud's downsampling, metres.
    cloud_voxel_m: float = 0.02
    # TSDF voxel size, metres (truncation is 4 voxels).
    mesh_voxel_m: float = 0.02
    # Depth beyond this is not integrated (Kinect-class noise grows with depth squared).
    max_depth_m: float = 4.0
    # Leave the dynamic stage's pixels out of the maps (and inpaint them). false maps every
    # pixel as seen - the baseline that shows the ghosts masking removes.
    mask_dynamic: bool = True
    # Keyframes whose mask tracking took warped from an earlier frame (semantics.schedule:
    # latest, stride) are segmented again in the maps' worker, off the tracking path. Off:
    # measured on walking_halfsphere (300 frames) ghost voxels 134 without against 98 and
    # 245 with (run-to-run spread larger than the effect), and at camera rate (900 frames)
    # the worker no longer kept pace (queue 23 in the first third, 31 at the end).
    segment_keyframes: bool = False
    # Grow the dynamic mask by this many pixels before inpainting and mapping: a mask's edge
    # (segmentation, SRM, a warped mask on frames not segmented) misses the mover's outline.
    dynamic_margin_px: int = 0
    # A folder to write every tracked frame's inpainted RGB, depth and fill mask to
    # (``semslam run --save-inpainted DIR``); empty: none.
    save_inpainted: str = ""
    inpainting: InpaintingConfig = field(default_factory=InpaintingConfig)


@dataclass
class ImuConfig:
    """The IMU, when the input has one (EuRoC / TUM-VI ``imu0``, a bag's Imu topic, the API's
    ``imu=``): its noise from the calibration unless given here, and how tracking uses it
    (``slam/orb/motion_priors/inertial.py``)."""

    # Use the input's IMU when it has one (false: ignore it, visual only).
    use: bool = True
    # Seconds of visually tracked frames before the inertial initialisation (gravity,
    # velocities, biases; backend/inertial_init.py), and the spacing of the frames it uses.
    init_s: float = 1.0
    init_step_s: float = 0.1
    # Seconds after the initialisation at which it is refined on the longer history (twice,
    # as ORB-SLAM3), over at most refine_window_s of it.
    refine_first_s: float = 2.0
    refine_second_s: float = 10.0
    refine_window_s: float = 10.0
    # Frames whose features do not track (black, blurred, covered) are posed by the IMU
    # alone for at most this long, then tracking is lost as without an IMU (ORB-SLAM3's
    # time_recently_lost).
    max_blind_s: float = 5.0
    # A frame after one the IMU posed alone (whose features were dropped), when the motion
    # model and the reference keyframe do not track it, searches the local map from the
    # IMU's pose before the IMU poses it alone too (ORB-SLAM3's recently-lost tracking).
    local_map_recovery: bool = True
    # A keyframe at least this often (ORB-SLAM3's temporal condition for inertial runs, 0.5 s
    # there), from a frame the IMU posed alone too (its points from depth at the IMU's pose, so
    # a view the map never had gets mapped while blind); 0: ORB-SLAM2's decision alone, none
    # while blind. Off by default: on the 320x240 blackout render of the tests the extra
    # keyframes took the RGB-D-inertial run from 0.58 to 2.3 cm (docs/results/inertial.md).
    keyframe_every_s: float = 0.0
    # With a rolling shutter (slam.rolling_shutter_ms): the keypoints moved to the middle
    # row's time by the camera's motion as the IMU measures it at the frame (the gyro's rate,
    # and the velocity once initialised), not by the visual motion (the last interval's, which
    # lags a turn that speeds up, or the one fitted to the few matches a blurred frame keeps).
    rolling_shutter: bool = True
    # The window of recent tracked frames (and its spacing) the velocity and biases are
    # re-estimated on after each frame (GTSAM CombinedImuFactor, backend/inertial_window.py).
    window_s: float = 1.0
    window_step_s: float = 0.1
    # Tracked frames the estimation uses: posed by their features with at least this many
    # inliers (a blurred turn's coasted poses are too rough for velocities and biases).
    min_inliers: int = 50
    # Tracking's pose optimisation held near the IMU's prediction (ORB-SLAM3's inertial
    # tracking, marginalised to the pose): a Gaussian prior whose spread is the last frame's
    # pose error (these two sigmas) plus the velocity's spread over the time since the last
    # frame posed by its features. Off by default: on a held-out hard-imaging render (seed
    # 31) the IMU once posed 150 frames alone and the run ended 125 cm off; with the rolling
    # shutter moved by the IMU it no longer does and helps most runs (docs/results/inertial.md).
    pose_prior: bool = False
    pose_prior_rotation_deg: float = 0.5
    pose_prior_translation_m: float = 0.01
    # The spread of tracking's velocity estimate (m/s), over the time the IMU predicts across:
    # in the pose prior above and the keyframe links below.
    velocity_sigma_m_s: float = 0.05
    # Local BA holds consecutive keyframes to the IMU's motion between them (the frames'
    # predicted motions composed; spreads from the velocity's above and the gyro bias's).
    keyframe_links: bool = True
    # The map rotated about its origin so gravity points down its z axis after the
    # initialisation and each refinement (ORB-SLAM3's gravity-aligned world); off: the map
    # keeps the first camera's frame and gravity is a direction in it.
    gravity_aligned: bool = True
    # Monocular-inertial: the map's scale is taken from an initialisation or refinement only
    # when the motion showed it to this relative spread (1 sigma); else tried again later.
    max_scale_spread: float = 0.05
    # A first, provisional scale applied when shown to this spread, replaced by each better
    # shown one until one is sure (the IMU then predicts and bridges blackouts before the
    # motion has shown the scale well; 0.5 does that about 1.5 s after the two-view
    # initialisation). Off (= max_scale_spread) by default: on a hard-imaging render a 47 %
    # provisional scale and biases from 1.5 s of motion dead-reckoned 146 frames metres off.
    provisional_scale_spread: float = 0.05
    # ... solved on tracked frames at least this far apart: the scale shows in the poses'
    # second differences, whose noise (sqrt(6) sigma / dt^2: 0.02 m/s^2 for 2 mm at 0.5 s, 0.2
    # at 0.15 s) must stay well under a hand-held camera's accelerations (0.2-0.5 m/s^2), or
    # the scale comes out shrunk (errors in the variables).
    scale_step_s: float = 0.5
    # ... and re-estimated on the longer history this long after, then at doubling intervals
    # (each accepted one corrects it).
    scale_refine_s: float = 1.0
    # Noise overrides (0: the calibration's): continuous-time densities and random walks.
    gyro_noise_density: float = 0.0
    acc_noise_density: float = 0.0
    gyro_random_walk: float = 0.0
    acc_random_walk: float = 0.0


@dataclass
class SystemConfig:
    """Root of the config tree."""

    preset: str = "custom"
    # rgbd, stereo (a rectified pair: EuRoC, KITTI, a TUM-like folder with rgb_right/; a
    # stereo input switches rgbd to it) or mono (image folders, TUM folders read without
    # depth: tracking.method sdf_slam, or orb_slam with a depth network as depth.source).
    sensor: str = "rgbd"
    seed: int = 0
    depth_scale: float = 5000.0
    features: FeatureConfig = field(default_factory=FeatureConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    frame_to_keyframe: FrameToKeyframeConfig = field(default_factory=FrameToKeyframeConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    sdf_slam: SdfSlamConfig = field(default_factory=SdfSlamConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    semantics: SemanticsConfig = field(default_factory=SemanticsConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    maps: MapsConfig = field(default_factory=MapsConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
