"""The choice among candidate parameter sets (``params="auto"``): each candidate's
cross-validated error (:mod:`calib.calibration.validation`), the selection rules
(:func:`lowest_score`, :func:`one_standard_error`), :class:`ModelSelection`,
:func:`select_model` and :func:`select_and_fit` (what :func:`calib.calibrate` runs for "auto").
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from calib.calibration.accuracy import target_rows
from calib.calibration.estimators.least_squares import Fit, Solver, fit_stage, fit_with, solver_for
from calib.calibration.options import LOO_BELOW_ROWS, CalibrationOptions
from calib.calibration.parameters import candidate_sets
from calib.calibration.prepare import Setup
from calib.calibration.cross_validation import CrossValidation
from calib.calibration.validation import _standard_error, cross_validate
from calib.errors import DataError
from calib.model.kinematics import ChainKinematics
from calib.solvers.lm import LMOptions
from calib.solvers.problem import Problem

log = logging.getLogger(__name__)


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


def lowest_score(candidates: Sequence[Candidate]) -> Candidate:
    """The candidate of lowest mean held-out score (the first, i.e. the smallest, of equal ones),
    the default rule: on fresh configurations :func:`one_standard_error` did no better
    (scripts/bench_selection.py, 1,440 simulated cases of 15-40 rows: where the rules disagree,
    each choice was the worse one about half the time; mean errors within 0.6 %)."""
    return min(candidates, key=lambda c: c.cv.score)


def one_standard_error(candidates: Sequence[Candidate]) -> Candidate:
    """The one-standard-error rule: the first (smallest) of the nested ``candidates`` whose mean
    held-out score exceeds the best one's by at most one standard error of their paired difference
    (the candidates are scored on the same rows and folds, so their row scores are strongly
    correlated and the difference is what is uncertain)."""
    best = min(candidates, key=lambda c: c.cv.score)
    return next(c for c in candidates
                if np.mean(c.cv.row_scores - best.cv.row_scores) <= _standard_error(c.cv.row_scores - best.cv.row_scores))


#: The printed names of the selection rules of this module (a rule passed in without one is
#: named by its function's name).
RULE_NAMES = {lowest_score: "lowest score", one_standard_error: "one standard error"}


def _rule_name(rule) -> str:
    return RULE_NAMES.get(rule, getattr(rule, "__name__", "custom"))


def select_model(setup: Setup, candidates: Sequence[tuple[str, tuple[str, ...]]], full: Fit,
                 full_problem: Problem, solve: Solver, folds: int, kin: ChainKinematics,
                 options: LMOptions, *, rule: Callable[[Sequence[Candidate]], Candidate] = lowest_score,
                 ) -> tuple[ModelSelection, dict[str, tuple[Fit, Problem]]]:
    """Cross-validate each candidate set (label, names), smallest first, at the noise levels and
    kept rows of ``full`` (the fit of the largest set) and choose by ``rule`` (a function of the
    scored candidates returning one of them; default :func:`lowest_score`, as scikit-learn's
    ``GridSearchCV(refit=callable)``). Returns the selection and the candidates' fits."""
    sp, sr = full_problem.sigma_pos, full_problem.sigma_rot
    fits, cands = {}, []
    for label, free in candidates:
        if tuple(free) == full.free:
            fit, problem = full, full_problem
        else:
            s = solver_for(setup, free, solve.method, options, solve.max_rounds, solve.fixed_rounds,
                            solve.lm_variant)
            fit, problem = fit_stage(setup, free, s, sigma_pos=sp, sigma_rot=sr, outlier_k=None,
                                     keep=full.keep, kin=kin)
        fits[label] = (fit, problem)
        try:
            cands.append(Candidate(label, tuple(free), cross_validate(setup, fit, problem, folds, options=options)))
        except DataError:
            continue            # too few rows to hold any out for this set: not a candidate
    if not cands:
        raise DataError(f"{setup.cal.n_poses} calibration rows are too few to compare parameter sets by "
                        f"cross-validation (no candidate can be identified with a row held out): "
                        f"measure more rows, or name the parameter set (params / --params)")
    best = min(cands, key=lambda c: c.cv.score)
    chosen = rule(tuple(cands))
    return ModelSelection(tuple(cands), chosen.label, best.label, _rule_name(rule)), fits


def auto_candidates(setup: Setup, ident: Sequence[str], full: Fit,
                    options: CalibrationOptions) -> list[tuple[str, tuple[str, ...]]]:
    """The nested :func:`candidate_sets` of ``params="auto"``, each its own maximal identifiable
    subset on the rows ``full`` (the fit of the identifiable set ``ident``) kept, weighted by the
    options' noise levels as the identifiable set was."""
    keep = full.keep
    rows = target_rows(setup.start, setup.cal)
    return candidate_sets(setup.start, ident, setup.cal.q[keep], setup.measure, *options.weights,
                          None if rows is None else rows[keep])


def fit_identifiable(setup: Setup, ident: Sequence[str], options: CalibrationOptions,
                     kin: ChainKinematics) -> tuple[Fit, Problem, Solver]:
    """The fit of the identifiable set ``ident`` that model selection starts from (noise
    estimate, outlier check), its problem and its solver."""
    solve = solver_for(setup, ident, options.method, options.lm, options.max_rounds, options.fixed_rounds,
                       options.lm_variant)
    full, problem = fit_stage(setup, ident, solve, sigma_pos=options.sigma_pos, sigma_rot=options.sigma_rot,
                              loss=options.loss, loss_scale=options.loss_scale, outlier_k=options.outlier_k,
                              kin=kin)
    return full, problem, solve


def selection_folds(full: Fit, options: CalibrationOptions) -> int:
    """The folds of model selection: leave-one-out on small sets (far less noisy than K folds at
    a few ms per refit), else the options' folds."""
    n = int(full.keep.sum())
    return n if n <= LOO_BELOW_ROWS else options.folds


def select_and_fit(setup: Setup, ident: Sequence[str], options: CalibrationOptions, kin: ChainKinematics, *,
                   rule: Callable[[Sequence[Candidate]], Candidate] = lowest_score,
                   ) -> tuple[ModelSelection, Fit, Problem]:
    """Model selection ("auto"): the fit of the identifiable set ``ident``
    (:func:`fit_identifiable`), :func:`select_model` among the nested :func:`auto_candidates` at
    its noise levels and kept rows, and the fit of the chosen set (the full fit when it is the
    largest)."""
    full, full_problem, full_solve = fit_identifiable(setup, ident, options, kin)
    selection, _ = select_model(setup, auto_candidates(setup, ident, full, options), full, full_problem,
                                full_solve, selection_folds(full, options), kin, options.lm, rule=rule)
    free = next(c.free for c in selection.candidates if c.label == selection.chosen)
    if free == full.free:
        fit, problem = full, full_problem
    else:
        fit, problem = fit_with(setup, free, options, outlier_k=None, keep=full.keep, kin=kin)
        fit = replace(fit, outliers=full.outliers, notes=full.notes + fit.notes, unremoved=full.unremoved,
                      refusals=full.refusals)
    log.info("model selection: %s", selection.chosen)
    return selection, fit, problem
