"""calib.model: see ARCHITECTURE.md."""
