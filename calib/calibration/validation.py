"""Cross-validation (:func:`cross_validate`; its result, :class:`CrossValidation`, is in
:mod:`calib.calibration.cross_validation`), :func:`held_out_error` and the held-out quantities
the statistics and the choice of joint terms use. The choice among candidate parameter sets
(``params="auto"``) is :mod:`calib.calibration.estimators.selection`.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from calib.calibration.estimators.base import Fit
from calib.calibration.options import CV_FOLDS
from calib.calibration.prepare import Setup
from calib.errors import DataError, ParameterError
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.solvers.inverse import normal_inverse
from calib.solvers.blocks import GROUPS
from calib.solvers.problem import Problem

if TYPE_CHECKING:
    from calib.calibration.cross_validation import CrossValidation
    from calib.calibration.estimators.selection import ModelSelection


def _hat_blocks(Jw: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(n, k, k) each row's block of the hat matrix, Jw_i C Jw_i^T, of whitened Jacobian blocks
    Jw (n, k, m) (Jw C as one (n k, m) x (m, m) product: one BLAS call instead of n)."""
    n, k, m = Jw.shape
    return (Jw.reshape(n * k, m) @ C).reshape(n, k, m) @ np.transpose(Jw, (0, 2, 1))


def _held_out_factors(Jw: np.ndarray, C: np.ndarray, H: np.ndarray | None = None) -> np.ndarray:
    """(n, k, k): (I - H_ii)^-1 for each row's whitened Jacobian block Jw (n, k, m), H_ii = Jw_i C
    Jw_i^T its block of the hat matrix (``H`` when already made): a kept row's held-out
    (leave-one-out) residual is this times its residual. A leverage reaching 1 (the row alone
    determines a parameter) counts as 0.99."""
    H = _hat_blocks(Jw, C) if H is None else H
    # H is positive semi-definite: a leverage can reach 0.99 only where its trace does
    high = np.trace(H, axis1=1, axis2=2) >= 0.99
    if not high.any():          # (the usual case: every block inverted as it is, no masks)
        return np.linalg.inv(np.eye(H.shape[1]) - H)
    M = np.empty_like(H)                                         # (I - H)^-1
    M[~high] = np.linalg.inv(np.eye(H.shape[1]) - H[~high])
    w, V = np.linalg.eigh(H[high])
    w = np.minimum(w, 0.99)
    M[high] = (V / (1.0 - w)[:, None, :]) @ np.transpose(V, (0, 2, 1))
    return M


def row_traces(problem: Problem, x: np.ndarray, C: np.ndarray) -> tuple[float, float, float, float]:
    """(t_p, t_r, e_p, e_r) over the rows of ``problem`` at x: t_p / t_r the means of
    tr (I - H_ii)^-1 over the position and the rotation components (whitened units), H_ii = Jw_i C
    Jw_i^T the row's block of the hat matrix (a row whose leverage reaches 1, alone determining a
    parameter, counts as leverage 0.99); e_p / e_r the means of tr (J_i C J_i^T) over the position
    (m^2) and the rotation (rad^2) block of each row's pose Jacobian J_i (the pose error a
    parameter error of covariance C causes, as :func:`~calib.calibration.workspace.propagated`
    gives it; t_r and e_r 0 for position rows only), from one product Jw C: a row's position block
    of J C J^T is sigma_pos^2 times H_ii's, and the rotation blocks sum to tr (C sum J_r^T J_r)
    (Jw's rotation rows carry the log map's Jacobian, the pose error's do not)."""
    t_p = t_r = e_p = 0.0
    m = C.shape[0]
    A_r = np.zeros((m, m))
    n = 0
    for _, Jw, J in problem.whitened_blocks(x, raw=True):
        k = Jw.shape[1]
        H = _hat_blocks(Jw, C)
        d = np.diagonal(_held_out_factors(Jw, C, H), axis1=1, axis2=2)
        t_p += float(d[:, :3].sum())
        t_r += float(d[:, 3:].sum())
        e_p += float(np.trace(H[:, :3, :3], axis1=1, axis2=2).sum())
        if k == 6:
            J_r = J[:, 3:].reshape(-1, m)
            A_r += J_r.T @ J_r
        n += len(Jw)
    n = max(n, 1)
    return t_p / n, t_r / n, e_p * problem.sigma_pos ** 2 / n, float(np.sum(C * A_r)) / n


# ---------------------------------------------------------------- cross-validation
def cross_validate(setup: Setup, fit: Fit, problem: Problem, folds: int = CV_FOLDS, *,
                   options: LMOptions = LMOptions(), seed: int = 0, refit: str = "newton") -> CrossValidation:
    """K-fold cross-validated held-out error of ``fit`` (its parameter set, noise weights and
    kept rows): the kept calibration rows split at random (``seed``) into ``folds`` folds, each
    predicted by the model refitted on the others. The refit is one Gauss-Newton step from the
    fit's solution with the fold's rows taken out of its normal equations, and the fold's
    residuals predicted to first order from the same linearisation (``refit="newton"``, default:
    exact for a model linear in its parameters, and one pass over the data in all; the
    second-order terms are of the order of the parameter errors squared), or LM run to
    convergence and the fold's residuals evaluated (``refit="lm"``)."""
    n = int(fit.keep.sum())
    if folds > n:
        raise ParameterError(f"cv: {folds} folds need at least {folds} calibration rows, there are {n}")
    fold_of = fold_labels(n, folds, seed)
    kept = problem.derived(loss="linear")   # the kept rows, least squares
    x0 = fit.model.values[fit.model.indices(fit.free)]
    e_p, e_r = np.zeros(n), np.zeros(n)
    has_rot = setup.measure == "pose"
    if refit == "newton":
        # (a generator each pass: the whole Jacobian of a million rows is not held at once)
        blocks = lambda: ((r, Jw) for r, Jw, _ in kept.whitened_blocks(x0, raw=True))   # noqa: E731
        prior = None if fit.prior_precision is None else (fit.prior_precision, x0 - fit.prior_mean)
        w_p, w_r = newton_held_out(blocks, fold_of, folds, prior=prior, check_rank=fit.full_rank)
        e_p, e_r = w_p * kept.sigma_pos ** 2, w_r * kept.sigma_rot ** 2
    else:
        if fit.prior_precision is not None:
            raise ParameterError("cross_validate: refit='lm' is least squares; a regularised fit is "
                                 "cross-validated with refit='newton'")
        for f in range(folds):
            where = fold_of == f
            x_f = levenberg_marquardt(kept.derived(keep=~where), x0, "pose", options).x
            dp, dr = kept.derived(keep=where).pose_residuals(x_f)
            e_p[where] = np.sum(dp ** 2, axis=1)
            if dr is not None:
                e_r[where] = np.sum(dr ** 2, axis=1)
    return held_out_summary(fold_of, folds, e_p, e_r if has_rot else None, problem.sigma_pos, problem.sigma_rot)


def fold_labels(n: int, folds: int, seed: int = 0) -> np.ndarray:
    """(n,) the fold of each of n rows: a random permutation (``seed``) dealt into ``folds``
    (the labels of the last few (n, folds, seed) kept: a generator costs more than the deal)."""
    key = (int(n), int(folds), seed) if type(seed) is int else None     # (a Generator, None: drawn)
    fold_of = _FOLD_LABELS.get(key)
    if fold_of is None:
        fold_of = np.empty(n, int)
        fold_of[np.random.default_rng(seed).permutation(n)] = np.arange(n) % folds
        fold_of.setflags(write=False)
        if key is not None:
            _FOLD_LABELS[key] = fold_of
            while len(_FOLD_LABELS) > 8:
                _FOLD_LABELS.pop(next(iter(_FOLD_LABELS)))
    return fold_of.copy()


_FOLD_LABELS: dict = {}


def fold_normal_equations(blocks, fold_of: np.ndarray, folds: int) -> tuple[np.ndarray, np.ndarray]:
    """(A (folds, m, m), g (folds, m)): J^T J and J^T r of each fold's rows (their sums are the
    normal equations of all the rows), from ``blocks()`` (see :func:`newton_held_out`)."""
    A_fold = g_fold = None
    start = 0
    for r, Jw in blocks():
        m = Jw.shape[2]
        if A_fold is None:
            A_fold, g_fold = np.zeros((folds, m, m)), np.zeros((folds, m))
        order, bounds = _by_fold(fold_of[start:start + len(r)], folds)
        start += len(r)
        Jw_f, r_f = Jw[order].reshape(-1, m), r[order].reshape(-1)
        k = Jw.shape[1]
        for f, (a, b) in enumerate(bounds):
            Jf, rf = Jw_f[a * k:b * k], r_f[a * k:b * k]
            A_fold[f] += Jf.T @ Jf
            g_fold[f] += Jf.T @ rf
    return A_fold, g_fold


def _by_fold(fold_of: np.ndarray, folds: int) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """(order, bounds): the rows gathered fold by fold (a stable sort keeps their order within a
    fold) and each fold's (start, end) in that order: a fold's rows are then a slice, the same
    values in the same order as a mask picks, one gather instead of a mask per fold."""
    order = np.argsort(fold_of, kind="stable")
    ends = np.cumsum(np.bincount(fold_of, minlength=folds)).tolist()
    return order, list(zip([0] + ends[:-1], ends))


def newton_held_out(blocks, fold_of: np.ndarray, folds: int, *, prior=None, check_rank: bool = True,
                    cols: np.ndarray | None = None, fold_ne=None,
                    shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each row's whitened squared held-out error, (position (n,), rotation (n,)), predicted by one
    Gauss-Newton step from the linearisation ``blocks()`` (a function that returns an iterable of
    (r (n_b, k), Jw (n_b, k, m)), the whitened residuals and Jacobian of the rows in order) with
    its fold's rows taken out of the normal equations (exact for a model linear in its
    parameters). prior : None or (precision (m,), x0 - prior mean (m,)) of a regularised fit,
    kept in every refit. cols : the model's columns of Jw (default all: a smaller model
    linearised with a larger one's Jacobian); shift : with cols, the step (all columns, zero on
    cols) that takes the other columns to the model's values (a smaller model linearised where
    the larger one's extra parameters are not at its values); fold_ne : the blocks'
    :func:`fold_normal_equations` when already made. A fold without which the rows cannot
    identify the parameters raises DataError when ``check_rank``."""
    n = len(fold_of)
    A_fold, g_fold = fold_ne if fold_ne is not None else fold_normal_equations(blocks, fold_of, folds)
    m_all = A_fold.shape[1]
    if cols is not None:
        if shift is not None:       # (the rows' residuals after the shift: r + J shift)
            g_fold = g_fold + A_fold @ shift
        A_fold, g_fold = A_fold[:, cols][:, :, cols], g_fold[:, cols]
    m = A_fold.shape[1]
    A_all, g_all = A_fold.sum(axis=0), g_fold.sum(axis=0)
    if prior is not None:
        A_all = A_all + np.diag(prior[0])
        g_all = g_all + prior[0] * prior[1]
    # the folds' refits: A without each fold's rows, inverted at once
    A_inv, full = normal_inverse(A_all[None] - A_fold)
    bad = np.flatnonzero(~full)
    if len(bad) and check_rank:
        # without this fold the rows cannot identify the parameters: its prediction would be
        # the whole fit's, which has seen it (a leak), not a held-out error
        f = int(bad[0])
        raise DataError(f"cross-validation: without fold {f + 1} of {folds} the remaining "
                        f"{n - int(np.sum(fold_of == f))} rows cannot identify the {m} parameters")
    dx = -np.einsum("fij,fj->fi", A_inv, g_all[None] - g_fold)       # (folds, m)
    if cols is not None:
        dx_all = np.zeros((folds, m_all)) if shift is None else np.tile(shift, (folds, 1))
        dx_all[:, cols] = dx
        dx = dx_all
    # each row's whitened residual at its fold's refit, r + Jw dx
    w_p, w_r = np.zeros(n), np.zeros(n)
    start = 0
    for r, Jw in blocks():
        lab = fold_of[start:start + len(r)]
        pred = r + np.einsum("nkm,nm->nk", Jw, dx[lab])
        w_p[start:start + len(r)] = np.sum(pred[:, :3] ** 2, axis=1)
        w_r[start:start + len(r)] = np.sum(pred[:, 3:] ** 2, axis=1)
        start += len(r)
    return w_p, w_r


def held_out_summary(fold_of: np.ndarray, folds: int, e_p: np.ndarray, e_r: np.ndarray | None,
                     sigma_pos: float, sigma_rot: float) -> CrossValidation:
    """The :class:`CrossValidation` of the rows' squared held-out errors e_p (m^2) and e_r (rad^2,
    None for position data), their scores whitened at sigma_pos / sigma_rot."""
    has_rot = e_r is not None
    order, bounds = _by_fold(fold_of, folds)
    ep_f = e_p[order]
    er_f = e_r[order] if has_rot else None
    per_fold = [(b - a, math.sqrt(_mean(ep_f[a:b])), math.sqrt(_mean(er_f[a:b])) if has_rot else None)
                for a, b in bounds]
    score = e_p / sigma_pos ** 2 + (e_r / sigma_rot ** 2 if has_rot else 0.0)
    from calib.calibration.cross_validation import CrossValidation

    return CrossValidation(folds, math.sqrt(_mean(e_p)), math.sqrt(_mean(e_r)) if has_rot else None,
                           tuple(per_fold), _mean(score), _standard_error(score), score)


def _mean(x: np.ndarray) -> float:
    """np.mean of a 1-D float array (its sum, then the division; nan when empty) without its
    wrapper's cost: the same value."""
    return float(np.add.reduce(x)) / len(x) if len(x) else math.nan


def _standard_error(values: np.ndarray) -> float:
    """The standard error of the mean of ``values`` (1-D): np.std(ddof=1) / sqrt(n), its sums as
    np.std makes them (the mean, the squared deviations summed, / (n - 1)) without its wrapper."""
    values = np.asarray(values, float)
    n = len(values)
    if n < 2:
        return 0.0
    d = values - np.add.reduce(values) / n
    return float(np.sqrt(np.add.reduce(d * d) / (n - 1)) / math.sqrt(n))


def held_out_error(setup: Setup, fit: Fit, problem: Problem, selection: ModelSelection | None, folds: int,
                   options: LMOptions) -> tuple[CrossValidation | None, list[str]]:
    """The cross-validated held-out error of ``fit`` when there are no validation rows and
    ``folds`` >= 2 (the chosen candidate's after model selection), and a note when it cannot run."""
    if setup.val is not None or folds < 2:
        return None, []
    if selection is not None:
        return next(c.cv for c in selection.candidates if c.label == selection.chosen), []
    if fit.keep.sum() < folds:
        return None, [f"no cross-validation: fewer rows than the {folds} folds"]
    try:
        if setup.touch is not None:
            return cross_validate_blocks(fit, problem, folds), []
        return cross_validate(setup, fit, problem, folds, options=options), []
    except DataError as exc:
        return None, [f"no cross-validation: {exc}"]


def stratified_folds(strata: np.ndarray, folds: int, seed: int = 0) -> np.ndarray:
    """(n,) the fold of each row, dealt stratum by stratum (``strata``: each row's stratum, e.g.
    the feature a touch row touches) from a random permutation of its rows and a random first
    fold (``seed``): every stratum keeps rows in every refit that it has more rows than folds for."""
    rng = np.random.default_rng(seed)
    fold_of = np.empty(len(strata), int)
    for s in np.unique(strata):
        rows = rng.permutation(np.flatnonzero(strata == s))
        fold_of[rows] = (np.arange(len(rows)) + rng.integers(folds)) % folds
    return fold_of


def cross_validate_blocks(fit: Fit, problem, folds: int = CV_FOLDS, seed: int = 0) -> CrossValidation:
    """K-fold cross-validated held-out error of a fit of residual blocks (touch data;
    ``problem``: its kept rows, :class:`calib.solvers.blocks.BlockProblem`): the folds dealt within
    each stratum (:func:`stratified_folds`: every feature keeps rows in every refit), each fold
    predicted by one Gauss-Newton step from the fit's solution without its rows
    (:func:`newton_held_out`, as :func:`cross_validate`). position_rms : RMS over the rows of the
    held-out error's norm (a touch row's distance to its feature, a measured row's position
    error); rotation_rms : the measured rotations' (None without); ``groups`` : each residual
    group's held-out RMS per component."""
    x = fit.solver.x
    fold_rows = stratified_folds(problem.strata(), folds, seed)
    chunks = list(problem.row_blocks(x))
    order = np.concatenate([rows for rows, _, _, _ in chunks])
    w_p, w_r = newton_held_out(lambda: ((r, Jw) for _, r, Jw, _ in chunks), fold_rows[order], folds,
                               check_rank=fit.full_rank)
    levels = np.asarray(problem.levels)
    e_p, e_r = np.zeros(problem.n_poses), np.full(problem.n_poses, np.nan)
    sq, count = np.zeros(3), np.zeros(3)
    start = 0
    for rows, r, _, groups in chunks:
        a, b = w_p[start:start + len(rows)], w_r[start:start + len(rows)]
        start += len(rows)
        g_p, g_r = groups[:, 0], groups[:, -1]          # (a row's first three components: one group)
        e_p[rows] = a * levels[g_p] ** 2
        if r.shape[1] == 6:
            e_r[rows] = b * levels[g_r] ** 2
        np.add.at(sq, g_p, e_p[rows])
        np.add.at(count, g_p, min(r.shape[1], 3))
        if r.shape[1] == 6:
            np.add.at(sq, g_r, e_r[rows])
            np.add.at(count, g_r, 3)
    summary = held_out_summary(fold_rows, folds, e_p, None, 1.0, 1.0)
    measured = ~np.isnan(e_r)
    score = np.empty(problem.n_poses)
    score[order] = w_p + w_r
    from dataclasses import replace

    return replace(summary, rotation_rms=math.sqrt(_mean(e_r[measured])) if measured.any() else None,
                   score=_mean(score), score_se=_standard_error(score), row_scores=score,
                   groups={g: math.sqrt(sq[k] / count[k]) for k, g in enumerate(GROUPS) if count[k]})
