"""The machine-speed probe the real-time benchmark records: both probes run and measure
something (what the numbers are is the machine's business, not a test's)."""

from __future__ import annotations

from semslam.experiments.speed_probe import _probe_image, speed_probe


def test_probe_image_is_fixed_and_has_corners_for_the_extractor():
    a, b = _probe_image(), _probe_image()
    assert a.shape == (480, 640) and (a == b).all() and a.std() > 30


def test_speed_probe_reports_both_numbers():
    p = speed_probe(repeats=1)
    assert set(p) == {"python_loop_1e7_s", "orb_extract_ms"}
    assert p["python_loop_1e7_s"] > 0 and p["orb_extract_ms"] > 0
