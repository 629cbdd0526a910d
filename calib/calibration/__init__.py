"""calib.calibration: the calibration stages and the pipeline (see ARCHITECTURE.md)."""
