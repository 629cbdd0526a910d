"""The outlier check of the fit stage: which calibration rows are gross (:class:`~calib.calibration.estimators.outlier.Outlier`),
judged against a fit that they cannot drag (:func:`judge_rows`).

A least-squares fit spreads gross rows over the others until none stands out, and inflates
the noise estimate with them. The rows are judged instead against

- a high-breakdown fit (:func:`trimmed_fit`, least trimmed squares of a third of the rows,
  then the least-squares fit of the rows it does not flag) when the rows are few (where the
  spread can hide gross rows altogether: 12 of 40 position-only rows 5 mm off, none flagged)
  or when the least-squares noise level is far above the robust one (the median absolute
  residual): many gross rows;
- a robust (Huber) fit when the least-squares residuals already flag a row;
- the least-squares fit itself otherwise (clean data pay for nothing more: 100 full poses).

More than half of the rows flagged against the high-breakdown fit (its breakdown point) means
data inconsistent with the model: :attr:`Judgement.breakdown` says so, and the fit stage
refuses the result (status "implausible"). The noise levels those rows are judged by come from
the rows the trimmed fit fits, then from the rows within k sigma of it until that set settles
(issue 39: from every kept row they sat in the gross rows where those are more than half).
scripts/accept_gross_rows.py measures it all. Heavy tails of the final fit (a least-squares
noise level far above the robust one) are measured here (:class:`Tails`,
:func:`leftover_gross`) and noted, not refused: the data-consistency rule and the texts of its
refusals and note are in :mod:`calib.calibration.plausibility`, beside the other rules
(scripts/bench_refusal.py measures its false refusals).

The noise levels are a tuple in the problem's order: (sigma_pos, sigma_rot) of a
:class:`~calib.solvers.problem.Problem`, (sigma_pos, sigma_rot, sigma_touch) of a
:class:`~calib.solvers.blocks.BlockProblem` (:func:`levels_of`); the rows of a problem of blocks
are judged by each row's components whitened by its groups' levels, and the trimmed fit keeps
the best rows of each stratum (the measured rows; each feature's touch rows), so that no block
and no feature is left without rows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.calibration.frames import median
from calib.calibration.options import (
    ROBUST_CHECK_FTOL,
    ROBUST_CHECK_INFLATION,
    ROBUST_CHECK_ITERATIONS,
    TRIMMED_FIT_STEPS,
    TRIMMED_MAX_OUTLIER_SHARE,
    WARM_MU0,
)
from calib.calibration.plausibility import heavy_tails_note, inconsistent_rows
from calib.solvers.blocks import GROUPS, BlockProblem
from calib.solvers.lm import LMOptions, LMTrace, levenberg_marquardt, options_with
from calib.solvers.inverse import normal_inverse
from calib.solvers.problem import Problem

if TYPE_CHECKING:      # (built when rows are flagged: calib.calibration.estimators.outlier)
    from calib.calibration.estimators.outlier import Outlier


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Judgement:
    """The outlier check of one pass: ``outliers`` newly flagged (empty when ``too_many``);
    too_many : more rows above the threshold than outliers can be (the noise levels too small,
    or the model wrong); x : where the fit continues (the robust fit's solution when it flagged
    rows, else the fit's own); sigma_pos (m) / sigma_rot (rad): the noise levels the rows were
    judged with; trimmed : judged against the trimmed fit; breakdown : why the data are
    inconsistent when more than half of the rows are gross against the trimmed fit (its
    breakdown point; nothing flagged), else empty."""

    outliers: tuple[Outlier, ...]
    too_many: bool
    x: np.ndarray
    levels: tuple[float, ...]
    trimmed: bool = False
    breakdown: str = ""


def levels_of(problem) -> tuple[float, ...]:
    """The noise levels a problem is weighted by: (sigma_pos, sigma_rot), and sigma_touch for a
    problem of residual blocks."""
    if isinstance(problem, BlockProblem):
        return problem.levels
    return problem.sigma_pos, problem.sigma_rot


def at_levels(problem, levels: Sequence[float], **changes):
    """``problem`` weighted by the noise ``levels`` (see :func:`levels_of`), with ``changes``."""
    if isinstance(problem, BlockProblem):
        return problem.derived(sigma_pos=levels[0], sigma_rot=levels[1], sigma_touch=levels[2], **changes)
    return problem.derived(sigma_pos=levels[0], sigma_rot=levels[1], **changes)


def components(problem, keep: np.ndarray | None = None) -> int:
    """The residual components of the rows ``keep`` (default all)."""
    if isinstance(problem, BlockProblem):
        return problem.components(keep)
    n = problem.n_poses if keep is None else int(np.count_nonzero(keep))
    return n * (6 if problem.has_orientation else 3)


def row_rms(problem: Problem, x: np.ndarray, levels: Sequence[float]):
    """Each row's whitened residual RMS per component at the noise ``levels``, its position
    residuals (N, 3) metres (a touch row's displacement from its feature) and the norm of its
    rotation residual (radians; NaN without orientation data)."""
    if isinstance(problem, BlockProblem):
        return problem.row_rms(x, levels), problem.pose_residuals(x)[0], problem.row_errors(x)[1]
    sigma_pos, sigma_rot = levels[0], levels[1]
    dp, dr = problem.pose_residuals(x)
    blocks = [dp / sigma_pos]
    rot = np.full(len(dp), np.nan)
    if dr is not None:
        blocks.append(dr / sigma_rot)
        rot = np.linalg.norm(dr, axis=1)
    w = np.concatenate(blocks, axis=1)
    return np.sqrt(np.mean(w ** 2, axis=1)), dp, rot


def flag_outliers(problem: Problem, x: np.ndarray, rows: np.ndarray, keep: np.ndarray, k: float,
                  levels: Sequence[float], max_share: float = 0.25,
                  spread: np.ndarray | None = None) -> tuple[list[Outlier], bool]:
    """Rows still kept whose whitened residual RMS per component exceeds k (with the noise
    ``levels``), and whether they are too many (more than ``max_share`` of the kept rows) to be
    outliers. ``problem`` holds all calibration rows; rows : their line numbers; spread : (N,)
    each row's residual RMS expected from noise, in sigma (default 1: rows the fit saw; a row
    predicted by a fit of other rows errs by its noise and the fit's prediction error)."""
    rms, dp, rot = row_rms(problem, x, levels)
    bad = np.flatnonzero(keep & (rms > k * (1.0 if spread is None else spread)))
    found = []
    if len(bad):
        from calib.calibration.estimators.outlier import Outlier

        found = [Outlier(int(rows[i]), float(np.linalg.norm(dp[i])), float(rot[i]), float(rms[i])) for i in bad]
    return found, len(bad) > max_share * keep.sum()


def robust_sigmas(problem: Problem, x: np.ndarray, keep: np.ndarray, red: Sequence[float]) -> tuple[float, ...]:
    """Noise levels (see :func:`levels_of`) from the median absolute residual component of each
    group over the rows ``keep`` (1.4826 MAD, corrected for the fit's share of the degrees of
    freedom): what outliers cannot inflate. red : each group's redundancy in the fit."""
    if isinstance(problem, BlockProblem):
        out = list(problem.levels)
        for g, r in problem.group_residuals(x, keep).items():
            k = GROUPS.index(g)
            if len(r):
                f = max(red[k] / len(r), 1e-3)
                out[k] = max(1.4826 * median(np.abs(r)) / math.sqrt(f), 1e-12)
        return tuple(out)
    red_p, red_r = red[0], red[1]
    dp, dr = problem.pose_residuals(x)
    n = keep.sum()
    f_p = max(red_p / (3 * n), 1e-3)
    sp = 1.4826 * median(np.abs(dp[keep])) / math.sqrt(f_p)
    sr = problem.sigma_rot
    if dr is not None:
        f_r = max(red_r / (3 * n), 1e-3)
        sr = 1.4826 * median(np.abs(dr[keep])) / math.sqrt(f_r)
    return max(sp, 1e-12), max(sr, 1e-12)


def trimmed_fit(problem: Problem, starts: Sequence[np.ndarray], keep: np.ndarray, levels: Sequence[float],
                options: LMOptions, trace: LMTrace) -> np.ndarray:
    """A high-breakdown fit of ``problem``'s kept rows (least trimmed squares by concentration
    steps): from each start, the least-squares fit of the h kept rows with the smallest whitened
    residuals (at the robust noise levels given), repeated until those rows stop changing; the
    solution whose h best rows have the smallest sum of squares. h : a third of the rows (at
    least twice as many residual components as parameters, at most half of the rows): random
    gross rows up to half of them leave a third of clean rows, where the concentration finds
    them (with h a half, 50 of 100 rows 5 mm off were missed in 2 of 5 runs). ``problem`` holds all
    calibration rows (its weights: the robust noise levels); starts : free-parameter vectors (SI
    units), e.g. the least-squares solution and the nominal values (a least-squares fit dragged
    by many gross rows can lead the steps to a half that holds some of them). LM starts at the
    re-fits' damping WARM_MU0 where it starts near a solution (from the first start, a fit of
    these rows, and from the last step's fit), at the options' from the others (1 to 2 Jacobian
    passes fewer per fit on 25 full-pose rows). A problem of residual blocks keeps the best rows
    of each stratum, in proportion
    (:func:`best_rows_of`)."""
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL))     # (it ranks rows)
    h = trim_size(problem, keep, len(starts[0]))
    best, best_cost = None, np.inf
    apart = _apart(problem)
    warm = options_with(options, mu0=min(options.mu0, WARM_MU0))
    for i, x in enumerate(starts):
        chosen = None
        for step in range(TRIMMED_FIT_STEPS):
            rms = np.where(keep, row_rms(problem, x, levels)[0], np.inf)
            best_rows = best_rows_of(problem, rms, keep, int(h))
            if chosen is not None and np.array_equal(best_rows, chosen):
                break
            chosen = best_rows
            x = levenberg_marquardt(apart.derived(keep=chosen), x, "pose", warm if (i == 0 or step) else options,
                                    trace).x
        rms = np.where(keep, row_rms(problem, x, levels)[0], np.inf)
        cost = (float(np.sum(rms[best_rows_of(problem, rms, keep, int(h))] ** 2)) if isinstance(problem, BlockProblem)
                else float(np.sum(np.sort(rms)[:h] ** 2)))
        if cost < best_cost:
            best, best_cost = x, cost
    return best


def trim_size(problem, keep: np.ndarray, n_params: int) -> int:
    """The number h of rows the trimmed fit fits (:func:`trimmed_fit`): a third of the kept
    rows, at least twice as many residual components as parameters, at most half of the rows."""
    n = int(keep.sum())
    per_row = 6 if problem.has_orientation else 3
    if isinstance(problem, BlockProblem):
        per_row = components(problem, keep) / max(n, 1)
    return int(min(max(-(-n // 3), -(-2 * n_params // per_row) + 1), (n + 1) // 2))


def best_rows_of(problem, rms: np.ndarray, keep: np.ndarray, h: int) -> np.ndarray:
    """(N,) bool: the h kept rows of smallest whitened residual ``rms``; of a problem of residual
    blocks, the best of each stratum in proportion to its kept rows (at least 3 of it, or all it
    has: a block or a feature without rows would leave its unknowns undetermined)."""
    best = np.zeros(len(rms), bool)
    if not isinstance(problem, BlockProblem):
        best[np.argsort(rms, kind="stable")[:h]] = True
        return best
    strata, n = problem.strata(), max(int(keep.sum()), 1)
    for s in np.unique(strata[keep]):
        mine = np.flatnonzero(keep & (strata == s))
        take = min(len(mine), max(3, -(-h * len(mine) // n)))
        best[mine[np.argsort(rms[mine], kind="stable")[:take]]] = True
    return best


def _apart(problem: Problem) -> Problem:
    """``problem``'s rows (as an index: the problems derived from it for subsets of them keep
    their results in caches of their own): the many passes of the trimmed fit's subsets do not
    push out of the shared cache the normal equations of the kept rows at the fit's solution, where
    the refit of the rows it keeps starts (a Jacobian pass saved)."""
    return problem.derived(keep=np.arange(problem.n_poses))


#: The trimmed route's flags stand only when the least-squares refit of the rows it keeps has at
#: least this share of their position components as redundancy (the noise it judges by comes
#: from them).
TRIM_MIN_REDUNDANCY_SHARE = 0.25
#: The same for a problem of residual blocks, of all its components: a feature's rows carry its
#: own unknowns besides the robot's (one point touched from 6 orientations, the tool fitted, a
#: robot with 0.5 mm errors: the refit of 3 rows had a redundancy of 3 of its 9 components, and
#: flagged the 3 others, off by the robot's unmodelled errors).
TRIM_MIN_BLOCKS_REDUNDANCY_SHARE = 0.5
#: Residual components per parameter that half of the rows must hold for the trimmed fit.
TRIM_MIN_RATIO = 1.5


def can_trim(problem: Problem, keep: np.ndarray, n_params: int) -> bool:
    """Whether half of the kept rows hold TRIM_MIN_RATIO residual components per parameter: the
    trimmed fit (at most half of the rows) determines the parameters, and leaves residuals that
    say what the noise is, only then. 8 full-pose rows of a 6-axis arm, 30 parameters: a fit of 4
    rows passed through them and flagged the other 4 of noise-free data as gross; the real TIAGo
    marker data, 27 position-only rows, 33 parameters: a fit of 14 rows (42 components) flagged
    13 of the 27 (held-out error 4.27 mm instead of 3.81); 25 position-only rows of 23
    parameters (39 components in 13 rows) are trimmed and their 2 gross rows found."""
    if isinstance(problem, BlockProblem):
        return components(problem, keep) / 2 >= TRIM_MIN_RATIO * n_params
    per_row = 6 if problem.has_orientation else 3
    return (int(keep.sum()) + 1) // 2 * per_row >= TRIM_MIN_RATIO * n_params


def judge_rows(everything: Problem, problem: Problem, x: np.ndarray, keep: np.ndarray, rows: np.ndarray,
               k: float, *, given: tuple[float | None, ...], red: tuple[float, ...],
               few: bool, first: bool = True, options: LMOptions, trace: LMTrace) -> Judgement:
    """The outlier check of the fit at x (see the module docstring).

    everything : the problem of all calibration rows; problem : the fit's (the kept rows, its
    noise levels and loss); keep : (N,) bool, rows kept; rows : (N,) their line numbers; k : the
    threshold on a row's whitened residual RMS per component; given : the noise levels the user
    gave, in the order of :func:`levels_of` (None: estimated); red : the fit's redundancy of each
    group, in the same order; few : the rows hold few residual components per parameter; first :
    no row was flagged yet (few rows go to the high-breakdown fit on the first judgement only:
    once the gross rows are out, a trimmed fit of what is left, a third of a few rows, scatters
    its predictions for the others and flagged 12 good rows of 24).
    """
    levels = levels_of(problem)
    estimate = any(g is None for g in given)
    found = _levels(everything, x, keep, red, given, levels) if estimate else levels
    new, too_many = flag_outliers(everything, x, rows, keep, k, found)
    if problem.loss != "linear":
        return Judgement(tuple(new), too_many, x, found)
    # few rows (a least-squares fit spreads gross rows until none stands out, and the median
    # residual swells with them: 12 of 40 position-only rows 5 mm off, 1.5 mm noise estimated
    # against 0.02 mm), or a least-squares noise level far above the robust one (many gross
    # rows): judged against the high-breakdown fit
    if can_trim(everything, keep, len(x)) and ((few and first) or (
            estimate and max(a / b for a, b in zip(levels, found)) > ROBUST_CHECK_INFLATION)):
        return _judge_trimmed(everything, problem, x, keep, rows, k, found, given, red, options, trace)
    if not new:
        return Judgement(tuple(new), too_many, x, found)
    # a least-squares fit spreads a gross error over its neighbours: judge the rows against a
    # robust (Huber) fit instead, then refit by least squares without them
    x_robust, found = _huber(everything, problem, x, keep, red, given, found, options, trace)
    new, too_many = flag_outliers(everything, x_robust, rows, keep, k, found)
    return Judgement(tuple(new), too_many, x_robust if (new and not too_many) else x, found)


def _levels(everything, x, rows, red, given, levels) -> tuple[float, ...]:
    """The robust noise levels at x over ``rows`` where they are estimated, the given ones
    (``levels``) where not; red : the fit's redundancy of each group on ``rows``."""
    robust = robust_sigmas(everything, x, rows, red)
    return tuple(r if g is None else lv for r, g, lv in zip(robust, given, levels))


def _huber(everything, problem, x, keep, red, given, levels, options, trace, judged=None):
    """The Huber fit of the kept rows from x at the noise levels ``levels``, with the noise
    levels re-taken from its residuals on the rows ``judged`` (default: the kept rows) and the
    fit repeated (ROBUST_CHECK_ITERATIONS at most,
    until they change by less than 10 %): with several gross rows the first levels, from a
    least-squares fit's smeared residuals, set the threshold near them (5 rows 1-1.5 mm off
    among 40 UR5 rows of 0.05 mm noise: sigma 0.27 mm, none flagged). Returns (x, levels)."""
    found = levels
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL))
    for _ in range(ROBUST_CHECK_ITERATIONS):
        x = levenberg_marquardt(at_levels(problem, found, loss="huber"), x, "pose", options, trace).x
        if all(g is not None for g in given):
            break
        rows = keep if judged is None else judged
        share = rows.sum() / keep.sum()
        again = _levels(everything, x, rows, tuple(r * share for r in red), given, found)
        settled = max(abs(a / b - 1.0) for a, b in zip(again, found)) < 0.1
        found = again
        if settled:
            break
    return x, found


def _fit_covariance(everything: Problem, x: np.ndarray, fitted: np.ndarray, levels: Sequence[float]):
    """The normal equations at x of the least-squares fit of the rows ``fitted`` (whitened at
    the noise levels given) and its covariance C."""
    pr = at_levels(everything, levels, loss="linear")
    ne = pr.derived(keep=fitted).normal_equations(x)
    return pr, ne, normal_inverse(ne.A)[0]


def _fit_redundancy(everything: Problem, x: np.ndarray, fitted: np.ndarray,
                    levels: Sequence[float]) -> tuple[float, ...]:
    """Each group's redundancy in the least-squares fit at x of the rows ``fitted`` (its
    components less its share of the parameters, tr(C A_group)), at least 1."""
    _, ne, C = _fit_covariance(everything, x, fitted, levels)
    out = []
    for g in GROUPS[:len(levels)]:
        A_g, _, n_g = ne.share(g)
        out.append(max(n_g - float(np.sum(C * A_g)) if A_g is not None else 0.0, 1.0))
    return tuple(out)


def _prediction_spread(everything: Problem, x: np.ndarray, fitted: np.ndarray, levels: Sequence[float],
                       judged: np.ndarray) -> np.ndarray:
    """(N,) each row's expected residual RMS per component in sigma at x, the least-squares fit
    of the rows ``fitted``: 1 for those, sqrt(1 + tr(Jw_i C Jw_i^T) / k) for the others, C the
    fit's covariance (whitened at the noise levels given): a fit of 8 of 15 full-pose rows of a
    6-axis arm (30 parameters) predicts the other 7 to 2-12 sigma, and judged by the noise alone
    they were flagged as gross. judged : (N,) bool, the rows whose spread is asked (1 for the
    others too when every one of them was fitted: nothing to compute)."""
    if not np.any(judged & ~fitted):
        return np.ones(len(fitted))
    pr, _, C = _fit_covariance(everything, x, fitted, levels)
    out = np.ones(len(fitted))
    if isinstance(pr, BlockProblem):
        for rows, _, Jw, _ in pr.row_blocks(x):
            out[rows] = np.sqrt(1.0 + np.einsum("nkm,ml,nkl->n", Jw, C, Jw) / Jw.shape[1])
        return np.where(fitted, 1.0, out)
    start = 0
    for _, Jw in pr.whitened_blocks(x):
        h = np.einsum("nkm,ml,nkl->n", Jw, C, Jw) / Jw.shape[1]
        out[start:start + len(Jw)] = np.sqrt(1.0 + h)
        start += len(Jw)
    return np.where(fitted, 1.0, out)


def _judged(everything, x_t, inliers, levels, ctx, fitted=None):
    """Noise levels from the inliers' residuals at x_t, the rows flagged against them, the rows
    not flagged (see :func:`_judge_trimmed`; ctx: its (keep, rows, k, given, red, n, last_red)).
    fitted : None (x_t a trimmed fit: the fit's share of each group's degrees of freedom kept as
    on all the kept rows), or x_t is the least-squares fit of the rows ``fitted`` (their own
    redundancy, and a row it did not see judged by its noise and the fit's prediction error: 8
    of 15 full-pose rows of 30 parameters left 0.4 of a position redundancy scaled from all the
    rows, the noise came out at a tenth of the truth and the 7 other clean rows were flagged)."""
    keep, rows, k, given, red, n, last_red = ctx
    if fitted is None:
        share = inliers.sum() / n
        levels = _levels(everything, x_t, inliers, tuple(r * share for r in red), given, levels)
        spread = None
    else:
        red_fit = _fit_redundancy(everything, x_t, fitted, levels)
        last_red[0] = red_fit
        levels = _levels(everything, x_t, fitted, red_fit, given, levels)
        spread = _prediction_spread(everything, x_t, fitted, levels, keep)
    new, too_many = flag_outliers(everything, x_t, rows, keep, k, levels, TRIMMED_MAX_OUTLIER_SHARE, spread=spread)
    return levels, new, too_many, keep & ~np.isin(rows, [o.row for o in new])


def _judge_trimmed(everything, problem, x, keep, rows, k, levels, given, red, options, trace) -> Judgement:
    """The rows judged against a high-breakdown fit from x (MM-style): the trimmed fit (the half
    of the rows it explains best), noise levels from the residuals of the rows it does not flag
    (re-taken until that set settles: the median over every row sits high when the gross ones
    are many), then the least-squares fit of the rows it does not flag at those levels, every
    row judged again against it (the trimmed fit fits a third of the rows: its predictions for
    the others scatter more than the noise)."""
    start_levels = levels
    # (it judges rows; its fits stop before a last step whose predicted decrease is below ftol,
    # at the point whose normal equations are at hand: that step's Jacobian pass served nothing,
    # the steps rank the rows by a residual pass of all of them)
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL), last_step=False)
    starts = (x, everything.values[everything.free])    # (the fit's solution, the nominal values)
    if isinstance(everything, BlockProblem):
        # (with the blocks' unknowns: x's, then fitted robustly at x's robot; a point's rows at two
        # nests leave x's point between them, where no half of the rows lies)
        nominal = np.concatenate([starts[1], x[len(starts[1]):]])
        starts = (x, nominal, everything.robust_start(x))
    x_t = trimmed_fit(at_levels(everything, levels), starts, keep, levels, options, trace)
    n = keep.sum()
    last_red = [None]       # the redundancy of the last least-squares refit of the inliers
    ctx = (keep, rows, k, given, red, n, last_red)
    # the noise levels first from the rows the trimmed fit fits (its h best rows, of each stratum),
    # then from the rows within k sigma of it, until that set settles (issue 39): taken from every
    # kept row they sat in the gross rows where those are more than half (55 of 100 full-pose rows
    # 5 mm off: 1.4 mm where the others agree to 0.05 mm, nothing flagged), and the data were not
    # refused
    rms = np.where(keep, row_rms(everything, x_t, levels)[0], np.inf)
    inliers = best_rows_of(everything, rms, keep, trim_size(everything, keep, len(x)))
    for _ in range(ROBUST_CHECK_ITERATIONS + 3):
        levels, new, too_many, now = _judged(everything, x_t, inliers, levels, ctx)
        if np.array_equal(now, inliers):
            break
        inliers = now
    for _ in range(ROBUST_CHECK_ITERATIONS if not too_many else 0):
        # the least-squares fit of the rows it does not flag (the trimmed fit fits half of the
        # rows: its predictions for the others scatter more than the noise, and would flag
        # good rows among few), every row judged again against it (a Huber fit from the
        # trimmed solution is dragged away by 40 % gross rows)
        # (from x when the rows are all the kept ones: x is their least-squares fit at the fit's
        # noise levels, nearer than the trimmed fit of a third of them)
        start = x if np.array_equal(inliers, keep) else x_t        # (near: a re-fit's damping)
        x_t = levenberg_marquardt(at_levels(everything, levels, keep=inliers), start, "pose",
                                  options_with(options, mu0=min(options.mu0, WARM_MU0)), trace).x
        levels, new, too_many, now = _judged(everything, x_t, inliers, levels, ctx, inliers)
        if too_many or np.array_equal(now, inliers):
            break
        inliers = now
    if new and not too_many and last_red[0] is not None and _little_redundancy(everything, last_red[0], inliers):
        # the rows the trimmed route keeps leave too little position redundancy to say what the
        # noise is (15 full-pose UR5 rows, 30 parameters: 8 rows kept, interpolated to a noise a
        # tenth of the truth, and the 7 clean others flagged): its flags are not trusted, the
        # rows are judged against the fit of them all
        new0, too_many0 = flag_outliers(everything, x, rows, keep, k, start_levels)
        return Judgement(tuple(new0), too_many0, x, start_levels)
    if too_many and _all_estimated(everything, given):
        why = inconsistent_rows(len(new), int(n), k, _levels_text(everything, levels),
                                _levels_text(everything, levels_of(problem)))
        return Judgement((), True, x, levels, trimmed=True, breakdown=why)
    return Judgement(tuple(new), too_many, x_t if (new and not too_many) else x, levels, trimmed=True)


def _little_redundancy(everything, red_fit: tuple[float, ...], inliers: np.ndarray) -> bool:
    """Whether the least-squares refit of the ``inliers`` leaves less than
    TRIM_MIN_REDUNDANCY_SHARE of their components (pose rows: of their position components) as
    redundancy (red_fit: its redundancy per group)."""
    if isinstance(everything, BlockProblem):
        red = sum(red_fit[GROUPS.index(g)] for g in everything.groups)
        return red < TRIM_MIN_BLOCKS_REDUNDANCY_SHARE * components(everything, inliers)
    return red_fit[0] < TRIM_MIN_REDUNDANCY_SHARE * 3 * int(inliers.sum())


def _all_estimated(everything, given) -> bool:
    """Whether every noise level of the problem's groups is estimated (none given)."""
    if isinstance(everything, BlockProblem):
        return all(given[GROUPS.index(g)] is None for g in everything.groups)
    return given[0] is None and (given[1] is None or not everything.has_orientation)


def _levels_text(everything, levels) -> str:
    """The noise levels of the problem's groups for a person (mm, rad)."""
    if isinstance(everything, BlockProblem):
        unit = {"position": ("mm", 1e3), "rotation": ("rad", 1.0), "touch": ("mm", 1e3)}
        return ", ".join(f"{g} {levels[GROUPS.index(g)] * unit[g][1]:.3g} {unit[g][0]}" for g in everything.groups)
    return f"{levels[0] * 1e3:.3g} mm" + (f", {levels[1]:.3g} rad" if everything.has_orientation else "")



@dataclass(frozen=True)
class Tails:
    """The residuals of a least-squares fit after the outlier check, as the data-consistency rule
    (:mod:`calib.calibration.plausibility`) reads them: ratios : (group, the noise level estimated
    from the residuals over the robust one, 1.4826 MAD) of the groups whose level is estimated;
    kurtosis : (group, the kurtosis of the whitened residual components, 3 for normal noise);
    rows : the rows kept; beyond : how many of them lie beyond k sigma of the fit of the rows
    that agree best (those the high-breakdown check flagged), None when it did not judge them."""

    ratios: tuple[tuple[str, float], ...]
    kurtosis: tuple[tuple[str, float], ...]
    rows: int
    k: float
    beyond: int | None = None

    @property
    def heavy(self) -> bool:
        """Whether a group's least-squares noise level is more than ROBUST_CHECK_INFLATION times
        the robust one: the tails the outlier check judges against the high-breakdown fit."""
        return any(r > ROBUST_CHECK_INFLATION for _, r in self.ratios)

    def note(self) -> str:
        """The rule's note on heavy but consistent tails ("" when they are not heavy)."""
        if not self.heavy:
            return ""
        return heavy_tails_note(self.ratios, self.kurtosis, self.rows, self.beyond or 0, self.k)


def _group_residuals(everything, x: np.ndarray, keep: np.ndarray) -> dict:
    """GROUPS name -> the unweighted residual components (m or rad) of the rows ``keep`` at x."""
    if isinstance(everything, BlockProblem):
        return everything.group_residuals(x, keep)
    dp, dr = everything.pose_residuals(x)
    return {"position": dp[keep].ravel(), **({} if dr is None else {"rotation": dr[keep].ravel()})}


def leftover_gross(everything: Problem, x: np.ndarray, keep: np.ndarray, red: tuple[float, ...],
                   levels: tuple[float, ...], given: tuple[float | None, ...], k: float) -> Tails:
    """The :class:`Tails` of the least-squares fit at x of the kept rows after the outlier check:
    its estimated noise levels ``levels`` (see :func:`levels_of`) over the robust ones (the median
    absolute residual; red : the fit's redundancy of each group), the kurtosis of the whitened
    residual components of each group. A ratio above ROBUST_CHECK_INFLATION was refused as "many
    rows gross by amounts the check cannot separate" until issue 39, and refused honest data
    (Student-t noise: 10 % of simulated calibrations; real tracker sets): heavy tails are judged
    by the high-breakdown check instead, which refuses only more than half of the rows far from
    the fit of the others. given : the noise levels the user gave (None: estimated; given levels
    are judged by the chi-square test); k : the outlier threshold."""
    names = {"position": "position", "rotation": "orientation", "touch": "touch"}
    robust = robust_sigmas(everything, x, keep, red)
    ratios, kurt = [], []
    for g, r in _group_residuals(everything, x, keep).items():
        i = GROUPS.index(g)
        if given[i] is not None or not len(r):
            continue
        ratios.append((names[g], levels[i] / robust[i]))
        z = r / levels[i]
        m2 = float(np.mean(z ** 2))
        kurt.append((names[g], float(np.mean(z ** 4)) / max(m2 * m2, 1e-300)))
    return Tails(tuple(ratios), tuple(kurt), int(keep.sum()), k)
