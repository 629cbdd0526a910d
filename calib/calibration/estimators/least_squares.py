"""The fit stage (:class:`Fit`): the noise-weighted identification, variance-component estimation of
the noise levels (:class:`NoiseEstimate`), and the outlier check (:class:`~calib.calibration.estimators.outlier.Outlier`).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.calibration.accuracy import AccuracyStats, target_rows
from calib.calibration.options import (
    IMPLAUSIBLE_LENGTH_FRACTION,
    IMPLAUSIBLE_REACH_FRACTION,
    IMPLAUSIBLE_ROT_RAD,
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
from calib.calibration.prepare import Setup, robot_memo, robot_reach
from calib.calibration.estimators.base import Estimate, Fit, Linearised, linearised, noise_estimate, vce_fixed_point
from calib.calibration.estimators.outlier import Outlier
from calib.calibration.estimators.robust import (can_trim, flag_outliers, judge_rows, leftover_gross, robust_sigmas,
                                      too_many_gross)
from calib.errors import DataError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.solvers import dispatch
from calib.solvers.angles import RotationChain
from calib.solvers.lm import LMOptions, LMTrace, SolverResult, options_with
from calib.solvers.inverse import normal_inverse
from calib.solvers.problem import CHI2_ESCAPE, NormalEquations, Problem


log = logging.getLogger(__name__)


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
              warm: bool = False, refit: bool = True, choose_weights: bool = False) -> tuple[Fit, Problem]:
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
    choose_weights : for pose data with both noise levels estimated, the orientation's weight
    chosen by cross-validated held-out position error once the rows are judged
    (:mod:`calib.calibration.estimators.weights`; a note says when it is not the variance
    components').
    Returns the :class:`Fit` and the final weighted problem on the kept rows.
    """
    return _FitRun(setup, free, solve, sigma_pos=sigma_pos, sigma_rot=sigma_rot, loss=loss, loss_scale=loss_scale,
                   outlier_k=outlier_k, keep=keep, kin=kin, rank_deficit=rank_deficit, warm=warm,
                   refit=refit, choose_weights=choose_weights).run()


class _FitRun:
    """One run of :func:`fit_stage`: its state (the rows kept, the noise levels, the solution, the
    outliers found) and its steps: the noise-weighted fits (:meth:`weighted_fits`), the outlier
    check (:meth:`judge`) and the result (:meth:`finish`)."""

    def __init__(self, setup: Setup, free: Sequence[str], solve: Solver, *, sigma_pos: float | None,
                 sigma_rot: float | None, loss: str, loss_scale: float, outlier_k: float | None,
                 keep: np.ndarray | None, kin: ChainKinematics | None, rank_deficit: int, warm: bool,
                 refit: bool, choose_weights: bool = False):
        cal, start = setup.cal, setup.start
        kin = kin or ChainKinematics(start)
        self.setup, self.solve, self.loss, self.outlier_k, self.refit = setup, solve, loss, outlier_k, refit
        self.free = tuple(free)
        idx = start.indices(self.free)
        self.given = (sigma_pos, sigma_rot)
        self.estimate = sigma_pos is None or sigma_rot is None
        self.sp = SIGMA_POS_M if sigma_pos is None else sigma_pos
        self.sr = SIGMA_ROT_RAD if sigma_rot is None else sigma_rot
        self.everything = Problem(kin, cal.q, cal.position, cal.rotation, start.values, idx, self.sp, self.sr,
                                  loss, loss_scale, targets=target_rows(start, cal))
        self.everything.set_rank_deficit(rank_deficit)     # (of the set at the nominal model, these rows)
        self.suspect = None
        if keep is None:
            keep = np.ones(cal.n_poses, bool)
            if setup.suspect is not None and outlier_k is not None:
                # rows the frame estimate found gross would drag the first fit far from the others'
                # solution: start without them, take back below those the fitted model explains
                self.suspect = setup.suspect.copy()
                keep &= ~self.suspect
        else:
            keep = keep.copy()
        self.keep = keep
        self.trace = LMTrace()
        self.x = start.values[idx]
        self.sol: SolverResult | None = None
        self.outliers: list[Outlier] = []
        self.notes: list[str] = []
        self.refusals: list[str] = []
        self.first = not warm
        self.start_mu0 = STEP_START_MU0 if warm else WARM_MU0     # (the first solve's damping, when not first)
        self.stuck = None
        # (a warm start comes from a fit of the geometry, which may itself have stopped in a local
        # minimum: the warm fit's first converged solution is judged as a first fit's is)
        self.unjudged = warm
        self.unremoved: tuple[Outlier, ...] = ()
        self.vce_total = 0
        self.two_groups = setup.measure == "pose"
        # the levels where the estimation stops, from one linearisation (vce_fixed_point): a
        # re-fit that follows the weights confirms them; the paper's LM as printed ignores the
        # weights, and the estimation then ran to its limit of re-fits, its levels not its
        # residuals' own
        self.fixed_point = self.two_groups and loss == "linear" and solve.lm_variant != "paper"
        self.robust_levels = (self.sp, self.sr)       # (the outlier check's robust noise levels)
        self.trimmed_last = False       # (the rows now kept were judged against the high-breakdown fit)
        self.choose_weights = choose_weights
        self.weight_choice = None       # (a WeightChoice when the orientation's weight was changed)
        self._last_lin = None

    def problem(self) -> Problem:
        """The weighted problem of the rows kept, at the current noise levels."""
        return self.everything.derived(keep=self.keep, sigma_pos=self.sp, sigma_rot=self.sr)

    def linearised(self, problem: Problem, x: np.ndarray) -> Linearised:
        """:func:`linearised` of the kept rows at the current weights, the last one kept: the
        outlier check and the noise estimate ask at the same solution."""
        key = (x.tobytes(), problem.sigma_pos, problem.sigma_rot, self.keep.tobytes())
        if self._last_lin is None or self._last_lin[0] != key:
            self._last_lin = key, linearised(problem, x)
        return self._last_lin[1]

    def run(self) -> tuple[Fit, Problem]:
        for outlier_pass in range(4):
            if not self.first and self.estimate and self.fixed_point:
                # rows were removed (or taken back): the noise levels of the fit of the rows now
                # kept, from their linearisation at x (whose normal equations the re-fit starts from)
                levels = (self.sp, self.sr)
                self.sp, self.sr = vce_fixed_point(self.linearised(self.problem(), self.x).ne, levels, levels,
                                                   (self.given[0] is None, self.given[1] is None))
            if outlier_pass and not self.refit:
                self.take_back_unrefitted()
                break
            self.weighted_fits()
            if self.outlier_k is None or outlier_pass == 3 or self.sol.status == "diverged":
                break
            if not self.judge():
                break
        if self.choose_weights:
            self.rotation_weight()
        return self.finish()

    def rotation_weight(self) -> None:
        """The orientation's weight chosen by cross-validated held-out position error
        (:func:`~calib.calibration.estimators.weights.choose_rotation_weight`) for pose data with
        both noise levels estimated, least squares: when another than the variance components'
        is chosen, the orientation is held at that level and the fit re-weighted (its position
        level estimated again)."""
        if not (self.two_groups and self.given == (None, None) and self.loss == "linear" and self.refit
                and self.sol is not None and self.sol.status == "converged" and self.solve.lm_variant != "paper"):
            return
        from calib.calibration.estimators.weights import choose_rotation_weight

        try:
            choice = choose_rotation_weight(self.problem(), self.x)
        except DataError:
            return
        if choice.factor == 1.0:
            return
        self.weight_choice = choice
        self.sr *= choice.factor
        self.given = (None, self.sr)
        self.weighted_fits()

    def take_back_unrefitted(self) -> None:
        """``refit`` False: the rows now kept and their levels, at the robust solution; the frame
        estimate's suspect rows judged there, as :meth:`judge` does."""
        if self.suspect is not None:
            cal = self.setup.cal
            still, _ = flag_outliers(self.everything, self.x, cal.rows, self.suspect, self.outlier_k,
                                     *self.robust_levels)
            back = self.suspect & ~np.isin(cal.rows, [o.row for o in still])
            self.outliers += still
            self.suspect = None
            # (the levels stay those of the rows without them: calibrate's fit estimates its own)
            self.keep |= back

    def weighted_fits(self) -> None:
        """The fit of the kept rows, re-weighted by the noise levels its residuals give until they
        settle (variance-component estimation; once when the levels are given)."""
        sigma_pos, sigma_rot = self.given
        for _ in range(VCE_MAX_ITERATIONS):
            problem = self.problem()
            # (pose data: the weights change the fit, so a re-weighted fit follows the first)
            loose = self.first and self.estimate and self.two_groups
            sol = _solve_logged(self.solve, problem, self.x, self.trace, self.first, loose=loose, mu0=self.start_mu0)
            self.start_mu0 = WARM_MU0
            if self.first or (self.unjudged and sol.status == "converged"):
                # judged at the starting weights, before they adapt to a stuck fit's residuals;
                # a first fit that stopped unconverged (the paper's LM at its iteration limit) is
                # judged when a re-fit from it first calls itself converged
                sol = _check_local_minimum(sol, problem, self.solve)
                self.stuck = sol if sol.status == "local_minimum" else None
                self.unjudged = sol.status != "converged" and self.stuck is None
            self.first = False
            self.sol, self.x = sol, sol.x
            if not self.estimate or sol.status == "diverged":
                break
            lin = self.linearised(problem, self.x)
            ne, red_p, red_r = lin.ne, lin.red_pos, lin.red_rot
            self.vce_total += 1
            sp, sr = self.sp, self.sr
            if self.loss == "linear":
                est_p = sp * math.sqrt(ne.rss_pos / red_p) if red_p > 0.5 else sp
                est_r = sr * math.sqrt(ne.rss_rot / red_r) if (self.two_groups and red_r > 0.5) else sr
            else:   # a robust fit: a noise level that the outliers it resists cannot inflate
                est_p, est_r = robust_sigmas(problem, self.x, np.ones(problem.n_poses, bool), red_p, red_r)
            new_sp = est_p if sigma_pos is None else sp
            new_sr = est_r if (sigma_rot is None and self.two_groups) else sr
            new_sp, new_sr = max(new_sp, 1e-12), max(new_sr, 1e-12)
            change = max(abs(new_sp / sp - 1.0), abs(new_sr / sr - 1.0))
            if change >= VCE_RTOL and self.fixed_point:
                # where the estimation would stop, from this linearisation: one re-weighted fit
                # confirms it instead of one per step of the estimation
                new_sp, new_sr = vce_fixed_point(ne, (sp, sr), (new_sp, new_sr),
                                                 (sigma_pos is None, sigma_rot is None))
            self.sp, self.sr = new_sp, new_sr
            if (change < VCE_RTOL and not loose) or (not self.two_groups and self.loss == "linear"):
                break   # (one group: the weights do not change the fit)

    def judge(self) -> bool:
        """The outlier check of the rows kept against a robust fit: rows removed (or the frame
        estimate's suspect rows taken back) and True for another pass, False when the rows kept
        stand."""
        cal, everything, outlier_k = self.setup.cal, self.everything, self.outlier_k
        problem = self.problem()
        lin = self.linearised(problem, self.x)
        few = everything.n_poses * (6 if self.two_groups else 3) < ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM * len(self.x)
        judged = judge_rows(everything, problem, self.x, self.keep, cal.rows, outlier_k, given=self.given,
                            red=(lin.red_pos, lin.red_rot), few=few, first=not self.outliers,
                            options=self.solve.options, trace=self.trace)
        self.x, self.robust_levels = judged.x, (judged.sigma_pos, judged.sigma_rot)
        new, too_many = list(judged.outliers), judged.too_many
        self.trimmed_last = judged.trimmed
        if judged.breakdown:
            self.refusals.append(judged.breakdown)
        elif too_many:
            self.notes.append(f"{len(new)} of {int(self.keep.sum())} rows have residuals above {outlier_k:g} sigma: "
                              f"the noise is larger than the noise levels (or the model cannot describe the "
                              f"data), so no row was removed as an outlier")
            self.unremoved = tuple(new)
        new = [] if too_many else new
        if new and len(self.outliers) + len(new) > TRIMMED_MAX_OUTLIER_SHARE * cal.n_poses:
            self.refusals.append(too_many_gross(len(self.outliers) + len(new), cal.n_poses))
            new = []
        if self.suspect is not None and not new:
            # the suspect rows against the fit of the others: those within outlier_k are taken
            # back (and the fit repeated), the others are outliers
            still, _ = flag_outliers(everything, self.x, cal.rows, self.suspect, outlier_k, *self.robust_levels)
            back = self.suspect & ~np.isin(cal.rows, list({o.row for o in still}))
            self.outliers += still
            self.suspect = None
            if back.any():
                self.keep |= back
                self.trimmed_last = False
                return True
        if not new:
            return False
        self.outliers += new
        self.keep &= ~np.isin(cal.rows, [o.row for o in new])
        self.trimmed_last = False
        return True

    def finish(self) -> tuple[Fit, Problem]:
        """The :class:`Fit` of the rows kept: a last least-squares fit where the robust solution
        was not solved at the final weights, the noise estimate, the covariance, the check for
        gross rows left over."""
        cal, everything, start = self.setup.cal, self.everything, self.setup.start
        if self.suspect is not None:   # never judged (the fit diverged or ran out of passes): outliers
            self.outliers += flag_outliers(everything, self.x, cal.rows, self.suspect, -1.0, self.sp, self.sr)[0]
        problem = self.problem()
        sol, x = self.sol, self.x
        if sol.x is not x and self.refit:   # the last change of x was not solved at these weights (robust start)
            sol = _solve_logged(self.solve, problem, x, self.trace, False)
            x = sol.x
        if sol.x is not x:      # (refit False: the robust solution, not refitted)
            sol = replace(sol, x=x, message=f"{sol.message}; then the outlier check's robust solution, not "
                                            f"refitted without the rows it flagged (refit=False)")
        if self.stuck is not None:
            sol = replace(sol, status=self.stuck.status, message=self.stuck.message)
        lin = self.linearised(problem, x)
        noise = noise_estimate(problem, lin, self.estimate, self.vce_total)
        covariance = lin.inverse
        if self.weight_choice is not None:
            # the orientation weighted as noisier than it is: its noise as its residuals give it,
            # and the covariance of a fit so weighted (A^-1 (A_pos + c A_rot) A^-1, c its
            # residuals' reduced chi-square: the weighting's own A^-1 overstated the orientation
            # error 1.4 times)
            c = max(noise.chi2_rot, 0.0)
            actual = problem.sigma_rot * math.sqrt(c)
            noise = replace(noise, rotation=actual, chi2_rot=1.0, chi2=noise.chi2 - lin.ne.rss_rot + lin.red_rot)
            covariance = lin.inverse @ (noise.chi2_pos * lin.ne.A_pos + c * lin.ne.A_rot) @ lin.inverse
            self.notes.append(self.weight_choice.note(problem.sigma_rot, actual))
        notes = list(self.notes)
        if self.estimate and self.outlier_k is not None and self.loss == "linear" and not self.refusals \
                and self.refit and can_trim(everything, self.keep, len(x)):
            # (where half of the rows cannot determine the parameters, the median residual cannot
            # say what the noise is either: the real TIAGo marker rows, 27 for 33 parameters, were
            # refused as inconsistent, the least-squares noise 2.2x the median residual's)
            notes += self.tails(problem, x, lin)
        model = start.with_values(problem.full(x))
        if self.outliers:
            notes.append(f"{len(self.outliers)} outlier rows removed and the fit repeated without them: rows "
                         + ", ".join(str(o.row) for o in self.outliers))
        # (least squares: the cost from the normal equations of the noise estimate)
        cost = lin.ne.cost if problem.loss == "linear" else 0.5 * float(np.sum(problem.residuals(x) ** 2))
        fit = Fit(model, self.free, replace(sol, cost=cost), self.keep, tuple(self.outliers), noise,
                  self.trace.iterations, covariance=covariance, full_rank=lin.full_rank, all_rows=everything,
                  notes=tuple(notes), unremoved=self.unremoved,
                  refusals=tuple(r for r in dict.fromkeys(self.refusals) if r))
        return fit, problem

    def tails(self, problem: Problem, x: np.ndarray, lin: Linearised) -> list[str]:
        """The data-consistency rule on the final fit (:mod:`calib.calibration.consistency`):
        heavy tails (the least-squares noise level above ROBUST_CHECK_INFLATION times the robust
        one) are judged against the high-breakdown fit where the passes did not judge these rows
        there (a refusal when more than half of them lie far from it), else noted with their
        figures."""
        cal, everything = self.setup.cal, self.everything
        tails = leftover_gross(everything, x, self.keep, (lin.red_pos, lin.red_rot), (self.sp, self.sr),
                               self.given, self.outlier_k)
        if not tails.heavy:
            return []
        beyond = len(self.outliers)
        if not self.trimmed_last:
            judged = judge_rows(everything, problem, x, self.keep, cal.rows, self.outlier_k, given=self.given,
                                red=(lin.red_pos, lin.red_rot), few=True, options=self.solve.options,
                                trace=self.trace)
            if judged.breakdown:
                self.refusals.append(judged.breakdown)
                return []
            beyond += len(judged.outliers)
        return [replace(tails, rows=cal.n_poses, beyond=beyond).note()]


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


def implausibility(nominal: RobotModel, fit: Fit, *, sigma_pos_given: bool,
                   sigma_rot_given: bool) -> list[str]:
    """Why the fit's result cannot be trusted, one sentence each (empty when it can): residuals
    far above given noise levels (every uncertainty and prediction is that much too small),
    errors no robot and instrument give. A calibration with any of these is not called converged
    (status "implausible"). sigma_pos_given / sigma_rot_given: which noise levels the user gave
    (each group is judged against its own)."""
    notes = list(fit.refusals)
    nz = fit.noise
    given = [("position", nz.chi2_pos)] if sigma_pos_given else []
    if sigma_rot_given and nz.chi2_rot is not None:
        given.append(("orientation", nz.chi2_rot))
    worst = max(given, key=lambda g: g[1], default=None)
    if worst is not None and fit.solver.status == "converged" and worst[1] > CHI2_ESCAPE:
        notes.append(f"the fit converged but its {worst[0]} residuals are {math.sqrt(worst[1]):.1f} times the "
                     f"given noise (reduced chi^2 {worst[1]:.3g}): a wrong sigma, or errors the model "
                     f"does not describe; omit the noise levels to estimate them from the data")
    # judged on the rows the fit kept: a gross row it flagged is not the model's failure
    return notes + _implausible_fit_notes(nominal, fit.errors.subset(fit.keep))


def length_notes(nominal: RobotModel, fit: Fit) -> list[str]:
    """Notes naming link lengths identified far from ``nominal``'s. A note, not a refusal: a
    length tied to another (d2 and d3 of parallel axes, d6 and the tool's z) can move along the
    tie with the model's kinematics exact (from a start 1.55 rad off in alpha2: d2 -26 m,
    d3 +26 m, error to the truth 1e-9 m)."""
    return _implausible_length_notes(nominal, fit.model)


def fit_with(setup: Setup, free: Sequence[str], options: CalibrationOptions, *, outlier_k: float | None,
             keep: np.ndarray | None = None, kin: ChainKinematics | None = None, rank_deficit: int = 0,
             sigma_pos: float | None = None, sigma_rot: float | None = None,
             warm: bool = False, refit: bool = True, choose_weights: bool = False) -> tuple[Fit, Problem]:
    """:func:`fit_stage` of ``free`` with the solver, loss and noise levels of ``options``
    (sigma_pos / sigma_rot: given instead of the options' ones when not None; warm, refit,
    choose_weights: see :func:`fit_stage`)."""
    solve = solver_for(setup, free, options.method, options.lm, options.max_rounds, options.fixed_rounds,
                        options.lm_variant)
    return fit_stage(setup, free, solve, sigma_pos=options.sigma_pos if sigma_pos is None else sigma_pos,
                     sigma_rot=options.sigma_rot if sigma_rot is None else sigma_rot, loss=options.loss,
                     loss_scale=options.loss_scale, outlier_k=outlier_k, keep=keep, kin=kin,
                     rank_deficit=rank_deficit, warm=warm, refit=refit, choose_weights=choose_weights)


@dataclass(frozen=True, eq=False)
class LeastSquares:
    """The least-squares estimator: the noise-weighted fit of the chosen set by the options'
    method, its noise levels estimated (variance components) unless given, its robust loss and
    outlier check (:func:`fit_stage`).

    start : a model near the solution to start from (the joint terms' chosen model, linearised at
    the geometric solution: a few LM iterations instead of the method's scheme), or None (the
    method's scheme from the setup's start); suspect : (N_cal,) bool, rows to start without
    (the geometric fit's outliers), taken back when the model explains them."""

    start: RobotModel | None = None
    suspect: np.ndarray | None = None
    name: str = "least-squares"

    def fit(self, setup: Setup, choice, options: CalibrationOptions, kin: ChainKinematics) -> Estimate:
        warm = self.start is not None and not choice.deficit
        if warm:
            setup = replace(setup, start=self.start, suspect=self.suspect)
        fit, problem = fit_with(setup, choice.free, options, outlier_k=options.outlier_k, kin=kin,
                                rank_deficit=choice.deficit, warm=warm, choose_weights=True)
        return Estimate(fit, problem, choice.label, {"kind": self.name, "param_set": choice.label})

    def refit(self, setup: Setup, free: Sequence[str], options: CalibrationOptions, kin: ChainKinematics, *,
              keep: np.ndarray, levels: tuple[float, float] | None = None) -> tuple[Fit, Problem]:
        """``free`` fitted on the rows ``keep`` without the outlier check: at the noise levels
        ``levels`` (sigma_pos m, sigma_rot rad; least squares), or, with None, at the options'
        (estimated where not given) and with their loss. Model selection's candidates."""
        if levels is None:
            return fit_with(setup, free, options, outlier_k=None, keep=keep, kin=kin)
        solve = solver_for(setup, free, options.method, options.lm, options.max_rounds, options.fixed_rounds,
                           options.lm_variant)
        return fit_stage(setup, free, solve, sigma_pos=levels[0], sigma_rot=levels[1], outlier_k=None, keep=keep,
                         kin=kin)


def _implausible_fit_notes(robot: RobotModel, after: AccuracyStats) -> list[str]:
    """A note when the calibrated model leaves errors on its calibration rows that no robot and
    instrument give (:data:`IMPLAUSIBLE_REACH_FRACTION` of the reach, :data:`IMPLAUSIBLE_ROT_RAD`):
    the fit ran, but on data that do not belong to this robot as read."""
    reach = robot_memo("reach", robot, (), lambda: robot_reach(robot))
    pos = after.position["rms"]
    rot = after.rotation["rms"] if after.rotation is not None else 0.0
    what, check = [], []
    if pos > IMPLAUSIBLE_REACH_FRACTION * reach:
        what.append(f"a position RMS error of {pos * 1e3:.4g} mm ({100 * pos / reach:.0f} % of the robot's "
                    f"reach {reach * 1e3:.0f} mm)")
        check.append("the joint units (degrees read as radians, or radians as degrees), the joint order "
                     "and the robot")
    if rot > IMPLAUSIBLE_ROT_RAD:
        what.append(f"an orientation RMS error of {rot:.3g} rad")
        check.append("the orientation columns (quaternion order w, x, y, z; --euler sequence; a rotation "
                     "vector read as angles: --convention ur; angle units) and the tool frame")
    if not what:
        return []
    return [f"the calibrated model does not describe these measurements: on the calibration rows it "
            f"leaves {' and '.join(what)}; check {', and '.join(check)}"]


def _implausible_length_notes(nominal: RobotModel, calibrated: RobotModel) -> list[str]:
    """A note naming the link lengths (d, a of the joints) identified further than
    :data:`IMPLAUSIBLE_LENGTH_FRACTION` of the reach from their nominal values: no robot is built
    that far from its drawing (positions in metres named _mm shrink a UR5's 425 mm link to
    0.6 mm and the fit converges at the noise; the URDF of another robot model)."""
    reach = robot_memo("reach", nominal, (), lambda: robot_reach(nominal))
    far = [(p.name, b - a) for p, a, b in zip(nominal.parameters, nominal.values, calibrated.values)
           if p.group == "joint" and p.unit == "m" and abs(b - a) > IMPLAUSIBLE_LENGTH_FRACTION * reach
           and not (p.kind == "d" and nominal.prismatic[p.joint - 1])]   # (a slide's offset: any)
    if not far:
        return []
    shown = ", ".join(f"{name} {dev * 1e3:+.1f} mm" for name, dev in far)
    return [f"identified link lengths far from the URDF's: {shown} (more than "
            f"{100 * IMPLAUSIBLE_LENGTH_FRACTION:g} % of the robot's reach {reach * 1e3:.0f} mm); check the "
            f"length unit of the positions (metres named _mm?) and that the URDF is this robot's"]
