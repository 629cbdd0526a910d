"""The result of a cross-validation (:class:`CrossValidation`, made by
:mod:`calib.calibration.validation`), in a module of its own: loaded when a calibration
cross-validates, not by every one (a dataclass costs ~3M instructions to build at import)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np



@dataclass(frozen=True, eq=False)     # (an array field: compared by identity; nothing compares them)
class CrossValidation:
    """K-fold cross-validated held-out error of a fit: each fold's rows predicted by the model
    fitted on the other folds. position_rms (m) and rotation_rms (rad, None position only) pooled
    over every held-out row; per_fold : per fold (rows, position_rms, rotation_rms);
    row_scores : (n,) whitened squared held-out error of each kept row (position and rotation,
    weighted by the fit's noise levels; rows in the order of the calibration rows);
    score / score_se : their mean and its standard error."""

    folds: int
    position_rms: float
    rotation_rms: float | None
    per_fold: tuple[tuple[int, float, float | None], ...]
    score: float
    score_se: float
    row_scores: np.ndarray = field(repr=False, default=None)
    #: a fit of residual blocks (touch data): each group's held-out RMS per component (m, rad)
    groups: dict | None = None

    def to_dict(self) -> dict:
        out = {"folds": self.folds, "position_rms_mm": self.position_rms * 1e3,
               "rotation_rms_rad": self.rotation_rms,
               "per_fold": [{"rows": n, "position_rms_mm": p * 1e3, "rotation_rms_rad": r}
                            for n, p, r in self.per_fold]}
        if self.groups is not None:
            out["groups"] = {g: v * (1.0 if g == "rotation" else 1e3) for g, v in self.groups.items()}
        return out
