"""Sharpness of the last tracked frames, shared by the priors that tell blurred frames from
sharp ones (``frontend/sharpness.py``)."""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import NDArray

from semslam.frontend.sharpness import sharpness

#: Tracked frames whose sharpness a frame is compared with.
RECENT_FRAMES = 10


class SharpnessHistory:
    """This frame's sharpness (measured once) against the sharpest of the last tracked ones."""

    def __init__(self) -> None:
        self._recent: deque[float] = deque(maxlen=RECENT_FRAMES)
        self._current: float | None = None
        self._counts = True

    def begin(self, measured: float | None) -> None:
        """A new frame; ``measured``: its sharpness if the reader measured it ahead."""
        self._current = measured
        self._counts = True

    def of(self, gray: NDArray[np.uint8]) -> float:
        """This frame's sharpness, measured here when the reader did not."""
        if self._current is None:
            self._current = sharpness(gray)
        return self._current

    def is_sharp(self, gray: NDArray[np.uint8], ratio: float) -> bool:
        """At least ``ratio`` times the sharpest of the last tracked frames (True before any)."""
        recent = self._recent
        return not recent or self.of(gray) >= ratio * max(recent)

    def exclude(self) -> None:
        """This frame is not a reference for the next (it was posed without its features)."""
        self._counts = False

    def end(self, tracked: bool) -> None:
        """The frame is done: a tracked one that counts joins the history."""
        if tracked and self._current is not None and self._counts:
            self._recent.append(self._current)
        self._current = None
