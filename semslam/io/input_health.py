"""What was wrong with the frames a run was given, counted for ``stats.json``.

A covered lens, a blank or featureless image, a depth image without measurements or a
person filling the view does not stop a run: tracking loses (or never starts on) such
frames and goes on. The lost and uninitialised counts say that frames had no pose, not
why; these counters say why, and the first frame of each kind is logged as a warning, so
a user knows at once that the input, not the tracker, is the problem.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2

from semslam.core.types import Frame, TrackResult

log = logging.getLogger(__name__)

#: Fewer keypoints than this leave nothing to track with: no pose can be estimated from
#: them (pose-only optimisation, PnP, relocalisation all need dozens of matches).
FEW_KEYPOINTS = 20
#: Standard deviation of the grey levels (0-255) below which an image is blank: a covered
#: lens, a black or white frame (sensor noise alone). Learned detectors find "keypoints" even
#: there, so the count above does not tell it for every extractor.
BLANK_STD = 2.0
#: Share of pixels with a depth measurement below which an RGB-D frame counts as without depth.
MIN_DEPTH_SHARE = 0.01
#: Share of the image the dynamic mask covers from which a frame counts as all dynamic
#: (what is left is the mask's ragged edge, not a static scene to track on) ...
MOSTLY_DYNAMIC = 0.9
#: ... or from which a frame with too few keypoints is blamed on the mask, not the image.
HALF_DYNAMIC = 0.5

#: counter -> what the warning says about such a frame.
_WHY = {
    "frames_all_dynamic": "the dynamic mask covers {dyn:.0%} of the image (a person or mover fills the view): "
                          "no static keypoints to track with",
    "frames_featureless": "{kps} keypoints, grey levels spread {std:.1f}: the image is blank (covered lens, "
                          "black, white) or featureless",
    "frames_without_depth": "{depth:.1%} of the pixels have a depth (0, NaN, inf and 65535 are no measurement)",
}


@dataclass
class InputHealth:
    """Counts frames that were all dynamic, featureless or without depth (``observe`` after
    each tracked frame); ``stats()`` goes into ``stats.json``."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_WHY, 0))

    def observe(self, frame: Frame, result: TrackResult) -> None:
        dynamic = result.dynamic
        dyn = float(dynamic.mean()) if dynamic is not None and dynamic.size else result.dynamic_ratio
        # On the tracking thread, so cheap: OpenCV's std over the grey image (0.01 ms at
        # 640x480), depth sampled at every 4th pixel of every 4th row.
        depth = float((frame.depth[::4, ::4] > 0).mean()) if frame.depth is not None and frame.depth.size else None
        std = float(cv2.meanStdDev(frame.gray)[1][0, 0])
        found = []
        if std < BLANK_STD:
            found.append("frames_featureless")
        elif result.n_keypoints < FEW_KEYPOINTS:
            found.append("frames_all_dynamic" if dyn >= HALF_DYNAMIC else "frames_featureless")
        elif dyn >= MOSTLY_DYNAMIC:
            found.append("frames_all_dynamic")
        if depth is not None and depth < MIN_DEPTH_SHARE:
            found.append("frames_without_depth")
        for key in found:
            if not self.counts[key]:
                where = frame.depth_path if key == "frames_without_depth" else frame.rgb_path
                log.warning("frame %d%s: %s; the run goes on, such frames are counted in stats.json (%s)",
                            frame.index, f" ({where})" if where is not None else "",
                            _WHY[key].format(dyn=dyn, kps=result.n_keypoints, std=std, depth=depth or 0.0), key)
            self.counts[key] += 1

    def stats(self) -> dict[str, int]:
        return dict(self.counts)
