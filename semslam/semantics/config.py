"""Settings of the semantic thread (the ``semantics:`` section of the system config).

Kept in its own module so the system config can hang it in without importing any
segmentation backend (and so without pulling optional packages).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from semslam.errors import ConfigError
from semslam.semantics.labels import DDL_SLAM_DYNAMIC_CLASSES


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

    def check(self) -> None:
        """Raise ConfigError on values no backend can use (the config loader checks types only)."""
        if not self.backend:
            raise ConfigError("semantics.backend: empty backend name")
        if not isinstance(self.dynamic_classes, list) or not all(isinstance(c, str) for c in self.dynamic_classes):
            raise ConfigError(
                f"semantics.dynamic_classes: expected a list of class names, got {self.dynamic_classes!r}"
            )
        if not 0.0 <= self.threshold < 1.0:
            raise ConfigError(f"semantics.threshold: expected a value in [0, 1), got {self.threshold}")
        if self.srm_window < 1 or self.srm_window % 2 == 0:
            raise ConfigError(f"semantics.srm_window: expected an odd window size >= 1, got {self.srm_window}")
        if not self.srm_tau_m > 0.0:
            raise ConfigError(f"semantics.srm_tau_m: expected a positive depth step in metres, got {self.srm_tau_m}")
        if self.input_width < 0:
            raise ConfigError(f"semantics.input_width: expected 0 (native) or a width in px, got {self.input_width}")
