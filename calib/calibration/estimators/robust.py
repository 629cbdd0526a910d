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
refuses the result (status "implausible"). scripts/accept_gross_rows.py measures it all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.calibration.consistency import heavy_tails_note, inconsistent_rows, too_many_flagged
from calib.calibration.frames import median
from calib.calibration.options import (
    ROBUST_CHECK_FTOL,
    ROBUST_CHECK_INFLATION,
    ROBUST_CHECK_ITERATIONS,
    TRIMMED_FIT_STEPS,
    TRIMMED_MAX_OUTLIER_SHARE,
    WARM_MU0,
)
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
    sigma_pos: float
    sigma_rot: float
    trimmed: bool = False
    breakdown: str = ""


def row_rms(problem: Problem, x: np.ndarray, sigma_pos: float, sigma_rot: float):
    """Each row's whitened residual RMS per component, its position residuals (N, 3) metres and
    the norm of its rotation residual (radians; NaN without orientation data)."""
    dp, dr = problem.pose_residuals(x)
    blocks = [dp / sigma_pos]
    rot = np.full(len(dp), np.nan)
    if dr is not None:
        blocks.append(dr / sigma_rot)
        rot = np.linalg.norm(dr, axis=1)
    w = np.concatenate(blocks, axis=1)
    return np.sqrt(np.mean(w ** 2, axis=1)), dp, rot


def flag_outliers(problem: Problem, x: np.ndarray, rows: np.ndarray, keep: np.ndarray, k: float,
                  sigma_pos: float, sigma_rot: float, max_share: float = 0.25,
                  spread: np.ndarray | None = None) -> tuple[list[Outlier], bool]:
    """Rows still kept whose whitened residual RMS per component exceeds k (with the given noise
    levels), and whether they are too many (more than ``max_share`` of the kept rows) to be
    outliers. ``problem`` holds all calibration rows; rows : their line numbers; spread : (N,)
    each row's residual RMS expected from noise, in sigma (default 1: rows the fit saw; a row
    predicted by a fit of other rows errs by its noise and the fit's prediction error)."""
    rms, dp, rot = row_rms(problem, x, sigma_pos, sigma_rot)
    bad = np.flatnonzero(keep & (rms > k * (1.0 if spread is None else spread)))
    found = []
    if len(bad):
        from calib.calibration.estimators.outlier import Outlier

        found = [Outlier(int(rows[i]), float(np.linalg.norm(dp[i])), float(rot[i]), float(rms[i])) for i in bad]
    return found, len(bad) > max_share * keep.sum()


def robust_sigmas(problem: Problem, x: np.ndarray, keep: np.ndarray, red_p: float, red_r: float):
    """Noise levels (m, rad) from the median absolute residual component of each group over the
    rows ``keep`` (1.4826 MAD, corrected for the fit's share of the degrees of freedom): what
    outliers cannot inflate. red_p / red_r : each group's redundancy in the fit."""
    dp, dr = problem.pose_residuals(x)
    n = keep.sum()
    f_p = max(red_p / (3 * n), 1e-3)
    sp = 1.4826 * median(np.abs(dp[keep])) / math.sqrt(f_p)
    sr = problem.sigma_rot
    if dr is not None:
        f_r = max(red_r / (3 * n), 1e-3)
        sr = 1.4826 * median(np.abs(dr[keep])) / math.sqrt(f_r)
    return max(sp, 1e-12), max(sr, 1e-12)


def trimmed_fit(problem: Problem, starts: Sequence[np.ndarray], keep: np.ndarray, sigma_pos: float,
                sigma_rot: float, options: LMOptions, trace: LMTrace) -> np.ndarray:
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
    passes fewer per fit on 25 full-pose rows)."""
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL))     # (it ranks rows)
    h = trim_size(problem, keep, len(starts[0]))
    best, best_cost = None, np.inf
    apart = _apart(problem)
    warm = options_with(options, mu0=min(options.mu0, WARM_MU0))
    for i, x in enumerate(starts):
        chosen = None
        for step in range(TRIMMED_FIT_STEPS):
            fitted = best_rows(problem, x, keep, h, sigma_pos, sigma_rot)
            if chosen is not None and np.array_equal(fitted, chosen):
                break
            chosen = fitted
            x = levenberg_marquardt(apart.derived(keep=chosen), x, "pose", warm if (i == 0 or step) else options,
                                    trace).x
        cost = float(np.sum(np.sort(np.where(keep, row_rms(problem, x, sigma_pos, sigma_rot)[0], np.inf))[:h] ** 2))
        if cost < best_cost:
            best, best_cost = x, cost
    return best


def trim_size(problem: Problem, keep: np.ndarray, n_params: int) -> int:
    """The number h of rows the trimmed fit fits (:func:`trimmed_fit`): a third of the kept
    rows, at least twice as many residual components as parameters, at most half of the rows."""
    n = int(keep.sum())
    per_row = 6 if problem.has_orientation else 3
    return min(max(-(-n // 3), -(-2 * n_params // per_row) + 1), (n + 1) // 2)


def best_rows(problem: Problem, x: np.ndarray, keep: np.ndarray, h: int, sigma_pos: float,
              sigma_rot: float) -> np.ndarray:
    """(N,) bool: the h kept rows of smallest whitened residual RMS at x (the rows a trimmed
    fit at x fits)."""
    rms = np.where(keep, row_rms(problem, x, sigma_pos, sigma_rot)[0], np.inf)
    out = np.zeros(len(rms), bool)
    out[np.argsort(rms, kind="stable")[:h]] = True
    return out


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
    per_row = 6 if problem.has_orientation else 3
    return (int(keep.sum()) + 1) // 2 * per_row >= TRIM_MIN_RATIO * n_params


def judge_rows(everything: Problem, problem: Problem, x: np.ndarray, keep: np.ndarray, rows: np.ndarray,
               k: float, *, given: tuple[float | None, float | None], red: tuple[float, float],
               few: bool, first: bool = True, options: LMOptions, trace: LMTrace) -> Judgement:
    """The outlier check of the fit at x (see the module docstring).

    everything : the problem of all calibration rows; problem : the fit's (the kept rows, its
    noise levels and loss); keep : (N,) bool, rows kept; rows : (N,) their line numbers; k : the
    threshold on a row's whitened residual RMS per component; given : the noise levels the user
    gave (m, rad; None: estimated); red : the fit's redundancy (position, rotation); few : the
    rows hold few residual components per parameter; first : no row was flagged yet (few rows
    go to the high-breakdown fit on the first judgement only: once the gross rows are out, a
    trimmed fit of what is left, a third of a few rows, scatters its predictions for the others
    and flagged 12 good rows of 24).
    """
    sp, sr = problem.sigma_pos, problem.sigma_rot
    estimate = given[0] is None or given[1] is None
    fsp, fsr = _levels(everything, x, keep, red, given, sp, sr) if estimate else (sp, sr)
    new, too_many = flag_outliers(everything, x, rows, keep, k, fsp, fsr)
    if problem.loss != "linear":
        return Judgement(tuple(new), too_many, x, fsp, fsr)
    # few rows (a least-squares fit spreads gross rows until none stands out, and the median
    # residual swells with them: 12 of 40 position-only rows 5 mm off, 1.5 mm noise estimated
    # against 0.02 mm), or a least-squares noise level far above the robust one (many gross
    # rows): judged against the high-breakdown fit
    if can_trim(everything, keep, len(x)) and ((few and first)
                                               or (estimate and max(sp / fsp, sr / fsr) > ROBUST_CHECK_INFLATION)):
        return _judge_trimmed(everything, problem, x, keep, rows, k, (fsp, fsr), given, red, options, trace)
    if not new:
        return Judgement(tuple(new), too_many, x, fsp, fsr)
    # a least-squares fit spreads a gross error over its neighbours: judge the rows against a
    # robust (Huber) fit instead, then refit by least squares without them
    x_robust, fsp, fsr = _huber(everything, problem, x, keep, red, given, (fsp, fsr), options, trace)
    new, too_many = flag_outliers(everything, x_robust, rows, keep, k, fsp, fsr)
    return Judgement(tuple(new), too_many, x_robust if (new and not too_many) else x, fsp, fsr)


def _levels(everything, x, rows, red, given, sp, sr):
    """The robust noise levels at x over ``rows`` where they are estimated, the given ones
    (sp, sr) where not; red : the fit's redundancy on ``rows``."""
    rsp, rsr = robust_sigmas(everything, x, rows, *red)
    return (rsp if given[0] is None else sp), (rsr if given[1] is None else sr)


def _huber(everything, problem, x, keep, red, given, levels, options, trace, judged=None):
    """The Huber fit of the kept rows from x at the noise levels ``levels``, with the noise
    levels re-taken from its residuals on the rows ``judged`` (default: the kept rows) and the
    fit repeated (ROBUST_CHECK_ITERATIONS at most,
    until they change by less than 10 %): with several gross rows the first levels, from a
    least-squares fit's smeared residuals, set the threshold near them (5 rows 1-1.5 mm off
    among 40 UR5 rows of 0.05 mm noise: sigma 0.27 mm, none flagged). Returns (x, sp, sr)."""
    fsp, fsr = levels
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL))
    for _ in range(ROBUST_CHECK_ITERATIONS):
        x = levenberg_marquardt(problem.derived(loss="huber", sigma_pos=fsp, sigma_rot=fsr), x, "pose",
                                options, trace).x
        if given[0] is not None and given[1] is not None:
            break
        rows = keep if judged is None else judged
        share = rows.sum() / keep.sum()
        rsp, rsr = _levels(everything, x, rows, (red[0] * share, red[1] * share), given, fsp, fsr)
        settled = max(abs(rsp / fsp - 1.0), abs(rsr / fsr - 1.0)) < 0.1
        fsp, fsr = rsp, rsr
        if settled:
            break
    return x, fsp, fsr


def _fit_covariance(everything: Problem, x: np.ndarray, fitted: np.ndarray, sigma_pos: float, sigma_rot: float):
    """The normal equations at x of the least-squares fit of the rows ``fitted`` (whitened at
    the noise levels given) and its covariance C."""
    pr = everything.derived(sigma_pos=sigma_pos, sigma_rot=sigma_rot, loss="linear")
    ne = pr.derived(keep=fitted).normal_equations(x)
    return pr, ne, normal_inverse(ne.A)[0]


def _fit_redundancy(everything: Problem, x: np.ndarray, fitted: np.ndarray, sigma_pos: float,
                    sigma_rot: float) -> tuple[float, float]:
    """Each group's redundancy in the least-squares fit at x of the rows ``fitted`` (its
    components less its share of the parameters, tr(C A_group)), at least 1."""
    _, ne, C = _fit_covariance(everything, x, fitted, sigma_pos, sigma_rot)
    red_p = ne.n_pos - float(np.sum(C * ne.A_pos)) if ne.A_pos is not None else 0.0
    red_r = ne.n_rot - float(np.sum(C * ne.A_rot)) if ne.A_rot is not None else 0.0
    return max(red_p, 1.0), max(red_r, 1.0)


def _prediction_spread(everything: Problem, x: np.ndarray, fitted: np.ndarray, sigma_pos: float,
                       sigma_rot: float, judged: np.ndarray) -> np.ndarray:
    """(N,) each row's expected residual RMS per component in sigma at x, the least-squares fit
    of the rows ``fitted``: 1 for those, sqrt(1 + tr(Jw_i C Jw_i^T) / k) for the others, C the
    fit's covariance (whitened at the noise levels given): a fit of 8 of 15 full-pose rows of a
    6-axis arm (30 parameters) predicts the other 7 to 2-12 sigma, and judged by the noise alone
    they were flagged as gross. judged : (N,) bool, the rows whose spread is asked (1 for the
    others too when every one of them was fitted: nothing to compute)."""
    if not np.any(judged & ~fitted):
        return np.ones(len(fitted))
    pr, _, C = _fit_covariance(everything, x, fitted, sigma_pos, sigma_rot)
    out, start = np.ones(len(fitted)), 0
    for _, Jw in pr.whitened_blocks(x):
        h = np.einsum("nkm,ml,nkl->n", Jw, C, Jw) / Jw.shape[1]
        out[start:start + len(Jw)] = np.sqrt(1.0 + h)
        start += len(Jw)
    return np.where(fitted, 1.0, out)


def _judge_trimmed(everything, problem, x, keep, rows, k, levels, given, red, options, trace) -> Judgement:
    """The rows judged against a high-breakdown fit from x (MM-style): the trimmed fit (the half
    of the rows it explains best), noise levels from the residuals of the rows it does not flag
    (re-taken until that set settles: the median over every row sits high when the gross ones
    are many), then the least-squares fit of the rows it does not flag at those levels, every
    row judged again against it (the trimmed fit fits a third of the rows: its predictions for
    the others scatter more than the noise)."""
    fsp, fsr = levels
    # (it judges rows; its fits stop before a last step whose predicted decrease is below ftol,
    # at the point whose normal equations are at hand: that step's Jacobian pass served nothing,
    # the steps rank the rows by a residual pass of all of them)
    options = options_with(options, ftol=max(options.ftol, ROBUST_CHECK_FTOL), last_step=False)
    starts = (x, everything.values[everything.free])    # (the fit's solution, the nominal values)
    x_t = trimmed_fit(everything.derived(sigma_pos=fsp, sigma_rot=fsr), starts, keep, fsp, fsr, options, trace)
    inliers, n = keep, keep.sum()
    last_red = [None]       # the position redundancy of the last least-squares refit of the inliers

    def judged(x_t, inliers, fsp, fsr, fitted=None):
        """Noise levels from the inliers' residuals at x_t, the rows flagged against them, the
        rows not flagged. fitted : None (x_t a trimmed fit: the fit's share of each group's
        degrees of freedom kept as on all the kept rows), or x_t is the least-squares fit of
        the rows ``fitted`` (their own redundancy, and a row it did not see judged by its noise
        and the fit's prediction error: 8 of 15 full-pose rows of 30 parameters left 0.4 of a
        position redundancy scaled from all the rows, the noise came out at a tenth of the
        truth and the 7 other clean rows were flagged)."""
        if fitted is None:
            share = inliers.sum() / n
            fsp, fsr = _levels(everything, x_t, inliers, (red[0] * share, red[1] * share), given, fsp, fsr)
            spread = None
        else:
            red_fit = _fit_redundancy(everything, x_t, fitted, fsp, fsr)
            last_red[0] = red_fit[0]
            fsp, fsr = _levels(everything, x_t, fitted, red_fit, given, fsp, fsr)
            spread = _prediction_spread(everything, x_t, fitted, fsp, fsr, keep)
        new, too_many = flag_outliers(everything, x_t, rows, keep, k, fsp, fsr, TRIMMED_MAX_OUTLIER_SHARE,
                                      spread=spread)
        return fsp, fsr, new, too_many, keep & ~np.isin(rows, [o.row for o in new])

    # the noise levels first from the rows the trimmed fit fits (its h best rows), then from the
    # rows within k sigma of it, until that set settles: taken from every kept row they sat in
    # the gross rows where those are more than half (55 of 100 full-pose rows 5 mm off: 1.4 mm
    # where the others agree to 0.05 mm, nothing flagged), and the data were not refused
    inliers = best_rows(everything, x_t, keep, trim_size(everything, keep, len(x)), fsp, fsr)
    for _ in range(ROBUST_CHECK_ITERATIONS + 3):
        fsp, fsr, new, too_many, now = judged(x_t, inliers, fsp, fsr)
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
        x_t = levenberg_marquardt(everything.derived(keep=inliers, sigma_pos=fsp, sigma_rot=fsr), start, "pose",
                                  options_with(options, mu0=min(options.mu0, WARM_MU0)), trace).x
        fsp, fsr, new, too_many, now = judged(x_t, inliers, fsp, fsr, inliers)
        if too_many or np.array_equal(now, inliers):
            break
        inliers = now
    if new and not too_many and last_red[0] is not None \
            and last_red[0] < TRIM_MIN_REDUNDANCY_SHARE * 3 * int(inliers.sum()):
        # the rows the trimmed route keeps leave too little position redundancy to say what the
        # noise is (15 full-pose UR5 rows, 30 parameters: 8 rows kept, interpolated to a noise a
        # tenth of the truth, and the 7 clean others flagged): its flags are not trusted, the
        # rows are judged against the fit of them all
        new0, too_many0 = flag_outliers(everything, x, rows, keep, k, *levels)
        return Judgement(tuple(new0), too_many0, x, *levels)
    if too_many and given[0] is None and (given[1] is None or not everything.has_orientation):
        rot = everything.has_orientation
        why = inconsistent_rows(len(new), int(n), k, (fsp, fsr if rot else None),
                                (problem.sigma_pos, problem.sigma_rot if rot else None))
        return Judgement((), True, x, fsp, fsr, trimmed=True, breakdown=why)
    return Judgement(tuple(new), too_many, x_t if (new and not too_many) else x, fsp, fsr, trimmed=True)


def too_many_gross(flagged: int, rows: int) -> str:
    """Why the data are refused when the outlier passes together flag more than
    TRIMMED_MAX_OUTLIER_SHARE of the calibration rows (each pass judges only the rows kept by
    the last: 16 gross of 40 position-only rows, then 18 good ones, left 6 rows fitted
    exactly): :func:`calib.calibration.consistency.too_many_flagged`."""
    return too_many_flagged(flagged, rows)


@dataclass(frozen=True)
class Tails:
    """The residuals of a least-squares fit after the outlier check, as the data-consistency rule
    (:mod:`calib.calibration.consistency`) reads them: ratios : (group, the noise level estimated
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


def leftover_gross(everything: Problem, x: np.ndarray, keep: np.ndarray, red: tuple[float, float],
                   levels: tuple[float, float], given: tuple[float | None, float | None], k: float) -> Tails:
    """The :class:`Tails` of the least-squares fit at x of the kept rows after the outlier check:
    its estimated noise levels ``levels`` (m, rad) over the robust ones (the median absolute
    residual; red : the fit's redundancy of each group), the kurtosis of the whitened residual
    components. A ratio above ROBUST_CHECK_INFLATION was refused as "many rows gross by amounts
    the check cannot separate" until issue 39, and refused honest data (Student-t noise: 10 % of
    simulated calibrations; real tracker sets): heavy tails are judged by the high-breakdown
    check instead, which refuses only more than half of the rows far from the fit of the others.
    given : the noise levels the user gave (None: estimated; given levels are judged by the
    chi-square test); k : the outlier threshold."""
    rsp, rsr = robust_sigmas(everything, x, keep, *red)
    dp, dr = everything.pose_residuals(x)
    groups = [("position", levels[0], rsp, dp[keep] / levels[0], given[0])]
    if dr is not None:
        groups.append(("orientation", levels[1], rsr, dr[keep] / levels[1], given[1]))
    ratios, kurt = [], []
    for g, lvl, robust, z, giv in groups:
        if giv is None:
            ratios.append((g, lvl / robust))
            m2 = float(np.mean(z ** 2))
            kurt.append((g, float(np.mean(z ** 4)) / max(m2 * m2, 1e-300)))
    return Tails(tuple(ratios), tuple(kurt), int(keep.sum()), k)
