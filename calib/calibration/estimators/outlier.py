"""A calibration row left out of the fit (:class:`Outlier`), in a module of its own: loaded when
the outlier check flags rows (:func:`calib.calibration.estimators.robust.flag_outliers`), not on every
calibration (a dataclass costs ~3-5M instructions to build at import)."""
from __future__ import annotations

from dataclasses import dataclass



@dataclass(frozen=True)
class Outlier:
    """A calibration row left out of the fit: its line in the file, its errors after the fit
    (metres, radians; rotation NaN for position-only data) and its residual RMS in sigma."""

    row: int
    position_error: float
    rotation_error: float
    sigmas: float
