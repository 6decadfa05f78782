"""Synthetic TUM RGB-D sequences with exact ground truth (``semslam synth``).

Real TUM sequences cannot be downloaded everywhere, so tests, the demo and benchmarks run
on sequences rendered here: a textured office, TUM-like camera motions, people walking
through the view (cut out of real TUM photos when available) and an optional unlabelled
moving object, with Kinect-like depth and per-pixel class labels.
"""

from semslam.synth.render import Frame, Renderer, ensure_rendered, needs_render, render_sequence
from semslam.synth.sequences import MOTIONS, SEQUENCES, SynthConfig, get_sequence

__all__ = [
    "MOTIONS",
    "SEQUENCES",
    "Frame",
    "Renderer",
    "SynthConfig",
    "get_sequence",
    "ensure_rendered",
    "needs_render",
    "render_sequence",
]
