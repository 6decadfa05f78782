"""The IMU's motion between consecutive keyframes, for local BA (ORB-SLAM3's inertial edges
between keyframes, with velocities and biases held at tracking's estimates).

Tracking composes each frame's predicted motion from the last frame (the IMU's prediction
relative to the pose it started from: readings, gravity, velocity and biases only, not the
last frame's error) into a chain since the last keyframe; a new keyframe takes the chain as
its ``InertialLink`` to that keyframe. The chain breaks where a frame had no such prediction
(no IMU state yet, lost, another map), and the keyframe then gets no link. Spreads add up
linearly, as a velocity's error moves every frame of the chain the same way.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem
from semslam.slam.orb.map import InertialLink, KeyFrame

Array = NDArray[np.float64]

#: Spreads a link never goes under (radians, metres): the chain's model is first order.
MIN_SIGMA_ROTATION = 1e-4
MIN_SIGMA_TRANSLATION = 1e-4


class MotionChain:
    """The predicted motion since the last keyframe (see the module docstring)."""

    def __init__(self) -> None:
        self.keyframe: KeyFrame | None = None
        self.T = np.eye(4)
        self.sigma_rotation = 0.0
        self.sigma_translation = 0.0
        self.n_links = 0  # keyframes linked so far

    def frame(self, motion: Array | None, covariance: Array | None) -> None:
        """A tracked frame's predicted motion from the last frame (``T_cw(this) = motion @
        T_cw(last)``) and its 6x6 covariance; None breaks the chain."""
        if motion is None or covariance is None or self.keyframe is None:
            self.keyframe = None
            return
        self.T = motion @ self.T
        self.sigma_rotation += float(np.sqrt(np.max(np.diag(covariance)[:3])))
        self.sigma_translation += float(np.sqrt(np.max(np.diag(covariance)[3:])))

    def lost(self) -> None:
        self.keyframe = None

    def new_keyframe(self, kf: KeyFrame) -> None:
        """Link ``kf`` to the chain's keyframe when the chain is whole, then start anew from it."""
        prev = self.keyframe
        if prev is not None and prev.map_id == kf.map_id:
            kf.inertial_link = InertialLink(prev, self.T.copy(), max(self.sigma_rotation, MIN_SIGMA_ROTATION),
                                            max(self.sigma_translation, MIN_SIGMA_TRANSLATION))
            self.n_links += 1
        self.keyframe = kf
        self.T = np.eye(4)
        self.sigma_rotation = self.sigma_translation = 0.0


def link_to(kf: KeyFrame, present: dict[KeyFrame, int]) -> tuple[int, InertialLink] | None:
    """``kf``'s link to the nearest earlier keyframe in ``present`` (keyframe -> pose index),
    composed over culled keyframes in between; None when there is none."""
    link = kf.inertial_link
    T, sr, st = np.eye(4), 0.0, 0.0
    while link is not None:
        T, sr, st = T @ link.T, sr + link.sigma_rotation, st + link.sigma_translation
        prev = link.previous
        if prev in present and not prev.bad:
            return present[prev], InertialLink(prev, T, sr, st)
        if not prev.bad:
            return None  # a live keyframe outside the problem: the link ends there
        link = prev.inertial_link
    return None


def add_links(problem: BAProblem, kfs: list[KeyFrame]) -> None:
    """The links between the problem's keyframes (``problem.poses_cw`` rows follow ``kfs``)
    into ``problem``, those with at least one free end."""
    present = {kf: i for i, kf in enumerate(kfs)}
    rows: list[tuple[int, int]] = []
    Ts: list[Array] = []
    infos: list[Array] = []
    for b, kf in enumerate(kfs):
        found = link_to(kf, present)
        if found is None:
            continue
        a, link = found
        if problem.pose_fixed[a] and problem.pose_fixed[b]:
            continue
        rows.append((a, b))
        Ts.append(link.T)
        infos.append(link.information())
    if rows:
        problem.link_pose = np.array(rows, np.intp)
        problem.link_T = np.stack(Ts)
        problem.link_info = np.stack(infos)
