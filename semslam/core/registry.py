"""One registry for every plugin kind: ``name -> "module:factory"``, imported lazily.

As hloc finds its extractors by name, a backend here is one module with a factory function
plus one line below; nothing imports a backend until a run asks for it, so optional packages
(mediapipe, torch) are needed only by the runs that use them and no import circle can form.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from semslam.errors import ConfigError

#: kind -> backend name -> "module:factory". The config key that selects each kind is in KEYS.
#: Segmenter factories take the SemanticsConfig, depth sources the DepthConfig (``weights`` resolved).
PLUGINS: dict[str, dict[str, str]] = {
    "tracker": {
        "frame_to_keyframe": "semslam.slam.trackers.frame_to_keyframe:create_tracker",
        "orb_slam": "semslam.slam.orb.tracker:create_tracker",
        "sdf_slam": "semslam.slam.trackers.sdf_slam:create_tracker",
    },
    "extractor": {
        "orb_opencv": "semslam.features.orb_opencv:create_extractor",
        "orb_slam2": "semslam.features.orb_slam2:create_extractor",
        "qtree_orb": "semslam.features.qtree_orb:create_extractor",
        "sift": "semslam.features.sift:create_extractor",
        "fpfdcnn": "semslam.features.fpfdcnn:create_extractor",
        "xfeat": "semslam.features.xfeat:create_extractor",
    },
    "matcher": {
        "binary": "semslam.features.matching:HammingMatcher",
        "float": "semslam.features.matching:L2Matcher",
        "range": "semslam.features.range_matcher:RangeMatcher",
    },
    "segmenter": {
        "mediapipe_person": "semslam.semantics.mediapipe_person:create_general",
        "mediapipe_person_fast": "semslam.semantics.mediapipe_person:create_fast",
        "ground_truth": "semslam.semantics.ground_truth:create_segmenter",
        "stdc": "semslam.semantics.nets_backend:create_stdc",
        "dunet": "semslam.semantics.nets_backend:create_dunet",
        "sdfcnn": "semslam.semantics.sdfcnn_backend:create_segmenter",
    },
    "depth_source": {
        "sensor": "semslam.io.depth:create_sensor",
        "sdfcnn": "semslam.semantics.sdfcnn_backend:create_depth",
        "ground_truth_depth": "semslam.io.standin_depth:create_ground_truth",
        "constant_depth": "semslam.io.standin_depth:create_constant",
        "scaled_depth": "semslam.io.standin_depth:create_scaled",
        "shuffled_depth": "semslam.io.standin_depth:create_shuffled",
    },
    "map_builder": {
        "keyframe_cloud": "semslam.reconstruction.keyframe_cloud:KeyframeCloud",
        "octree": "semslam.reconstruction.octree:SemanticOctree",
        "cloud": "semslam.reconstruction.semantic_cloud:SemanticCloud",
        "mesh": "semslam.reconstruction.tsdf_mesh:TsdfMesh",
    },
    # What io/sequence.py's open_sequence opens besides TUM and image folders (they build on it).
    "sequence_source": {"rosbag": "semslam.io.rosbag_stereo:open_rosbag",
                        "stereo": "semslam.io.stereo_sequence:open_stereo_sequence",
                        "euroc": "semslam.io.euroc_sequence:open_euroc"},
}

#: The config field that names each kind's backend (for error messages).
KEYS = {"tracker": "tracking.method", "extractor": "features.extractor", "matcher": "descriptor kind",
        "segmenter": "semantics.backend", "depth_source": "depth.source", "map_builder": "maps.builders",
        "sequence_source": "sequence file type"}

#: Old names still accepted in presets and --set (renamed to say what they are).
ALIASES: dict[str, dict[str, str]] = {"extractor": {"orb_slam": "orb_slam2"}}


def names(kind: str) -> list[str]:
    """Registered backend names of one kind."""
    return sorted(PLUGINS[kind])


def resolve(kind: str, name: str) -> str:
    """The canonical backend name (aliases followed); ConfigError naming the choices if unknown."""
    name = ALIASES.get(kind, {}).get(name, name)
    if name not in PLUGINS[kind]:
        raise ConfigError(f"{KEYS[kind]}: unknown {kind} {name!r} (known: {', '.join(names(kind))})")
    return name


def load(kind: str, name: str) -> Callable[..., Any]:
    """Import and return the factory registered as ``name`` for ``kind``."""
    target = PLUGINS[kind][resolve(kind, name)]
    module_name, _, attr = target.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, attr)


def create(kind: str, name: str, *args: Any, **kwargs: Any) -> Any:
    """Build the backend ``name`` of ``kind`` with its factory's arguments."""
    return load(kind, name)(*args, **kwargs)
