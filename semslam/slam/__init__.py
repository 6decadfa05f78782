"""Stateful SLAM objects: frames, keyframes, tracking and the System that runs them."""
