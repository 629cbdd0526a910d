"""calib.calibration.core: see ARCHITECTURE.md."""
