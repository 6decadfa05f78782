"""What tracking needs of a sensor's frame, per sensor: keypoints (undistorted), a depth and
a right-image coordinate per keypoint where the sensor gives one, empty map-point slots."""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from semslam.config import SystemConfig
from semslam.core.protocols import Extractor
from semslam.core.types import DescriptorKind, FeatureSpec, Frame, Keypoints
from semslam.dynamics.masks import extractor_mask, keypoints_in_mask
from semslam.errors import ConfigError
from semslam.frontend.stereo_depth import right_view_mask
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.frame_state import FrameState
from semslam.frontend.keypoint_depth import sample_depth
from semslam.slam.orb.map import PointSlots
from semslam.features.orb.pyramid import StackedPyramid
from semslam.slam.orb.stereo_matching import compute_stereo_matches, stereo_pyramid


class FrameBuilder(Protocol):
    """Turns one frame's keypoints (and the depth image, where there is one) into a
    ``FrameState``. ``begin`` comes first, with the frame and the mask its keypoints are
    extracted under, for work that can run beside the extraction (a stereo pair's right
    image); ``close`` ends what the builder started."""

    camera: PinholeCamera

    def prepare(self, frame: Frame) -> None:
        """Work on the decoded frame that can run ahead of tracking (the reader thread)."""
        ...

    def begin(self, frame: Frame, mask: NDArray[np.bool_] | NDArray[np.uint8] | None) -> None: ...

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None) -> FrameState: ...

    def close(self) -> None: ...


class _SingleImage:
    """Builders of one image per frame: nothing to start beside the extraction."""

    def prepare(self, frame: Frame) -> None:
        pass

    def begin(self, frame: Frame, mask: NDArray[np.bool_] | NDArray[np.uint8] | None) -> None:
        pass

    def close(self) -> None:
        pass


def _frame(index: int, timestamp: float, kps: Keypoints, xy: NDArray[np.float64], z: NDArray[np.float32],
           ur: NDArray[np.float64]) -> FrameState:
    n = len(kps)
    return FrameState(index, timestamp, kps, xy, z, ur, PointSlots([None] * n), np.zeros(n, bool))


class RgbdFrameBuilder(_SingleImage):
    """Depth read at each keypoint; the right coordinate a stereo camera of baseline
    ``bf / fx`` would see (ORB-SLAM2's virtual right image), -1 without depth."""

    def __init__(self, camera: PinholeCamera, bf: float) -> None:
        self.camera = camera
        self.bf = bf

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None) -> FrameState:
        xy = self.camera.undistort_points(kps.xy)
        if depth_img is not None:
            z = sample_depth(depth_img, kps.xy).astype(np.float32)
        else:
            z = np.zeros(len(kps), np.float32)
        ur = np.where(z > 0, xy[:, 0] - self.bf / np.maximum(z, 1e-6), -1.0)
        return _frame(index, timestamp, kps, xy, z, ur)


class MonocularFrameBuilder(_SingleImage):
    """No depth: every keypoint's depth is 0 and its right coordinate -1 (none). A depth
    network's image, where there is one, is read at the keypoints as ``prior_depth`` only."""

    def __init__(self, camera: PinholeCamera) -> None:
        self.camera = camera

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None = None) -> FrameState:
        n = len(kps)
        frame = _frame(index, timestamp, kps, self.camera.undistort_points(kps.xy), np.zeros(n, np.float32),
                       np.full(n, -1.0))
        if depth_img is not None:
            frame.prior_depth = sample_depth(depth_img, kps.xy).astype(np.float32)
        return frame


#: The left mask is carried to the right image on every 4th pixel (``right_view_mask``'s
#: ``step``): whole-resolution carrying cost as much as the right image's extraction.
RIGHT_MASK_STEP = 4


@dataclass
class StereoViews:
    """What a stereo frame adds to its left keypoints: the right image's keypoints and both
    rectified images (grey, same size), whose pyramids the SAD refinement reads."""

    right_kps: Keypoints
    left_gray: NDArray[np.uint8]
    right_gray: NDArray[np.uint8]
    # The extractors' own pyramids of the two images where they keep them (``last_pyramid``:
    # the same levels ``stereo_pyramid`` builds), so they are not built twice.
    left_pyramid: StackedPyramid | None = None
    right_pyramid: StackedPyramid | None = None


class StereoFrameBuilder:
    """A rectified stereo pair: ORB-SLAM2's stereo matching (``stereo_matching``) gives each
    left keypoint a depth and its matched right coordinate ``ur``; unmatched ones keep depth 0
    and ``ur`` -1. The depth image is not read. Close/far (ThDepth) stays tracking's job.

    The right image's keypoints come from an extractor of its own (``right_extractor``: one
    is not shared by threads): ``prepare`` extracts them in the reader thread ahead of
    tracking, as an RGB-D frame's depth is decoded there, and ``build`` drops those under
    the left image's dynamic region carried across the pair along its depth (a right
    keypoint on a person must not pair with a static left one). A frame that was not
    prepared has them extracted on a thread of the builder's beside the left image's
    extraction (``begin``), under the carried region. ``build`` with ``right`` given (tests,
    tools) uses those views instead."""

    def __init__(self, camera: PinholeCamera, bf: float, spec: FeatureSpec,
                 right_extractor: Extractor | None = None, left_extractor: Extractor | None = None) -> None:
        self.camera = camera
        self.bf = bf
        self.baseline = bf / camera.fx  # ORB-SLAM2's minZ: the nearest depth searched
        self.spec = spec
        self.right_extractor = right_extractor
        self.left_extractor = left_extractor  # tracking's: its pyramid of the left image is reused
        self._pool = (ThreadPoolExecutor(max_workers=1, thread_name_prefix="right-features")
                      if right_extractor is not None else None)
        # The right image's job, its arguments and the left grey image, from ``begin`` to ``build``.
        self._pending: tuple[Future[Keypoints], tuple[Any, ...], NDArray[np.uint8]] | None = None
        # Right images extracted ahead by ``prepare`` (frame index -> keypoints, pyramid), and
        # what ``build`` needs to take one (frame index, mask, depth, left and right grey).
        self._ahead: dict[int, tuple[Keypoints, StackedPyramid]] = {}
        self._taking: tuple[int, Any, Any, NDArray[np.uint8], NDArray[np.uint8]] | None = None
        self._extractor_lock = threading.Lock()  # the reader's prepare and the job share the extractor

    def prepare(self, frame: Frame) -> None:
        """The right image's keypoints (without a mask: segmentation may not have finished)
        and pyramid, in the reader thread ahead of tracking, as an RGB-D frame's depth is
        decoded there; ``build`` drops the keypoints under the left mask carried across."""
        right_gray = frame.right_gray
        if self.right_extractor is None or right_gray is None:
            return
        with self._extractor_lock:
            kps = self.right_extractor.extract(right_gray, None)
        self._ahead[frame.index] = (kps, stereo_pyramid(right_gray, self.spec.n_levels, self.spec.scale_factor))

    def begin(self, frame: Frame, mask: NDArray[np.bool_] | NDArray[np.uint8] | None) -> None:
        right_gray = frame.right_gray
        self._pending = self._taking = None
        if right_gray is None:
            return
        if frame.index in self._ahead:
            self._taking = (frame.index, mask, frame.depth, frame.gray, right_gray)
            return
        if self._pool is None:
            return
        args = (right_gray, mask, frame.depth)
        self._pending = (self._pool.submit(self._extract_right, *args), args, frame.gray)

    def _carried_mask(self, mask: Any, depth: NDArray[np.float32] | None) -> NDArray[np.bool_] | None:
        """The left image's dynamic region (where the extractor ``mask`` is 0) carried into the
        right image along the pair's depth; None without a mask or a depth."""
        if mask is None or depth is None:
            return None
        return right_view_mask(np.asarray(mask) == 0, depth, self.bf, missing="component", step=RIGHT_MASK_STEP)

    def _take_ahead(self) -> StereoViews | None:
        """The right image ``prepare`` extracted, less its keypoints under the carried mask."""
        if self._taking is None:
            return None
        index, mask, depth, left_gray, right_gray = self._taking
        self._taking = None
        kps, pyramid = self._ahead.pop(index)
        for old in [i for i in self._ahead if i < index]:  # frames tracking never took
            self._ahead.pop(old, None)
        dynamic = self._carried_mask(mask, depth)
        if dynamic is not None and len(kps):
            kps = kps.subset(~keypoints_in_mask(kps.xy, dynamic))
        return StereoViews(kps, left_gray, right_gray, _pyramid_of(self.left_extractor, left_gray), pyramid)

    def _extract_right(self, right_gray: NDArray[np.uint8], mask: NDArray[np.bool_] | NDArray[np.uint8] | None,
                       depth: NDArray[np.float32] | None) -> Keypoints:
        """The right image's keypoints, under the left mask carried across the pair (where
        stereo misses part of a masked region, it moves with the rest of its region)."""
        assert self.right_extractor is not None
        dynamic = self._carried_mask(mask, depth)
        right_mask = None if dynamic is None else extractor_mask(dynamic, 0)
        with self._extractor_lock:
            return self.right_extractor.extract(right_gray, right_mask)

    def build(self, index: int, timestamp: float, kps: Keypoints,
              depth_img: NDArray[np.float32] | None = None, right: StereoViews | None = None) -> FrameState:
        n = len(kps)
        # Rectified images: undistortion is the identity unless the camera says otherwise.
        xy = self.camera.undistort_points(kps.xy)
        if right is None:
            right = self._take_ahead()
        if right is None and self._pending is not None:
            job, args, left_gray = self._pending
            self._pending = None
            # Not started yet (the other cores are busy): this thread, done with the left
            # image, extracts the right one itself rather than wait for a core.
            right_kps = self._extract_right(*args) if job.cancel() else job.result()
            right_gray = args[0]
            right = StereoViews(right_kps, left_gray, right_gray, _pyramid_of(self.left_extractor, left_gray),
                                _pyramid_of(self.right_extractor, right_gray))
        if right is None:
            return _frame(index, timestamp, kps, xy, np.zeros(n, np.float32), np.full(n, -1.0))
        sf, levels = self.spec.scale_factor, self.spec.n_levels
        pyr_l = stereo_pyramid(right.left_gray, levels, sf) if right.left_pyramid is None else right.left_pyramid
        pyr_r = stereo_pyramid(right.right_gray, levels, sf) if right.right_pyramid is None else right.right_pyramid
        m = compute_stereo_matches(kps, right.right_kps, pyr_l, pyr_r, sf, self.bf, self.baseline,
                                   th_low=self.spec.th_low, th_high=self.spec.th_high)
        return _frame(index, timestamp, kps, xy, m.depth, m.ur)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)


def _pyramid_of(extractor: Extractor | None, gray: NDArray[np.uint8]) -> StackedPyramid | None:
    """The pyramid ``extractor`` just built of ``gray`` (``last_pyramid``), else None."""
    pyr = getattr(extractor, "last_pyramid", None)
    if not isinstance(pyr, StackedPyramid) or pyr.widths[0] != gray.shape[1] or pyr.heights[0] != gray.shape[0]:
        return None
    return pyr


def stereo_builder(config: SystemConfig, camera: PinholeCamera, spec: FeatureSpec,
                   right_extractor: Extractor | None, left_extractor: Extractor | None = None) -> StereoFrameBuilder:
    """The stereo builder of a run, or a ``ConfigError`` where the features cannot be matched
    across the pair (ORB-SLAM2's matcher compares binary descriptors by Hamming distance)."""
    if spec.kind is not DescriptorKind.BINARY or spec.dim % 8:
        raise ConfigError(f"sensor: stereo matches binary descriptors across the pair (ORB); features.extractor: "
                          f"{config.features.extractor} makes {spec.kind.value} ones; use an ORB extractor "
                          "(orb_slam2, qtree_orb, orb)")
    return StereoFrameBuilder(camera, config.slam.bf, spec, right_extractor, left_extractor)


def is_monocular(config: SystemConfig) -> bool:
    """Monocular geometry: a monocular camera without a depth network, or with one whose depth
    is only a prior (``depth.use: prior``)."""
    return config.sensor == "mono" and (config.depth.source == "sensor" or config.depth.use == "prior")


def frame_builder(config: SystemConfig, camera: PinholeCamera, spec: FeatureSpec | None = None,
                  right_extractor: Extractor | None = None, left_extractor: Extractor | None = None) -> FrameBuilder:
    """The builder for the frames ``config`` gives: stereo pairs (``spec``: the extractor's,
    ``right_extractor``: a second extractor for the right images, ``left_extractor``:
    tracking's), monocular, else RGB-D
    whenever they come with depth, the sensor's or a depth network's (a monocular camera as
    pseudo-RGB-D)."""
    if config.sensor == "stereo":
        if spec is None:
            raise ValueError("a stereo frame builder needs the extractor's FeatureSpec")
        return stereo_builder(config, camera, spec, right_extractor, left_extractor)
    if is_monocular(config):
        return MonocularFrameBuilder(camera)
    return RgbdFrameBuilder(camera, config.slam.bf)
