"""semslam: semantic visual SLAM for scenes that are not static."""

__version__ = "0.1.0"
