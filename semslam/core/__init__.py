"""The core's vocabulary: read ``protocols.py`` first.

``types.py`` holds the values that cross component boundaries (frames, keypoints with their
``FeatureSpec``, tracking results, run results), ``protocols.py`` the contracts every backend
implements (tracker, extractor, matcher, segmenter, depth source, dynamic stage, map builder,
sequence source) and ``registry.py`` the one place where a backend's name is mapped to the
module that builds it. Nothing here imports a backend.
"""
