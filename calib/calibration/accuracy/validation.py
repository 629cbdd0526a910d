"""Cross-validation (:func:`cross_validate`; its result, :class:`CrossValidation`, is in
:mod:`calib.calibration.accuracy.cross_validation`), :func:`held_out_error` and the held-out quantities
the statistics and the choice of joint terms use. The choice among candidate parameter sets
(``params="auto"``) is :mod:`calib.calibration.estimators.selection`.

Data that disagree with themselves (:func:`data_consistency`, :func:`consistency_notes`): when
many calibration rows are flagged as outliers (more than :data:`INCONSISTENT_SHARE` of them), the
predictions of the fit describe only rows like the kept ones; the held-out error of every row,
flagged ones included, is measured, and the commonest cause, a moved instrument, tried on the
flagged rows. A kept row's held-out error is its leave-one-out residual, (I - H_ii)^-1 r_i with
H_ii its block of the hat matrix (exact for the linearised fit, also for a MAP fit with its
posterior covariance); a flagged row's is its residual (the fit did not use it).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np

from calib.memo import Memo
from calib.calibration.estimators.base import Fit
from calib.calibration.options import CV_FOLDS
from calib.calibration.prepare import Setup
from calib.errors import DataError, ParameterError
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.solvers.inverse import normal_inverse
from calib.solvers.blocks import GROUPS
from calib.solvers.problem import Problem

if TYPE_CHECKING:
    from calib.calibration.accuracy.cross_validation import CrossValidation, ModelSelection


def _hat_blocks(Jw: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(n, k, k) each row's block of the hat matrix, Jw_i C Jw_i^T, of whitened Jacobian blocks
    Jw (n, k, m) (Jw C as one (n k, m) x (m, m) product: one BLAS call instead of n)."""
    n, k, m = Jw.shape
    return (Jw.reshape(n * k, m) @ C).reshape(n, k, m) @ np.transpose(Jw, (0, 2, 1))


def held_out_factors(Jw: np.ndarray, C: np.ndarray, H: np.ndarray | None = None) -> np.ndarray:
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
    parameter error of covariance C causes, as :func:`~calib.calibration.accuracy.workspace.propagated`
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
        d = np.diagonal(held_out_factors(Jw, C, H), axis1=1, axis2=2)
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
    fold_of = None if key is None else FOLD_LABELS.get(key)
    if fold_of is None:
        fold_of = np.empty(n, int)
        fold_of[np.random.default_rng(seed).permutation(n)] = np.arange(n) % folds
        fold_of.setflags(write=False)
        if key is not None:
            FOLD_LABELS.put(key, fold_of)
    return fold_of.copy()


FOLD_LABELS = Memo("fold labels", 8)


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
    from calib.calibration.accuracy.cross_validation import CrossValidation

    return CrossValidation(folds, math.sqrt(_mean(e_p)), math.sqrt(_mean(e_r)) if has_rot else None,
                           tuple(per_fold), _mean(score), standard_error(score), score)


def _mean(x: np.ndarray) -> float:
    """np.mean of a 1-D float array (its sum, then the division; nan when empty) without its
    wrapper's cost: the same value."""
    return float(np.add.reduce(x)) / len(x) if len(x) else math.nan


def standard_error(values: np.ndarray) -> float:
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
                   score=_mean(score), score_se=standard_error(score), row_scores=score,
                   groups={g: math.sqrt(sq[k] / count[k]) for k, g in enumerate(GROUPS) if count[k]})


# ---------------------------------------------------------------- the data's consistency
#: More flagged calibration rows than this share: the data disagree with themselves.
INCONSISTENT_SHARE = 0.1
#: A rigid move of the measurement frame explains the flagged rows when it leaves them within
#: this factor of the predicted held-out error (and halves their error).
MOVED_FRAME_FACTOR = 3.0

_CAUSES = ("two measurement campaigns in one file (another day, another setup)",
           "an instrument (or the robot's base) moved during the measurements",
           "joint values in the wrong units for some rows (degrees read as radians), or a joint's zero "
           "or sign changed between campaigns")


def held_out_residuals(problem: Problem, x: np.ndarray, keep: np.ndarray,
                       covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Each calibration row's held-out residual (model - measured, meas frame).

    problem : every calibration row, weighted by the fit's noise levels (least squares); x : the
    fit's free parameters; keep : (N,) bool, the rows the fit used; covariance : (m, m) the fit's
    covariance of x in the same weights. Returns position (N, 3) metres and rotation (N, 3)
    radians (None for position-only data): for a kept row its leave-one-out residual, for a
    row left out its residual.
    """
    keep = np.asarray(keep, bool)
    k = 6 if problem.has_orientation else 3
    e = np.empty((problem.n_poses, k))
    start = 0
    for r, Jw, _ in problem.whitened_blocks(x, raw=True):
        sl = slice(start, start + len(r))
        kept = keep[sl]
        e[sl] = r
        if kept.any():
            e[sl][kept] = np.einsum("nij,nj->ni", held_out_factors(Jw[kept], covariance), r[kept])
        start += len(r)
    dp = e[:, :3] * problem.sigma_pos
    return dp, (e[:, 3:] * problem.sigma_rot if k == 6 else None)


def _rms(dp: np.ndarray, dr: np.ndarray | None, mask: np.ndarray) -> dict:
    """position_rms (m), rotation_rms (rad, None position only) of the rows in ``mask``."""
    if not mask.any():
        return {"position_rms": None, "rotation_rms": None}
    pos = math.sqrt(float(np.mean(np.sum(dp[mask] ** 2, axis=1))))
    rot = None if dr is None else math.sqrt(float(np.mean(np.sum(dr[mask] ** 2, axis=1))))
    return {"position_rms": pos, "rotation_rms": rot}


def _rigid_fit(p_from: np.ndarray, p_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (3, 3) and translation t (3,) minimising sum |R p_from + t - p_to|^2 (Kabsch)."""
    c_from, c_to = p_from.mean(axis=0), p_to.mean(axis=0)
    U, _, Vt = np.linalg.svd((p_from - c_from).T @ (p_to - c_to))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, c_to - R @ c_from


def _runs(indices: np.ndarray, rows: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive calibration rows among ``indices`` (sorted positions), as (first, last)
    file rows."""
    runs: list[tuple[int, int]] = []
    for i in indices:
        if runs and i == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], int(i))
        else:
            runs.append((int(i), int(i)))
    return [(int(rows[a]), int(rows[b])) for a, b in runs]


def data_consistency(problem: Problem, x: np.ndarray, keep: np.ndarray, covariance: np.ndarray,
                     predicted_holdout: Mapping, *, rows: Sequence[int], flagged_rows: Sequence[int] | None = None,
                     share: float = INCONSISTENT_SHARE) -> dict | None:
    """Whether the calibration rows agree with themselves, and what the disagreement costs.

    Parameters
    ----------
    problem, x, keep, covariance : as :func:`held_out_residuals` (every calibration row, the
        fit's free parameters, the rows it used, its covariance in the same weights).
    predicted_holdout : the fit's predicted RMS error of new rows like the kept ones
        (position_rms m, rotation_rms rad).
    rows : (N,) the file row of each calibration row; flagged_rows : the file rows flagged as
        outliers (removed or, being too many, kept); default: the rows not kept.
    share : the share of flagged rows above which the data count as inconsistent.

    Returns None when at most ``share`` of the rows are flagged; else a dict: ``flagged``,
    ``removed`` (how many of them the fit left out), ``rows``, ``share``, ``flagged_rows`` (file rows), ``runs`` ((first, last) file rows of the
    flagged rows' consecutive runs), ``held_out_all_rows`` / ``held_out_kept_rows`` /
    ``held_out_flagged_rows`` (position_rms m, rotation_rms rad: RMS held-out error of those
    rows), ``predicted_holdout`` (as given), ``moved_frame`` (a rigid move of the measurement
    frame fitted to the flagged rows' positions: translation_m, rotation_rad, position_rms_before
    / _after (m), explains (bool); None under 3 flagged rows) and ``causes`` (the likely
    causes, the one the data point to first).
    """
    rows = np.asarray(rows)
    keep = np.asarray(keep, bool)
    flagged = np.isin(rows, list(flagged_rows)) if flagged_rows is not None else ~keep
    n_flag = int(flagged.sum())
    if n_flag <= share * len(rows):
        return None
    dp, dr = held_out_residuals(problem, x, keep, covariance)
    pred = {"position_rms": predicted_holdout.get("position_rms"), "rotation_rms": predicted_holdout.get("rotation_rms")}
    moved = None
    causes = list(_CAUSES)
    if n_flag >= 3:
        # the fitted model's positions of the flagged rows moved rigidly onto the measured ones
        p_meas = problem.p_meas[flagged]
        p_model = p_meas + problem.pose_residuals(x)[0][flagged]
        R, t = _rigid_fit(p_model, p_meas)
        before = math.sqrt(float(np.mean(np.sum((p_model - p_meas) ** 2, axis=1))))
        after = math.sqrt(float(np.mean(np.sum((p_model @ R.T + t - p_meas) ** 2, axis=1))))
        angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0)))
        limit = MOVED_FRAME_FACTOR * (pred["position_rms"] or 0.0)
        explains = bool(after <= 0.5 * before and after <= limit)
        moved = {"translation_m": float(np.linalg.norm(t + R @ p_model.mean(axis=0) - p_model.mean(axis=0))),
                 "rotation_rad": angle, "position_rms_before": before, "position_rms_after": after,
                 "explains": explains}
        if not explains:
            causes = [causes[2], causes[0], causes[1]]
    return {"flagged": n_flag, "removed": int(np.sum(flagged & ~keep)), "rows": int(len(rows)),
            "share": n_flag / len(rows),
            "flagged_rows": [int(r) for r in rows[flagged]], "runs": _runs(np.flatnonzero(flagged), rows),
            "held_out_all_rows": _rms(dp, dr, np.ones(len(rows), bool)),
            "held_out_kept_rows": _rms(dp, dr, keep), "held_out_flagged_rows": _rms(dp, dr, flagged),
            "predicted_holdout": pred, "moved_frame": moved, "causes": causes}


def _figures(d: Mapping) -> str:
    rot = "" if d.get("rotation_rms") is None else f", orientation {d['rotation_rms']:.3g} rad"
    return f"position {d['position_rms'] * 1e3:.4g} mm{rot}"


def consistency_notes(consistency: Mapping | None) -> list[str]:
    """The leading note of a result whose data disagree with themselves (see
    :func:`data_consistency`; [] for None)."""
    if not consistency:
        return []
    c = consistency
    runs = c["runs"]
    where = (", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in runs[:4]) + (", ..." if len(runs) > 4 else ""))
    head = (f"the data disagree with themselves: {c['flagged']} of {c['rows']} calibration rows "
            f"({100 * c['share']:.0f}%, rows {where}) ")
    if c["removed"]:
        head += "were flagged as outliers and left out, so the predictions describe only rows like the kept ones"
    else:
        head += ("have residuals above the outlier threshold, too many to leave out: the fit is a compromise "
                 "between rows that disagree")
    text = (f"{head}. Held-out RMS error of all rows, flagged ones included: {_figures(c['held_out_all_rows'])}; "
            f"predicted for new rows like the kept ones: {_figures(c['predicted_holdout'])}.")
    mv = c.get("moved_frame")
    if mv is not None:
        if mv["explains"]:
            text += (f" A rigid move of the measurement frame ({mv['translation_m'] * 1e3:.3g} mm, "
                     f"{mv['rotation_rad']:.3g} rad) fitted to the flagged rows brings them from "
                     f"{mv['position_rms_before'] * 1e3:.3g} mm to {mv['position_rms_after'] * 1e3:.3g} mm RMS:"
                     f" the instrument most likely moved between them and the others.")
        else:
            text += (f" A rigid move of the measurement frame does not explain the flagged rows (it leaves "
                     f"{mv['position_rms_after'] * 1e3:.3g} of their {mv['position_rms_before'] * 1e3:.3g} mm RMS).")
    text += (" Likely causes: " + "; ".join(c["causes"]) + ". Calibrate each campaign (or instrument "
             "placement) apart, or find and fix the flagged rows.")
    return [text]


def consistency_dict(c: dict | None) -> dict | None:
    """The JSON form of :func:`calib.calibration.accuracy.validation.data_consistency`'s record (mm, rad)."""
    if c is None:
        return None

    def figures(d):
        return {"position_mm": None if d["position_rms"] is None else d["position_rms"] * 1e3,
                "rotation_rad": d["rotation_rms"]}
    mv = c["moved_frame"]
    return {"flagged": c["flagged"], "removed": c["removed"], "rows": c["rows"], "share": c["share"], "flagged_rows": c["flagged_rows"],
            "runs": [list(r) for r in c["runs"]],
            "held_out_all_rows": figures(c["held_out_all_rows"]), "held_out_kept_rows": figures(c["held_out_kept_rows"]),
            "held_out_flagged_rows": figures(c["held_out_flagged_rows"]),
            "predicted_holdout": figures(c["predicted_holdout"]),
            "moved_frame": None if mv is None else {
                "translation_mm": mv["translation_m"] * 1e3, "rotation_rad": mv["rotation_rad"],
                "position_rms_before_mm": mv["position_rms_before"] * 1e3,
                "position_rms_after_mm": mv["position_rms_after"] * 1e3, "explains": mv["explains"]},
            "causes": list(c["causes"])}
