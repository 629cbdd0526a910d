"""calib.cli.main: see ARCHITECTURE.md."""
