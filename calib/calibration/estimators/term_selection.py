"""The rule that picks the joint terms among scored candidates (issue 39, item 4):
:func:`pick_terms`, and what each candidate costs over the workspace (:func:`workspace_costs`).
:func:`calib.calibration.terms.choose_terms` scores the candidates (geometry, + compliance,
+ periodic, + both) by K-fold cross-validation on the same rows and folds.

* Compliance and periodic errors are alternatives, not steps of one ladder: the candidates are
  compared with each other by their cross-validated scores, the lowest wins, and it is kept only
  when it beats the geometry by more than ``TERMS_MIN_SE`` standard errors of their paired row
  by row difference. A candidate holding another's terms (+ both) must also beat that one by the
  margin. (Tried in order of size, compliance was kept in 2 of 20 simulated periodic-only truths
  where the periodic terms had the lower score, the error then 1.4-1.6 times larger.)
* The workspace weighs in: each candidate's predicted error over random configurations within
  the joint limits (its held-out error at the calibration configurations, plus what its
  parameters' uncertainty adds away from them). A candidate whose workspace figure rises above
  the geometry's by more than it gains at the calibration configurations is not chosen (the
  real iiwa's periodic terms: 1.8 mm over the workspace for 2.7 % at the measured
  configurations, compliance alone 0.49 mm); one that costs the workspace less than it gains
  may be chosen, and the reason says what it costs. The table shows every figure.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.calibration.accuracy.validation import standard_error
from calib.calibration.accuracy.workspace import propagate_covariance, workspace_configurations
from calib.model.robot import RobotModel
from calib.solvers.inverse import normal_inverse

#: A candidate is kept when it lowers the cross-validated score by more than this many standard
#: errors of the paired row-by-row difference (one-sided: a chance win of two standard errors
#: happens ~2 % of the time).
TERMS_MIN_SE = 2.0


@dataclass(frozen=True)
class TermScore:
    """One candidate of :func:`~calib.calibration.terms.choose_terms`: its label, term groups,
    number of free parameters, cross-validated held-out position RMS (m) and rotation RMS (rad,
    None for position data), mean whitened squared held-out error per row (``score``), the
    standard error of its paired difference from the geometric model's (``se_vs_geometry``),
    and its predicted held-out position RMS over random configurations within the joint limits
    (``workspace_rms``, m; None when not computed)."""

    label: str
    compliance: bool
    periodic: bool
    n_free: int
    position_rms: float
    rotation_rms: float | None
    score: float
    se_vs_geometry: float
    workspace_rms: float | None = None

    def holds(self, other: "TermScore") -> bool:
        """Whether this candidate has every term group of ``other`` and more."""
        return (self.compliance >= other.compliance and self.periodic >= other.periodic
                and (self.compliance, self.periodic) != (other.compliance, other.periodic))


def margin(row_scores: dict, better: TermScore, than: TermScore) -> float:
    """How far ``better``'s mean row score lies below ``than``'s beyond TERMS_MIN_SE standard
    errors of their paired difference (positive: it wins by the margin)."""
    d = row_scores[than.label] - row_scores[better.label]
    return float(np.mean(d) - TERMS_MIN_SE * standard_error(d))


def workspace_cost(t: TermScore, geo: TermScore) -> float:
    """How much ``t``'s workspace figure exceeds the geometry's (m; 0 when it does not, or
    either is unknown)."""
    if t.workspace_rms is None or geo.workspace_rms is None:
        return 0.0
    return max(t.workspace_rms - geo.workspace_rms, 0.0)


def too_costly(t: TermScore, geo: TermScore) -> bool:
    """Whether ``t``'s workspace figure rises above the geometry's by more than its held-out
    position error at the calibration configurations falls below it."""
    return workspace_cost(t, geo) > max(geo.position_rms - t.position_rms, 0.0)


def pick_terms(table, row_scores: dict) -> TermScore:
    """The rule (module docstring): ``table`` the candidates, the geometry first; ``row_scores``
    label -> (n,) their whitened squared held-out errors on the same rows. A candidate
    :func:`too_costly` over the workspace is left out."""
    geo = table[0]
    cands = [t for t in table[1:] if not too_costly(t, geo)]
    cands = [t for t in cands if all(margin(row_scores, t, u) > 0 for u in cands if t.holds(u))]
    if not cands:
        return geo
    best = min(cands, key=lambda t: t.score)
    return best if margin(row_scores, best, geo) > 0 else geo


def comparisons(table, row_scores: dict):
    """Every comparison the rule makes: (candidate, margin) against the geometry, and against
    each candidate it holds the terms of."""
    geo = table[0]
    for t in table[1:]:
        yield t, margin(row_scores, t, geo)
        for u in table[1:]:
            if t.holds(u):
                yield t, margin(row_scores, t, u)


def reason(table, row_scores: dict, best: TermScore) -> str:
    """Why the rule chose ``best`` (a sentence for the report)."""
    geo = table[0]
    winners = [t for t in table[1:] if margin(row_scores, t, geo) > 0]
    cost = "; ".join(f"{t.label} predicts {t.workspace_rms * 1e3:.3g} mm over the workspace against the "
                     f"geometry's {geo.workspace_rms * 1e3:.3g} mm"
                     + (", more than it gains at the calibration configurations: not chosen" if too_costly(t, geo)
                        else "") for t in winners if workspace_cost(t, geo) > 0)
    if best is geo:
        text = "no term group beat the geometry by the margin" + (" without costing the workspace" if cost else "")
    else:
        left = " left" if any(too_costly(t, geo) for t in winners) else ""
        text = (f"{best.label} had the lowest cross-validated score of the candidates{left} and beat the geometry "
                f"by more than {TERMS_MIN_SE:g} paired standard errors")
    return text + (f" ({cost})" if cost else "")


def workspace_costs(model: RobotModel, union: list, cols: dict, A: np.ndarray, values: dict, blocks,
                    sigma_pos: float, cv_rms: dict, calibration_q: np.ndarray) -> dict:
    """label -> the candidate's predicted held-out position RMS over random configurations
    within the joint limits (m): its cross-validated RMS at the calibration configurations
    ``cv_rms[label]``, plus the position error its parameters' covariance adds there over what
    it adds at the calibration configurations.

    model : the union's model (every candidate's terms; its structure and reference frames);
    union : the union's free parameter names; cols : label -> the candidate's columns of them;
    A : (m, m) the union's whitened normal equations at the geometric noise levels (a
    candidate's covariance is the inverse of its columns' block, SI units); values : label ->
    name -> value of the candidate's fit; blocks : the union's whitened (r, Jw) pose blocks at
    the calibration rows (position rows first, whitened by ``sigma_pos``, m)."""
    Q = workspace_configurations(model, calibration_q=calibration_q)
    out = {}
    for label, c in cols.items():
        if label not in values or label not in cv_rms:
            continue
        C = normal_inverse(A[np.ix_(c, c)])[0]
        at = model.values.copy()
        names = [union[k] for k in c]
        at[model.indices(list(values[label]))] = list(values[label].values())
        ws, _ = propagate_covariance(model.with_values(at), Q, names, C)
        tr, n = 0.0, 0
        for _, Jw in blocks:
            Jp = Jw[:, :3][:, :, c]
            tr += float(np.einsum("nkm,ml,nkl->", Jp, C, Jp))
            n += len(Jw)
        cal = math.sqrt(max(tr, 0.0) / max(n, 1)) * sigma_pos
        out[label] = math.sqrt(max(cv_rms[label] ** 2 + ws ** 2 - cal ** 2, 0.0))
    return out
