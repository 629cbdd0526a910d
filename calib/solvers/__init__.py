"""calib.solvers.problem: see ARCHITECTURE.md."""
