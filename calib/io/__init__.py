"""calib.io: see ARCHITECTURE.md."""
