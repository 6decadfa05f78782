#!/usr/bin/env python
"""Benchmark on the synthetic sequences: the same as ``semslam bench`` (same options)."""

import sys

from semslam.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
