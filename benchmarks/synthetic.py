#!/usr/bin/env python
"""Benchmark on the synthetic sequences: the same as ``semslam bench`` (see semslam/bench.py)."""

import sys

import semslam.runtime  # noqa: F401  (thread limits, before numpy loads)
from semslam.bench import main

if __name__ == "__main__":
    sys.exit(main())
