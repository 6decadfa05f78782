"""Map builders fed by keyframe snapshots (``core.protocols.MapBuilder``), apart from the
SLAM core's own sparse map in ``slam/``: dense and semantic maps a person or a robot uses."""
