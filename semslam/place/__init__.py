"""Place recognition for loop closing and relocalisation (DBoW2-style, no download).

A vocabulary tree trained by the project and shipped in ``semslam/data`` turns ORB
descriptors into bags of words; :class:`KeyframeDatabase` finds keyframes that look
alike, and the two ORB-SLAM2 candidate selections pick loop / relocalisation candidates.
"""

from semslam.place.database import (
    KeyframeDatabase,
    SharedWords,
    detect_loop_candidates,
    detect_relocalisation_candidates,
)
from semslam.place.vocabulary import (
    BowVector,
    FeatureVector,
    Vocabulary,
    hamming,
    l1_score,
    load_default_vocabulary,
)

__all__ = [
    "BowVector",
    "FeatureVector",
    "KeyframeDatabase",
    "SharedWords",
    "Vocabulary",
    "detect_loop_candidates",
    "detect_relocalisation_candidates",
    "hamming",
    "l1_score",
    "load_default_vocabulary",
]
