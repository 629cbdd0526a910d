"""How accurate a calibration is: its errors before and after (errors.py), its statistics
(covariance, predictions: statistics.py), over the workspace (workspace.py), held out
(cross-validation: validation.py; its results: cross_validation.py)."""
