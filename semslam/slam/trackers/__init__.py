"""The other trackers behind the same ``Tracker`` contract: frame-to-keyframe PnP (the
foundation tracker) and monocular SDF-SLAM."""
