"""The public API: every name in calib.__all__ resolves."""
import calib


def test_all_names_resolve():
    missing = [n for n in calib.__all__ if not hasattr(calib, n)]
    assert missing == []
    assert {"load_robot", "read_measurements", "calibrate", "evaluate"} <= set(calib.__all__)
