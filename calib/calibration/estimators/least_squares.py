"""The fit stage (:class:`Fit`): the noise-weighted identification, variance-component estimation of
the noise levels (:class:`NoiseEstimate`), and the outlier check (:class:`~calib.calibration.estimators.outlier.Outlier`).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from calib.calibration.accuracy.errors import target_rows
from calib.calibration.options import (
    ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM,
    STEP_START_MU0,
    TRIMMED_MAX_OUTLIER_SHARE,
    VCE_MAX_ITERATIONS,
    VCE_RTOL,
    WARM_MU0,
    CalibrationOptions,
)
from calib.calibration.plausibility import too_many_gross
from calib.calibration.prepare import Setup
from calib.calibration.estimators.base import (Estimate, Fit, Linearised, check_group_redundancy, linearised,
                                               noise_estimate, vce_fixed_point)
from calib.calibration.estimators.outlier import Outlier
from calib.calibration.estimators.robust import (can_trim, components, flag_outliers, judge_rows, leftover_gross, levels_of,
                                                 robust_sigmas)
from calib.errors import DataError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.calibration.estimators.solver import Solver, check_local_minimum, solve_logged, solver_for
from calib.solvers.lm import LMTrace, SolverResult
from calib.solvers.blocks import GROUPS
from calib.solvers.problem import Problem


log = logging.getLogger(__name__)


def fit_stage(setup: Setup, free: Sequence[str], solve: Solver, *, sigma_pos: float | None,
              sigma_rot: float | None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0, keep: np.ndarray | None = None,
              kin: ChainKinematics | None = None, rank_deficit: int = 0,
              warm: bool = False, refit: bool = True, sigma_touch: float | None = None,
              choose_weights: bool = False) -> tuple[Fit, Problem]:
    """The fit stage: identify ``free`` on the calibration rows of ``setup`` (with touch rows, and
    the features' unknowns: a :class:`~calib.solvers.blocks.BlockProblem` of the setup's blocks).

    sigma_pos (m) / sigma_rot (rad) / sigma_touch (m, touch rows): the noise per axis (per
    component), or None to estimate it from the residuals (variance-component estimation: each
    group's weight is re-set to its weighted residual sum of squares over its redundancy, and the
    fit repeated, until every one changes by less than VCE_RTOL).
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
                   refit=refit, sigma_touch=sigma_touch, choose_weights=choose_weights).run()


class _FitRun:
    """One run of :func:`fit_stage`: its state (the rows kept, the noise levels, the solution, the
    outliers found) and its steps: the noise-weighted fits (:meth:`weighted_fits`), the outlier
    check (:meth:`judge`) and the result (:meth:`finish`)."""

    def __init__(self, setup: Setup, free: Sequence[str], solve: Solver, *, sigma_pos: float | None,
                 sigma_rot: float | None, loss: str, loss_scale: float, outlier_k: float | None,
                 keep: np.ndarray | None, kin: ChainKinematics | None, rank_deficit: int, warm: bool,
                 refit: bool, sigma_touch: float | None = None, choose_weights: bool = False):
        cal, start = setup.cal, setup.start
        kin = kin or ChainKinematics(start)
        self.setup, self.solve, self.loss, self.outlier_k, self.refit = setup, solve, loss, outlier_k, refit
        self.free = tuple(free)
        idx = start.indices(self.free)
        # the noise levels given (None: estimated) and used, one per residual group: position,
        # rotation (and touch, with touch rows)
        self.given = (sigma_pos, sigma_rot) + ((sigma_touch,) if setup.touch is not None else ())
        self.estimate = any(g is None for g in self.given)
        self.lv = tuple(d if g is None else g for d, g in zip((SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M), self.given))
        if setup.touch is None:
            self.everything = Problem(kin, cal.q, cal.position, cal.rotation, start.values, idx, *self.lv,
                                      loss, loss_scale, targets=target_rows(start, cal))
            self.x = start.values[idx]
        else:
            self.everything = setup.block_problem(kin, idx, self.lv, loss, loss_scale)
            self.x = np.concatenate([start.values[idx], setup.features.values])
        self.everything.set_rank_deficit(rank_deficit)     # (of the set at the nominal model, these rows)
        self.rows = setup.rows
        self.suspect = None
        if keep is None:
            keep = np.ones(len(self.rows), bool)
            if setup.suspect is not None and outlier_k is not None:
                # rows the frame estimate found gross would drag the first fit far from the others'
                # solution: start without them, take back below those the fitted model explains
                self.suspect = setup.suspect.copy()
                keep &= ~self.suspect
        else:
            keep = keep.copy()
        self.keep = keep
        self.trace = LMTrace()
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
        self.two_groups = setup.measure == "pose" if setup.touch is None else len(self.everything.groups) > 1
        # the levels where the estimation stops, from one linearisation (vce_fixed_point): a
        # re-fit that follows the weights confirms them; the paper's LM as printed ignores the
        # weights, and the estimation then ran to its limit of re-fits, its levels not its
        # residuals' own. Pose rows only: with touch rows (three groups) each re-fit is one step
        self.fixed_point = (self.two_groups and setup.touch is None and loss == "linear"
                            and solve.lm_variant != "paper")
        self.robust_levels = self.lv       # (the outlier check's robust noise levels)
        self.trimmed_last = False       # (the rows now kept were judged against the high-breakdown fit)
        self.choose_weights = choose_weights
        self.weight_choice = None       # (a WeightChoice when the orientation's weight was changed)
        self._last_lin = None

    def problem(self) -> Problem:
        """The weighted problem of the rows kept, at the current noise levels."""
        if self.setup.touch is not None:
            return self.everything.derived(keep=self.keep, sigma_pos=self.lv[0], sigma_rot=self.lv[1],
                                           sigma_touch=self.lv[2])
        return self.everything.derived(keep=self.keep, sigma_pos=self.lv[0], sigma_rot=self.lv[1])

    def linearised(self, problem: Problem, x: np.ndarray) -> Linearised:
        """:func:`linearised` of the kept rows at the current weights, the last one kept: the
        outlier check and the noise estimate ask at the same solution."""
        key = (x.tobytes(), levels_of(problem), self.keep.tobytes())
        if self._last_lin is None or self._last_lin[0] != key:
            self._last_lin = key, linearised(problem, x)
        return self._last_lin[1]

    def run(self) -> tuple[Fit, Problem]:
        for outlier_pass in range(4):
            if not self.first and self.estimate and self.fixed_point:
                # rows were removed (or taken back): the noise levels of the fit of the rows now
                # kept, from their linearisation at x (whose normal equations the re-fit starts from)
                self.lv = vce_fixed_point(self.linearised(self.problem(), self.x).ne, self.lv, self.lv,
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
        if not (self.setup.touch is None and self.two_groups and self.given == (None, None)
                and self.loss == "linear" and self.refit and self.sol is not None
                and self.sol.status == "converged" and self.solve.lm_variant != "paper"):
            return
        from calib.calibration.estimators.weights import choose_rotation_weight

        try:
            choice = choose_rotation_weight(self.problem(), self.x)
        except DataError:
            return
        if choice.factor == 1.0:
            return
        self.weight_choice = choice
        self.lv = (self.lv[0], self.lv[1] * choice.factor)
        self.given = (None, self.lv[1])
        self.weighted_fits()

    def take_back_unrefitted(self) -> None:
        """``refit`` False: the rows now kept and their levels, at the robust solution; the frame
        estimate's suspect rows judged there, as :meth:`judge` does."""
        if self.suspect is not None:
            still, _ = flag_outliers(self.everything, self.x, self.rows, self.suspect, self.outlier_k,
                                     self.robust_levels)
            back = self.suspect & ~np.isin(self.rows, [o.row for o in still])
            self.outliers += still
            self.suspect = None
            # (the levels stay those of the rows without them: calibrate's fit estimates its own)
            self.keep |= back

    def weighted_fits(self) -> None:
        """The fit of the kept rows, re-weighted by the noise levels its residuals give until they
        settle (variance-component estimation; once when the levels are given)."""
        for _ in range(VCE_MAX_ITERATIONS):
            problem = self.problem()
            # (pose data: the weights change the fit, so a re-weighted fit follows the first)
            loose = self.first and self.estimate and self.two_groups
            sol = solve_logged(self.solve, problem, self.x, self.trace, self.first, loose=loose, mu0=self.start_mu0)
            self.start_mu0 = WARM_MU0
            if self.first or (self.unjudged and sol.status == "converged"):
                # judged at the starting weights, before they adapt to a stuck fit's residuals;
                # a first fit that stopped unconverged (the paper's LM at its iteration limit) is
                # judged when a re-fit from it first calls itself converged
                sol = check_local_minimum(sol, problem, self.solve)
                self.stuck = sol if sol.status == "local_minimum" else None
                self.unjudged = sol.status != "converged" and self.stuck is None
            self.first = False
            self.sol, self.x = sol, sol.x
            if not self.estimate or sol.status == "diverged":
                break
            lin = self.linearised(problem, self.x)
            ne, red = lin.ne, lin.redundancies(len(self.lv))
            self.vce_total += 1
            old = self.lv
            if self.loss == "linear":   # (each group: its weighted rss over its redundancy)
                est = tuple(lv * math.sqrt(ne.share(g)[1] / r) if r > 0.5 else lv
                            for g, lv, r in zip(GROUPS, old, red))
            else:   # a robust fit: a noise level that the outliers it resists cannot inflate
                est = robust_sigmas(problem, self.x, np.ones(problem.n_poses, bool), red)
            new = tuple(max(e if g is None else lv, 1e-12) for e, g, lv in zip(est, self.given, old))
            change = max(abs(a / b - 1.0) for a, b in zip(new, old))
            if change >= VCE_RTOL and self.fixed_point:
                # where the estimation would stop, from this linearisation: one re-weighted fit
                # confirms it instead of one per step of the estimation
                new = vce_fixed_point(ne, old, new, (self.given[0] is None, self.given[1] is None))
            self.lv = new
            if (change < VCE_RTOL and not loose) or (not self.two_groups and self.loss == "linear"):
                break   # (one group: the weights do not change the fit)

    def judge(self) -> bool:
        """The outlier check of the rows kept against a robust fit: rows removed (or the frame
        estimate's suspect rows taken back) and True for another pass, False when the rows kept
        stand."""
        rows, everything, outlier_k = self.rows, self.everything, self.outlier_k
        problem = self.problem()
        lin = self.linearised(problem, self.x)
        few = components(everything) < ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM * len(self.x)
        judged = judge_rows(everything, problem, self.x, self.keep, rows, outlier_k, given=self.given,
                            red=lin.redundancies(len(self.lv)), few=few, first=not self.outliers,
                            options=self.solve.options, trace=self.trace)
        self.x, self.robust_levels = judged.x, judged.levels
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
        if new and len(self.outliers) + len(new) > TRIMMED_MAX_OUTLIER_SHARE * len(rows):
            self.refusals.append(too_many_gross(len(self.outliers) + len(new), len(rows)))
            new = []
        if self.suspect is not None and not new:
            # the suspect rows against the fit of the others: those within outlier_k are taken
            # back (and the fit repeated), the others are outliers
            still, _ = flag_outliers(everything, self.x, rows, self.suspect, outlier_k, self.robust_levels)
            back = self.suspect & ~np.isin(rows, list({o.row for o in still}))
            self.outliers += still
            self.suspect = None
            if back.any():
                self.keep |= back
                self.trimmed_last = False
                return True
        if not new:
            return False
        self.outliers += new
        self.keep &= ~np.isin(rows, [o.row for o in new])
        self.trimmed_last = False
        return True

    def finish(self) -> tuple[Fit, Problem]:
        """The :class:`Fit` of the rows kept: a last least-squares fit where the robust solution
        was not solved at the final weights, the noise estimate, the covariance, the check for
        gross rows left over."""
        everything, start = self.everything, self.setup.start
        if self.suspect is not None:   # never judged (the fit diverged or ran out of passes): outliers
            self.outliers += flag_outliers(everything, self.x, self.rows, self.suspect, -1.0, self.lv)[0]
        problem = self.problem()
        sol, x = self.sol, self.x
        if sol.x is not x and self.refit:   # the last change of x was not solved at these weights (robust start)
            sol = solve_logged(self.solve, problem, x, self.trace, False)
            x = sol.x
        if sol.x is not x:      # (refit False: the robust solution, not refitted)
            sol = replace(sol, x=x, message=f"{sol.message}; then the outlier check's robust solution, not "
                                            f"refitted without the rows it flagged (refit=False)")
        if self.stuck is not None:
            sol = replace(sol, status=self.stuck.status, message=self.stuck.message)
        lin = self.linearised(problem, x)
        if self.setup.touch is not None and sol.status != "diverged":
            check_group_redundancy(lin, everything.groups, self.given)
        noise = noise_estimate(problem, lin, self.estimate, self.vce_total)
        covariance = lin.inverse
        if self.weight_choice is not None:
            noise, covariance = self.reweighted(problem, lin, noise)
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
            notes += feature_notes(self.setup.touch, self.outliers)
        # (least squares: the cost from the normal equations of the noise estimate)
        cost = lin.ne.cost if problem.loss == "linear" else 0.5 * float(np.sum(problem.residuals(x) ** 2))
        fit = Fit(model, self.free, replace(sol, cost=cost), self.keep, tuple(self.outliers), noise,
                  self.trace.iterations, covariance=covariance, full_rank=lin.full_rank, all_rows=everything,
                  notes=tuple(notes), unremoved=self.unremoved,
                  refusals=tuple(r for r in dict.fromkeys(self.refusals) if r))
        return fit, problem

    def reweighted(self, problem: Problem, lin: Linearised, noise):
        """The noise estimate and covariance of a fit whose orientation was weighted as noisier
        than it is (:meth:`rotation_weight`): its noise as its residuals give it, and the
        covariance of a fit so weighted (A^-1 (A_pos + c A_rot) A^-1, c its residuals' reduced
        chi-square: the weighting's own A^-1 overstated the orientation error 1.4 times); the
        note says so."""
        c = max(noise.chi2_rot, 0.0)
        actual = problem.sigma_rot * math.sqrt(c)
        noise = replace(noise, rotation=actual, chi2_rot=1.0, chi2=noise.chi2 - lin.ne.rss_rot + lin.red_rot)
        covariance = lin.inverse @ (noise.chi2_pos * lin.ne.A_pos + c * lin.ne.A_rot) @ lin.inverse
        self.notes.append(self.weight_choice.note(problem.sigma_rot, actual))
        return noise, covariance

    def tails(self, problem: Problem, x: np.ndarray, lin: Linearised) -> list[str]:
        """The data-consistency rule on the final fit (:mod:`calib.calibration.plausibility`):
        heavy tails (the least-squares noise level above ROBUST_CHECK_INFLATION times the robust
        one) are judged against the high-breakdown fit where the passes did not judge these rows
        there (a refusal when more than half of them lie far from it), else noted with their
        figures."""
        everything, red = self.everything, lin.redundancies(len(self.lv))
        tails = leftover_gross(everything, x, self.keep, red, self.lv, self.given, self.outlier_k)
        if not tails.heavy:
            return []
        beyond = len(self.outliers)
        if not self.trimmed_last:
            judged = judge_rows(everything, problem, x, self.keep, self.rows, self.outlier_k, given=self.given,
                                red=red, few=True, options=self.solve.options, trace=self.trace)
            if judged.breakdown:
                self.refusals.append(judged.breakdown)
                return []
            beyond += len(judged.outliers)
        return [replace(tails, rows=len(self.rows), beyond=beyond).note()]


#: A feature of touch data that loses this share of its rows to the outlier check is named.
FEATURE_FLAGGED_SHARE = 0.25


def feature_notes(touch, outliers) -> list[str]:
    """A note per feature of touch data (``touch``, None: none) that lost FEATURE_FLAGGED_SHARE
    or more of its rows to the outlier check: rows that contradict the others of one feature are
    another feature touched under its name, more often than gross touches."""
    if touch is None:
        return []
    flagged = {o.row: o for o in outliers}
    notes = []
    for k, f in enumerate(touch.features):
        rows = touch.rows[touch.rows_of(k)]
        out = [flagged[r] for r in rows if r in flagged]
        if out and len(out) >= FEATURE_FLAGGED_SHARE * len(rows):
            notes.append(f"{len(out)} of the {len(rows)} rows of {f.kind} {f.id!r} lie "
                         f"{min(o.position_error for o in out) * 1e3:.3g} mm or more from it (rows "
                         f"{', '.join(str(o.row) for o in out)}): a second {f.kind} touched under its name?")
    return notes


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
             warm: bool = False, refit: bool = True, choose_weights: bool = False) -> tuple[Fit, Problem]:
    """:func:`fit_stage` of ``free`` with the solver, loss and noise levels of ``options``
    (sigma_pos / sigma_rot: given instead of the options' ones when not None; warm, refit,
    choose_weights: see :func:`fit_stage`)."""
    solve = solver_for(setup, free, options.method, options.lm, options.max_rounds, options.fixed_rounds,
                        options.lm_variant)
    return fit_stage(setup, free, solve, sigma_pos=options.sigma_pos if sigma_pos is None else sigma_pos,
                     sigma_rot=options.sigma_rot if sigma_rot is None else sigma_rot, loss=options.loss,
                     loss_scale=options.loss_scale, outlier_k=outlier_k, keep=keep, kin=kin,
                     rank_deficit=rank_deficit, warm=warm, refit=refit, sigma_touch=options.sigma_touch,
                     choose_weights=choose_weights)


@dataclass(frozen=True, eq=False)
class LeastSquares:
    """The least-squares estimator: the noise-weighted fit of the chosen set by the options'
    method, its noise levels estimated (variance components) unless given, its robust loss and
    outlier check (:func:`fit_stage`).

    start : a model near the solution to start from (the joint terms' chosen model, linearised at
    the geometric solution: a few LM iterations instead of the method's scheme), or None (the
    method's scheme from the setup's start); suspect : (N_cal,) bool, rows to start without
    (the geometric fit's outliers), taken back when the model explains them. Touch data: the
    parameter set decided again at the fitted model (:meth:`second_pass`)."""

    start: RobotModel | None = None
    suspect: np.ndarray | None = None
    name: str = "least-squares"

    def fit(self, setup: Setup, choice, options: CalibrationOptions, kin: ChainKinematics) -> Estimate:
        warm = self.start is not None and not choice.deficit
        if warm:
            setup = replace(setup, start=self.start, suspect=self.suspect)
        fit, problem = fit_with(setup, choice.free, options, outlier_k=options.outlier_k, kin=kin,
                                rank_deficit=choice.deficit, warm=warm, choose_weights=True)
        if setup.touch is not None and fit.solver.status != "diverged":
            return self.second_pass(setup, choice, options, kin, fit, problem)
        return Estimate(fit, problem, choice.label, {"kind": self.name, "param_set": choice.label}, choice=choice)

    def second_pass(self, setup: Setup, choice, options: CalibrationOptions, kin: ChainKinematics, fit: Fit,
                    problem) -> Estimate:
        """Touch data: the parameter set decided again at the first fit's model, and the fit with
        it when it is larger and lowers the cost significantly. Ties and "no effect" are decided
        at an idealised model (exact right angles, zero small lengths); a robot whose errors are
        larger than that idealisation snaps (1 mm, 0.05 rad: a tool point millimetres off the last
        axis) breaks some of them (the last joint's offset then moves the tool point), and holding
        those parameters nominal leaves residuals of several times the noise (UR10, errors of 5 mm
        / 10 mrad: 3 times, the tool positions 2-5 times the Cramer-Rao prediction; with the
        second pass at the noise and the prediction). Kept when the likelihood-ratio statistic of
        the extra parameters, on the rows both fits kept at the second fit's noise levels, exceeds
        its chi-square 99 % point."""
        from calib.calibration.estimators.robust import at_levels
        from calib.calibration.parameters import choose_touch_parameters
        from calib.errors import DataError

        first = Estimate(fit, problem, choice.label, {"kind": self.name, "param_set": choice.label}, choice=choice)
        try:
            again = choose_touch_parameters(setup, options, at=fit.model, first=choice.free)
        except DataError:       # (the first fit's model is far from any the rows determine: judged as it is)
            return first
        extra = set(again.free) - set(choice.free)
        if not extra or not set(choice.free) <= set(again.free) or \
                problem.n_residuals <= len(again.free) + problem.n_free - len(choice.free):
            return first
        n_robot = len(choice.free)
        start = replace(setup, start=fit.model,
                        features=replace(setup.features, values=fit.solver.x[n_robot:].copy()))
        fit2, problem2 = fit_with(start, again.free, options, outlier_k=options.outlier_k, kin=kin, warm=True,
                                  keep=fit.keep)
        both = fit.keep & fit2.keep
        levels = problem2.levels
        r1 = at_levels(fit.all_rows, levels).derived(keep=both).residuals(fit.solver.x)
        r2 = at_levels(fit2.all_rows, levels).derived(keep=both).residuals(fit2.solver.x)
        from scipy.stats import chi2

        if r1 @ r1 - r2 @ r2 <= chi2.ppf(0.99, len(extra)):
            return first
        return Estimate(fit2, problem2, again.label, {"kind": self.name, "param_set": again.label}, choice=again)

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
