"""Process-wide settings for running SLAM on a few cores.

SLAM runs its own threads (tracking, local mapping, loop closing) and a BA worker
process; BLAS and OpenCV worker pools on top of them only compete for the cores
(measured on 2 cores: 36 -> 28 ms/frame median on room_loop). Import this module before
numpy for the BLAS settings to take effect; the environment overrides the defaults.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def limit_opencv_threads() -> None:
    """One OpenCV thread unless SEMSLAM_OPENCV_THREADS says otherwise."""
    import cv2

    cv2.setNumThreads(int(os.environ.get("SEMSLAM_OPENCV_THREADS", "1")))
