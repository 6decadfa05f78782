"""Pose priors: what predicts or corrects a frame's pose besides its features (``base.py``)."""
