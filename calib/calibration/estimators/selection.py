"""The choice among candidate parameter sets (``params="auto"``): each candidate's
cross-validated error (:mod:`calib.calibration.accuracy.validation`), the selection rules
(:func:`lowest_score`, :func:`one_standard_error`), :class:`ModelSelection`,
:func:`select_model` and :func:`select_and_fit` (what :func:`calib.calibrate` runs for "auto").
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from calib.calibration.accuracy.errors import target_rows
from calib.calibration.estimators.base import Estimate, Estimator, Fit
from calib.calibration.estimators.least_squares import LeastSquares
from calib.calibration.options import LOO_BELOW_ROWS, CalibrationOptions
from calib.calibration.parameters import ParameterChoice, candidate_sets
from calib.calibration.prepare import Setup
from calib.calibration.accuracy.cross_validation import Candidate, CrossValidation, ModelSelection
from calib.calibration.accuracy.validation import standard_error, cross_validate
from calib.errors import DataError
from calib.model.kinematics import ChainKinematics
from calib.solvers.lm import LMOptions
from calib.solvers.problem import Problem

log = logging.getLogger(__name__)


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
                if np.mean(c.cv.row_scores - best.cv.row_scores) <= standard_error(c.cv.row_scores - best.cv.row_scores))


#: The printed names of the selection rules of this module (a rule passed in without one is
#: named by its function's name).
RULE_NAMES = {lowest_score: "lowest score", one_standard_error: "one standard error"}


def _rule_name(rule) -> str:
    return RULE_NAMES.get(rule, getattr(rule, "__name__", "custom"))


def select_model(setup: Setup, candidates: Sequence[tuple[str, tuple[str, ...]]], full: Fit,
                 full_problem: Problem, refit: Callable[[tuple[str, ...]], tuple[Fit, Problem]], folds: int,
                 options: LMOptions, *, rule: Callable[[Sequence[Candidate]], Candidate] = lowest_score,
                 ) -> tuple[ModelSelection, dict[str, tuple[Fit, Problem]]]:
    """Cross-validate each candidate set (label, names), smallest first, fitted by ``refit(free)``
    (the wrapped estimator at the noise levels and kept rows of ``full``, the fit of the largest
    set), and choose by ``rule`` (a function of the scored candidates returning one of them;
    default :func:`lowest_score`, as scikit-learn's ``GridSearchCV(refit=callable)``). Returns the
    selection and the candidates' fits."""
    fits, cands = {}, []
    for label, free in candidates:
        fit, problem = (full, full_problem) if tuple(free) == full.free else refit(tuple(free))
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


def selection_folds(full: Fit, options: CalibrationOptions) -> int:
    """The folds of model selection: leave-one-out on small sets (far less noisy than K folds at
    a few ms per refit), else the options' folds."""
    n = int(full.keep.sum())
    return n if n <= LOO_BELOW_ROWS else options.folds


@dataclass(frozen=True, eq=False)
class SelectBest:
    """Model selection (``params="auto"``) wrapping an estimator, as scikit-learn's
    ``GridSearchCV`` wraps one: the estimator's fit of the identifiable set (its noise levels and
    outlier check), each nested candidate set (:func:`auto_candidates`) refitted by the estimator
    at those levels and kept rows and cross-validated (:func:`select_model`), the one ``rule``
    chooses, fitted again at the options' noise levels (the full fit when it is the largest).

    estimator : any estimator with ``fit`` and ``refit(setup, free, options, kin, *, keep,
    levels)`` (:class:`~calib.calibration.estimators.least_squares.LeastSquares`)."""

    estimator: Estimator = field(default_factory=LeastSquares)
    rule: Callable[[Sequence[Candidate]], Candidate] = lowest_score
    name: str = "select"

    def fit(self, setup: Setup, choice: ParameterChoice, options: CalibrationOptions,
            kin: ChainKinematics) -> Estimate:
        inner = self.estimator
        full = inner.fit(setup, choice, options, kin)
        levels = (full.problem.sigma_pos, full.problem.sigma_rot)

        def refit(free):
            return inner.refit(setup, free, options, kin, keep=full.fit.keep, levels=levels)

        selection, _ = select_model(setup, auto_candidates(setup, choice.free, full.fit, options), full.fit,
                                    full.problem, refit, selection_folds(full.fit, options), options.lm,
                                    rule=self.rule)
        free = next(c.free for c in selection.candidates if c.label == selection.chosen)
        fit, problem = full.fit, full.problem
        if free != full.fit.free:
            fit, problem = inner.refit(setup, free, options, kin, keep=full.fit.keep)
            fit = replace(fit, outliers=full.fit.outliers, notes=full.fit.notes + fit.notes,
                          unremoved=full.fit.unremoved, refusals=full.fit.refusals)
        log.info("model selection: %s", selection.chosen)
        label = f"auto: {selection.chosen}"
        return Estimate(fit, problem, label, {"kind": inner.name, "param_set": label}, selection)


def select_and_fit(setup: Setup, ident: Sequence[str], options: CalibrationOptions, kin: ChainKinematics, *,
                   rule: Callable[[Sequence[Candidate]], Candidate] = lowest_score,
                   ) -> tuple[ModelSelection, Fit, Problem]:
    """:class:`SelectBest` of least squares over the identifiable set ``ident``: the selection,
    the fit of the chosen set and its problem."""
    est = SelectBest(rule=rule).fit(setup, ParameterChoice("auto", tuple(ident)), options, kin)
    return est.selection, est.fit, est.problem
