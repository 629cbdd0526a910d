"""The fit stage (:class:`Fit`): the noise-weighted identification, variance-component estimation of
the noise levels (:class:`NoiseEstimate`), and the outlier check (:class:`~calib.calibration.outlier.Outlier`).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import field, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.dataclass_code import dataclass
from calib.calibration.accuracy import AccuracyStats, target_rows
from calib.calibration.options import (
    LOCAL_MINIMUM_RATIO,
    ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM,
    STEP_START_MU0,
    TRIMMED_MAX_OUTLIER_SHARE,
    VCE_FIRST_FTOL,
    VCE_MAX_ITERATIONS,
    VCE_RTOL,
    WARM_MU0,
    CalibrationOptions,
)
from calib.calibration.plausibility import leftover_gross, too_many_gross
from calib.calibration.prepare import Setup
from calib.calibration.robust import can_trim, flag_outliers, judge_rows, robust_sigmas
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.solvers import dispatch
from calib.solvers.angles import RotationChain
from calib.solvers.lm import LMOptions, LMTrace, SolverResult, options_with
from calib.solvers.inverse import normal_inverse
from calib.solvers.problem import NormalEquations, Problem

if TYPE_CHECKING:      # (built when the outlier check flags rows)
    from calib.calibration.outlier import Outlier

log = logging.getLogger(__name__)


# ====================================================================== stage objects
@dataclass(frozen=True)
class NoiseEstimate:
    """Measurement noise per axis used to weight the fit, and how well the residuals agree.

    position (m) and rotation (rad, None for position-only data); estimated : True when they come
    from the residuals (variance-component estimation), False when given. redundancy_pos / _rot :
    degrees of freedom of each group (its residual components minus its share of the rank of the
    Jacobian); chi2_pos / chi2_rot : the group's weighted residual sum of squares divided by its
    redundancy (1 when the noise level matches); chi2, dof, p_value : the chi-square test of the
    whole fit (p_value the two-sided probability of a chi-square at least this far from its
    expectation if the noise levels were right; None when they were estimated). iterations : re-weighted fits of the estimation.
    """

    position: float
    rotation: float | None
    estimated: bool
    redundancy_pos: float
    redundancy_rot: float
    chi2_pos: float
    chi2_rot: float | None
    chi2: float
    dof: float
    iterations: int

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.dof, 1e-300)

    @property
    def p_value(self) -> float | None:
        """The chi-square test's two-sided p-value (None when the noise levels were estimated),
        computed when asked: a report needs it, the fit does not (scipy.special, imported only
        then, costs 0.3 s; scipy.stats seconds)."""
        if self.estimated:
            return None
        return _chi2_p_value(self.chi2, self.dof)

    def to_dict(self) -> dict:
        return {"position_mm": self.position * 1e3, "rotation_rad": self.rotation,
                "estimated": self.estimated, "iterations": self.iterations,
                "reduced_chi2": self.reduced_chi2, "dof": self.dof,
                "chi2_test": None if self.estimated else {
                    "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                    "reduced_chi2_position": self.chi2_pos, "reduced_chi2_rotation": self.chi2_rot}}


@dataclass(frozen=True, eq=False, repr=False)     # (a model and arrays: nothing compares or prints it)
class Fit:
    """The fit stage: the identified model and how it was reached.

    model : the calibrated model; free : names of the identified parameters; solver : the
    solver's result for the last fit (x, cost in the final noise weights, status, message, ...);
    keep : (N_cal,) bool, rows used (False for outliers); outliers; noise : the weights used and
    the residuals' agreement with them; iterations : LM iterations of every fit in the stage;
    covariance : (n_free, n_free) covariance of the free parameters (SI units) in the final noise
    weights, from the least-squares normal equations at the solution; full_rank : False when it
    is a pseudo-inverse (for a regularised fit: the posterior covariance); all_rows : the problem
    of every calibration row, kept or not; unremoved : rows whose residuals exceeded the outlier
    threshold but were kept, being too many to be outliers (the fit's note says so); refusals :
    why the fit stage found the data inconsistent (gross rows beyond the outlier check's
    breakdown point), which :func:`implausibility` reports first.
    """

    model: RobotModel
    free: tuple[str, ...]
    solver: SolverResult
    keep: np.ndarray = field(repr=False)
    outliers: tuple[Outlier, ...]
    noise: NoiseEstimate
    iterations: int
    covariance: np.ndarray = field(repr=False)
    full_rank: bool
    all_rows: Problem = field(repr=False, compare=False)
    notes: tuple[str, ...] = ()
    unremoved: tuple[Outlier, ...] = ()
    refusals: tuple[str, ...] = ()
    #: A regularised fit's Gaussian prior on the free parameters (:mod:`calib.calibration.
    #: regularised`): precision (n_free,) in the weighted problem's units (1 / unit^2; 0: flat)
    #: and mean (n_free,); None for least squares. Refits (cross-validation) keep it.
    prior_precision: np.ndarray | None = field(default=None, repr=False)
    prior_mean: np.ndarray | None = field(default=None, repr=False)

    @property
    def errors(self) -> AccuracyStats:
        """The calibrated model's errors on every calibration row (outliers included); the fit's
        outlier check has computed them at the solution."""
        return AccuracyStats.from_residuals(*self.all_rows.pose_residuals(self.solver.x))


# ---------------------------------------------------------------- fit
@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class _Linearised:
    """The least-squares normal equations ``ne`` of a problem's rows at a solution, their
    (pseudo-)inverse ``inverse`` (the covariance of the free parameters, SI units; ``full_rank``
    False for a pseudo-inverse) and each group's redundancy: its number of residual components
    minus its share tr(A^-1 A_g) of the rank."""

    ne: NormalEquations
    inverse: np.ndarray
    full_rank: bool
    red_pos: float
    red_rot: float


def _linearised(problem: Problem, x: np.ndarray) -> _Linearised:
    """The :class:`_Linearised` of ``problem``'s rows at x (least squares whatever its loss)."""
    ne = problem.derived(loss="linear").normal_equations(x)
    Ainv, full_rank = normal_inverse(ne.A)
    share_p = float(np.trace(Ainv @ ne.A_pos)) if ne.A_pos is not None else 0.0
    share_r = float(np.trace(Ainv @ ne.A_rot)) if ne.A_rot is not None else 0.0
    return _Linearised(ne, Ainv, full_rank, ne.n_pos - share_p, ne.n_rot - share_r)


def _vce_fixed_point(ne: NormalEquations, sigmas: tuple[float, float], start: tuple[float, float],
                     free: tuple[bool, bool], max_iterations: int = 50) -> tuple[float, float]:
    """The noise levels (sigma_pos m, sigma_rot rad) at which variance-component estimation
    stops, found on the least-squares normal equations ``ne`` of pose rows weighted by
    ``sigmas``, from the levels ``start`` their residuals give: for trial levels, the
    Gauss-Newton solution of the linearised problem, each group's residual sum of squares and
    redundancy there and the levels they give, repeated until they change by less than
    VCE_RTOL / 100 (``free``: which levels are estimated; a given one stays). Exact for a model
    linear in its parameters: the fit re-solved at these levels confirms them, where each
    re-weighted fit would otherwise move them one step of the estimation (a few passes of LM over
    the data each). ``start`` when ``ne`` does not split its gradient by group."""
    if ne.g_pos is None or ne.A_pos is None or ne.A_rot is None:
        return start
    (sp0, sr0), (sp, sr) = sigmas, start
    g_rot = ne.g - ne.g_pos
    for _ in range(max_iterations):
        f_p, f_r = (sp0 / sp) ** 2, (sr0 / sr) ** 2
        Ainv, _ = normal_inverse(f_p * ne.A_pos + f_r * ne.A_rot)
        dx = -Ainv @ (f_p * ne.g_pos + f_r * g_rot)
        rss_p = ne.rss_pos + 2.0 * ne.g_pos @ dx + dx @ ne.A_pos @ dx     # (at the weights sigmas)
        rss_r = ne.rss_rot + 2.0 * g_rot @ dx + dx @ ne.A_rot @ dx
        red_p = ne.n_pos - f_p * float(np.sum(Ainv * ne.A_pos))       # (tr(Ainv A_pos): both symmetric)
        red_r = ne.n_rot - f_r * float(np.sum(Ainv * ne.A_rot))
        if min(red_p, red_r) <= 0.5 or min(rss_p, rss_r) <= 0.0:
            return start                 # (nothing to estimate from: the loop's own rule decides)
        new_p = sp0 * math.sqrt(rss_p / red_p) if free[0] else sp
        new_r = sr0 * math.sqrt(rss_r / red_r) if free[1] else sr
        change = max(abs(new_p / sp - 1.0), abs(new_r / sr - 1.0))
        sp, sr = max(new_p, 1e-12), max(new_r, 1e-12)
        if change < VCE_RTOL / 100:
            return sp, sr
    return start


def _noise_estimate(problem: Problem, lin: _Linearised, estimated: bool, iterations: int) -> NoiseEstimate:
    """The noise levels of ``problem`` and the residuals' agreement with them, from its
    linearisation ``lin`` at the solution."""
    ne, red_p, red_r = lin.ne, lin.red_pos, lin.red_rot
    dof = red_p + red_r
    chi2 = ne.rss_pos + ne.rss_rot
    has_rot = problem.has_orientation
    return NoiseEstimate(problem.sigma_pos, problem.sigma_rot if has_rot else None, estimated,
                         red_p, red_r, ne.rss_pos / max(red_p, 1e-300),
                         ne.rss_rot / max(red_r, 1e-300) if has_rot else None, chi2, dof, iterations)


def _chi2_p_value(chi2: float, dof: float) -> float:
    """Two-sided p-value of a chi-square ``chi2`` with ``dof`` degrees of freedom: residuals far
    below the given noise disagree with it as much as far above (scipy.special's regularised
    incomplete gamma functions: scipy.stats costs seconds to import)."""
    from scipy.special import gammainc, gammaincc

    k = max(dof, 1e-9) / 2.0
    return float(min(1.0, 2.0 * min(gammaincc(k, chi2 / 2.0), gammainc(k, chi2 / 2.0))))


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Solver:
    """How the fit stage solves: method, options, and the search-lm ingredients."""

    method: str
    measure: str
    options: LMOptions
    max_rounds: int
    fixed_rounds: int | None
    angular: np.ndarray
    chain: RotationChain | None
    model: RobotModel
    lm_variant: str = "calib"

    def __call__(self, problem: Problem, x: np.ndarray, trace: LMTrace, first: bool, *,
                 loose: bool = False, mu0: float = WARM_MU0) -> SolverResult:
        """The first fit (``first``: the method's own scheme) or a re-fit from a near solution
        (LM started with damping ``mu0``, at most the options'); ``loose``: stop at
        VCE_FIRST_FTOL (calib's LM only)."""
        if self.lm_variant == "paper":
            return self._paper(problem, x, trace)
        opts = self.options
        if loose:   # (stopping at its last evaluated point, whose normal equations the estimate uses)
            opts = options_with(opts, ftol=max(opts.ftol, VCE_FIRST_FTOL), last_step=False)
        if not first:
            return dispatch.solve(problem, x, "lm", options=options_with(opts, mu0=min(opts.mu0, mu0)), trace=trace)
        method = "lm" if self.measure == "position" else self.method
        return dispatch.solve(problem, x, method, angular=self.angular, chain=self.chain, options=opts,
                              trace=trace, max_rounds=self.max_rounds, fixed_rounds=self.fixed_rounds)

    def _paper(self, problem: Problem, x: np.ndarray, trace: LMTrace) -> SolverResult:
        """The LM of Eq. (27)-(28) as printed (:mod:`calib.solvers.paper_lm`): unweighted residuals in mm
        and rad, so the noise levels do not change its solution; its cost is re-expressed in the
        fit's noise weights."""
        from calib.solvers.paper_lm import PaperLMOptions

        popts = PaperLMOptions(max_iterations=self.options.max_iterations)
        method = "c-lm" if (self.method == "c-lm" and self.measure == "pose") else "lm"
        r = dispatch.solve(problem, x, method, angular=self.angular, variant="paper", paper_options=popts,
                           max_rounds=self.max_rounds, fixed_rounds=self.fixed_rounds)
        trace.iterations += r.iterations
        cost = 0.5 * float(np.sum(problem.residuals(r.x) ** 2))
        return SolverResult(r.x, cost, r.status, f"paper's LM as printed: {r.message}", r.iterations,
                            max(r.rounds, 1))


def solver_for(setup: Setup, free: Sequence[str], method: str, options: LMOptions, max_rounds: int,
                fixed_rounds: int | None, lm_variant: str = "calib") -> Solver:
    """The :class:`Solver` of the fit stage for the free parameters ``free`` of ``setup``'s start
    model: ``method`` run as LM for several targets (the angle search takes one tool frame), the
    angle search's rotation chain for search-lm on pose data."""
    idx = setup.start.indices(free)
    angular = np.array([setup.start.parameters[k].is_angular for k in idx], bool)
    if method == "search-lm" and setup.start.targets:
        method = "lm"       # the angle search takes one tool frame (a note says so)
    chain = RotationChain(setup.start) if (method == "search-lm" and setup.measure == "pose") else None
    return Solver(method, setup.measure, options, max_rounds, fixed_rounds, angular, chain, setup.start,
                  lm_variant)


def fit_stage(setup: Setup, free: Sequence[str], solve: Solver, *, sigma_pos: float | None,
              sigma_rot: float | None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0, keep: np.ndarray | None = None,
              kin: ChainKinematics | None = None, rank_deficit: int = 0,
              warm: bool = False, refit: bool = True) -> tuple[Fit, Problem]:
    """The fit stage: identify ``free`` on the calibration rows of ``setup``.

    sigma_pos (m) / sigma_rot (rad): the noise per axis, or None to estimate it from the residuals
    (variance-component estimation: each group's weight is re-set to its weighted residual sum of
    squares over its redundancy, and the fit repeated, until both change by less than VCE_RTOL).
    With ``outlier_k``, rows whose whitened residual RMS exceeds it (judged against a robust fit,
    with noise levels that outliers cannot inflate) are removed and the fit repeated.
    rank_deficit : how many directions ``free`` leaves undetermined at the nominal model on these
    rows (0 for an identifiable set; see :meth:`calib.solvers.problem.Problem.set_rank_deficit`).
    warm : ``setup.start`` is already near the solution (a Gauss-Newton step of the same model:
    the joint terms' chosen model): LM from it with damping STEP_START_MU0, not the method's scheme
    from a nominal start.
    refit : False for a fit that is a means (the noise levels, the rows kept and a point near the
    solution: the joint terms' choice): once the outlier check removed rows, the rows now kept
    (the frame estimate's suspect rows judged there), at the robust fit's solution, are its
    result, without the least-squares re-fit and the check again (the choice's candidates are
    Gauss-Newton steps from there; calibrate's own fit judges the rows again), nor the check for
    gross rows left over. Its Fit is then not a least-squares solution: the status is the
    least-squares fit's before the check (the message says so), the noise levels (re-estimated
    from a linearisation there for pose data), the noise estimate and covariance are those at
    the robust solution.
    Returns the :class:`Fit` and the final weighted problem on the kept rows.
    """
    cal, start = setup.cal, setup.start
    kin = kin or ChainKinematics(start)
    free = tuple(free)
    idx = start.indices(free)
    estimate = sigma_pos is None or sigma_rot is None
    sp = SIGMA_POS_M if sigma_pos is None else sigma_pos
    sr = SIGMA_ROT_RAD if sigma_rot is None else sigma_rot
    everything = Problem(kin, cal.q, cal.position, cal.rotation, start.values, idx, sp, sr, loss, loss_scale,
                         targets=target_rows(start, cal))
    everything.set_rank_deficit(rank_deficit)     # (of the set at the nominal model, these rows)
    suspect = None
    if keep is None:
        keep = np.ones(cal.n_poses, bool)
        if setup.suspect is not None and outlier_k is not None:
            # rows the frame estimate found gross would drag the first fit far from the others'
            # solution: start without them, take back below those the fitted model explains
            suspect = setup.suspect.copy()
            keep &= ~suspect
    else:
        keep = keep.copy()
    trace = LMTrace()
    x = start.values[idx]
    outliers: list[Outlier] = []
    notes: list[str] = []
    refusals: list[str] = []
    first = not warm
    start_mu0 = STEP_START_MU0 if warm else WARM_MU0      # (the first solve's damping, when not first)
    stuck = None
    # (a warm start comes from a fit of the geometry, which may itself have stopped in a local
    # minimum: the warm fit's first converged solution is judged as a first fit's is)
    unjudged = warm
    unremoved: tuple[Outlier, ...] = ()
    vce_total = 0
    two_groups = setup.measure == "pose"
    # the levels where the estimation stops, from one linearisation (_vce_fixed_point): a re-fit
    # that follows the weights confirms them; the paper's LM as printed ignores the weights, and
    # the estimation then ran to its limit of re-fits, its levels not its residuals' own
    fixed_point = two_groups and loss == "linear" and solve.lm_variant != "paper"
    last_lin = None

    def linearised(problem: Problem, x: np.ndarray) -> _Linearised:
        """:func:`_linearised` of the kept rows at the current weights, the last one kept: the
        outlier check and the noise estimate ask at the same solution."""
        nonlocal last_lin
        key = (x.tobytes(), problem.sigma_pos, problem.sigma_rot, keep.tobytes())
        if last_lin is None or last_lin[0] != key:
            last_lin = key, _linearised(problem, x)
        return last_lin[1]

    for outlier_pass in range(4):
        if not first and estimate and fixed_point:
            # rows were removed (or taken back): the noise levels of the fit of the rows now kept,
            # from their linearisation at x (whose normal equations the re-fit starts from)
            sp, sr = _vce_fixed_point(linearised(everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr), x).ne,
                                      (sp, sr), (sp, sr), (sigma_pos is None, sigma_rot is None))
        if outlier_pass and not refit:
            # (the rows now kept and their levels, at the robust solution: see ``refit``; the frame
            # estimate's suspect rows judged there, as below)
            if suspect is not None:
                still, _ = flag_outliers(everything, x, cal.rows, suspect, outlier_k, fsp, fsr)
                back = suspect & ~np.isin(cal.rows, [o.row for o in still])
                outliers += still
                suspect = None
                # (the levels stay those of the rows without them: calibrate's fit estimates its own)
                keep |= back
            break
        for _ in range(VCE_MAX_ITERATIONS):
            problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
            # (pose data: the weights change the fit, so a re-weighted fit follows the first)
            loose = first and estimate and two_groups
            sol = _solve_logged(solve, problem, x, trace, first, loose=loose, mu0=start_mu0)
            start_mu0 = WARM_MU0
            if first or (unjudged and sol.status == "converged"):
                # judged at the starting weights, before they adapt to a stuck fit's residuals;
                # a first fit that stopped unconverged (the paper's LM at its iteration limit) is
                # judged when a re-fit from it first calls itself converged
                sol = _check_local_minimum(sol, problem, solve)
                stuck = sol if sol.status == "local_minimum" else None
                unjudged = sol.status != "converged" and stuck is None
            first = False
            x = sol.x
            if not estimate or sol.status == "diverged":
                break
            lin = linearised(problem, x)
            ne, red_p, red_r = lin.ne, lin.red_pos, lin.red_rot
            vce_total += 1
            if loss == "linear":
                est_p = sp * math.sqrt(ne.rss_pos / red_p) if red_p > 0.5 else sp
                est_r = sr * math.sqrt(ne.rss_rot / red_r) if (two_groups and red_r > 0.5) else sr
            else:   # a robust fit: a noise level that the outliers it resists cannot inflate
                est_p, est_r = robust_sigmas(problem, x, np.ones(problem.n_poses, bool), red_p, red_r)
            new_sp = est_p if sigma_pos is None else sp
            new_sr = est_r if (sigma_rot is None and two_groups) else sr
            new_sp, new_sr = max(new_sp, 1e-12), max(new_sr, 1e-12)
            change = max(abs(new_sp / sp - 1.0), abs(new_sr / sr - 1.0))
            if change >= VCE_RTOL and fixed_point:
                # where the estimation would stop, from this linearisation: one re-weighted fit
                # confirms it instead of one per step of the estimation
                new_sp, new_sr = _vce_fixed_point(ne, (sp, sr), (new_sp, new_sr),
                                                  (sigma_pos is None, sigma_rot is None))
            sp, sr = new_sp, new_sr
            if (change < VCE_RTOL and not loose) or (not two_groups and loss == "linear"):
                break   # (one group: the weights do not change the fit)
        if outlier_k is None or outlier_pass == 3 or sol.status == "diverged":
            break
        problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
        lin = linearised(problem, x)
        few = everything.n_poses * (6 if two_groups else 3) < ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM * len(x)
        judged = judge_rows(everything, problem, x, keep, cal.rows, outlier_k, given=(sigma_pos, sigma_rot),
                            red=(lin.red_pos, lin.red_rot), few=few, first=not outliers, options=solve.options,
                            trace=trace)
        x, fsp, fsr, new, too_many = judged.x, judged.sigma_pos, judged.sigma_rot, list(judged.outliers), \
            judged.too_many
        if judged.breakdown:
            refusals.append(judged.breakdown)
        elif too_many:
            notes.append(f"{len(new)} of {int(keep.sum())} rows have residuals above {outlier_k:g} sigma: "
                         f"the noise is larger than the noise levels (or the model cannot describe the "
                         f"data), so no row was removed as an outlier")
            unremoved = tuple(new)
        new = [] if too_many else new
        if new and len(outliers) + len(new) > TRIMMED_MAX_OUTLIER_SHARE * cal.n_poses:
            refusals.append(too_many_gross(len(outliers) + len(new), cal.n_poses))
            new = []
        if suspect is not None and not new:
            # the suspect rows against the fit of the others: those within outlier_k are taken
            # back (and the fit repeated), the others are outliers
            still, _ = flag_outliers(everything, x, cal.rows, suspect, outlier_k, fsp, fsr)
            gross = {o.row for o in still}
            back = suspect & ~np.isin(cal.rows, list(gross))
            outliers += still
            suspect = None
            if back.any():
                keep |= back
                continue
        if not new:
            break
        outliers += new
        keep &= ~np.isin(cal.rows, [o.row for o in new])
    if suspect is not None:   # never judged (the fit diverged or ran out of passes): outliers
        outliers += flag_outliers(everything, x, cal.rows, suspect, -1.0, sp, sr)[0]
    problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
    if sol.x is not x and refit:   # the last change of x was not solved at these weights (robust start)
        sol = _solve_logged(solve, problem, x, trace, False)
        x = sol.x
    if sol.x is not x:      # (refit False: the robust solution, not refitted)
        sol = replace(sol, x=x, message=f"{sol.message}; then the outlier check's robust solution, not "
                                        f"refitted without the rows it flagged (refit=False)")
    if stuck is not None:
        sol = replace(sol, status=stuck.status, message=stuck.message)
    lin = linearised(problem, x)
    noise = _noise_estimate(problem, lin, estimate, vce_total)
    if estimate and outlier_k is not None and loss == "linear" and not refusals and refit \
            and can_trim(everything, keep, len(x)):
        # (where half of the rows cannot determine the parameters, the median residual cannot say
        # what the noise is either: the real TIAGo marker rows, 27 for 33 parameters, were
        # refused as inconsistent, the least-squares noise 2.2x the median residual's)
        refusals.append(leftover_gross(everything, x, keep, (lin.red_pos, lin.red_rot), (sp, sr),
                                       (sigma_pos, sigma_rot)))
    model = start.with_values(problem.full(x))
    if outliers:
        notes.append(f"{len(outliers)} outlier rows removed and the fit repeated without them: rows "
                     + ", ".join(str(o.row) for o in outliers))
    # (least squares: the cost from the normal equations of the noise estimate)
    cost = lin.ne.cost if problem.loss == "linear" else 0.5 * float(np.sum(problem.residuals(x) ** 2))
    fit = Fit(model, free, replace(sol, cost=cost), keep, tuple(outliers), noise, trace.iterations,
              covariance=lin.inverse, full_rank=lin.full_rank, all_rows=everything, notes=tuple(notes),
              unremoved=unremoved, refusals=tuple(r for r in dict.fromkeys(refusals) if r))
    return fit, problem


def _solve_logged(solve: Solver, problem: Problem, x, trace, first, loose: bool = False,
                  mu0: float = WARM_MU0) -> SolverResult:
    t = time.perf_counter()
    sol = solve(problem, x, trace, first, loose=loose, mu0=mu0)
    log.info("fit (%s%s): %s, cost %.6g, %d iterations, %.1f ms", solve.method if first else "lm",
             "" if first else " re-weighted", sol.status, sol.cost, sol.iterations,
             (time.perf_counter() - t) * 1e3)
    return sol


def _check_local_minimum(sol: SolverResult, problem: Problem, solve: Solver) -> SolverResult:
    """An explicit lm / c-lm fit: an angle search from its solution, then LM; if that reaches a
    clearly lower cost, the fit stopped in a local minimum and is not called converged."""
    if solve.measure != "pose" or solve.method == "search-lm" or sol.status != "converged":
        return sol
    if solve.model.targets:     # the angle search takes one tool frame
        return sol
    chain = solve.chain or RotationChain(solve.model)
    other = dispatch.solve(problem, sol.x, "search-lm", angular=solve.angular, chain=chain,
                           options=solve.options, max_escapes=0)
    # clearly lower: by a fraction of the cost and by more than chance (1 in chi^2 / 2 units)
    if other.cost < LOCAL_MINIMUM_RATIO * sol.cost and sol.cost - other.cost > 1.0:
        msg = (f"{solve.method.upper()} stopped in a local minimum: an angle search from its solution, "
               f"then LM, reaches a cost {other.cost:.4g} below its {sol.cost:.4g} (method search-lm "
               f"escapes it)")
        return replace(sol, status="local_minimum", message=msg)
    return sol


def method_notes(setup: Setup, method: str) -> list[str]:
    """A note when the data make ``method`` run as LM (position-only data; several targets for
    the angle search of search-lm)."""
    if setup.measure == "position" and method != "lm":
        return [f"position-only data: {method.upper()} needs orientations for its angle step; ran LM"]
    if method == "search-lm" and setup.start.targets:
        return ["several targets: the angle search of SEARCH-LM takes one tool frame; ran LM"]
    return []


def fit_with(setup: Setup, free: Sequence[str], options: CalibrationOptions, *, outlier_k: float | None,
             keep: np.ndarray | None = None, kin: ChainKinematics | None = None, rank_deficit: int = 0,
             sigma_pos: float | None = None, sigma_rot: float | None = None,
             warm: bool = False, refit: bool = True) -> tuple[Fit, Problem]:
    """:func:`fit_stage` of ``free`` with the solver, loss and noise levels of ``options``
    (sigma_pos / sigma_rot: given instead of the options' ones when not None; warm, refit: see
    :func:`fit_stage`)."""
    solve = solver_for(setup, free, options.method, options.lm, options.max_rounds, options.fixed_rounds,
                        options.lm_variant)
    return fit_stage(setup, free, solve, sigma_pos=options.sigma_pos if sigma_pos is None else sigma_pos,
                     sigma_rot=options.sigma_rot if sigma_rot is None else sigma_rot, loss=options.loss,
                     loss_scale=options.loss_scale, outlier_k=outlier_k, keep=keep, kin=kin,
                     rank_deficit=rank_deficit, warm=warm, refit=refit)
