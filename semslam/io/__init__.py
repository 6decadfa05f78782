"""Everything that touches files: sequence readers, calibration, trajectory files."""
