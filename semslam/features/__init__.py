"""Keypoint extractors and matchers, each registered by name."""
