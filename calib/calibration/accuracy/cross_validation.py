"""The results of a cross-validation (:class:`CrossValidation`, made by
:mod:`calib.calibration.accuracy.validation`) and of a model selection among candidate parameter sets
(:class:`Candidate`, :class:`ModelSelection`, made by
:mod:`calib.calibration.estimators.selection`)."""
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


@dataclass(frozen=True)
class Candidate:
    """One candidate parameter set of the model selection and its cross-validated error."""

    label: str
    free: tuple[str, ...]
    cv: CrossValidation


@dataclass(frozen=True)
class ModelSelection:
    """``params="auto"``: the candidates (smallest first), the chosen one, the one of lowest
    cross-validated score (``best``) and the selection rule's name (by default
    :func:`lowest_score`: ``chosen`` is ``best``)."""

    candidates: tuple[Candidate, ...]
    chosen: str
    best: str
    rule: str = "lowest score"

    def to_dict(self) -> dict:
        return {"chosen": self.chosen, "best": self.best, "rule": self.rule,
                "candidates": [{"label": c.label, "n_free": len(c.free), "score": c.cv.score,
                                "score_se": c.cv.score_se, "position_rms_mm": c.cv.position_rms * 1e3,
                                "rotation_rms_rad": c.cv.rotation_rms} for c in self.candidates]}

    def format(self) -> str:
        lines = [f"model selection ({self.candidates[0].cv.folds}-fold cross-validation, rule: {self.rule}; "
                 f"score: mean noise-weighted squared held-out error per row):",
                 f"  {'candidate':<26}{'params':>7}{'score':>10}{'+-se':>9}{'pos rms/mm':>12}{'rot rms/rad':>13}"]
        for c in self.candidates:
            rot = "-" if c.cv.rotation_rms is None else f"{c.cv.rotation_rms:.3e}"
            mark = "  <- chosen" if c.label == self.chosen else ("  (lowest)" if c.label == self.best else "")
            lines.append(f"  {c.label:<26}{len(c.free):>7}{c.cv.score:>10.3f}{c.cv.score_se:>9.3f}"
                         f"{c.cv.position_rms * 1e3:>12.4f}{rot:>13}{mark}")
        return "\n".join(lines)
