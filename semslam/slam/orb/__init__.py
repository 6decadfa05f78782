"""The ORB-SLAM2/3-style core: tracking with its pose priors and frame builders, local mapping,
loop closing, the map and its files, the atlas of maps and their merging, and the tracker
that wires them (``tracker.OrbTracker``)."""
