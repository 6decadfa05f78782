"""Trajectory evaluation: association, ATE/RPE metrics (matching evo) and HTML reports."""

from semslam.io.association import associate, match_timestamps
from semslam.eval.metrics import AteResult, RpeResult, ate, error_stats, rpe

__all__ = [
    "AteResult",
    "RpeResult",
    "associate",
    "ate",
    "error_stats",
    "match_timestamps",
    "rpe",
]
