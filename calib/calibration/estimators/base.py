"""What every estimator of :mod:`calib.calibration.estimators` returns, and the protocol they share.

* :class:`Fit`: one shape whatever the estimator (least squares, its robust loss and outlier
  check; EB-MAP; model selection over candidate sets): the identified model, its covariance,
  the noise levels (:class:`NoiseEstimate`), the rows kept and the outliers, the solver's status,
  the prior of a regularised fit.
* :class:`Estimate`: a :class:`Fit` with the weighted problem it ended on (which the statistics
  and cross-validation stages take), the parameter set's label and the estimator's record.
* :class:`Estimator`: ``fit(setup, choice, options, kin) -> Estimate``, as scikit-learn's
  estimators share one ``fit``; :func:`calib.calibration.estimators.resolve.resolve_estimator`
  is the one place that decides which runs.
* The least-squares linearisation at a solution (:class:`Linearised`) and the variance-component
  estimation's figures from it (:func:`noise_estimate`, :func:`vce_fixed_point`), which every
  estimator reports its noise levels with.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from calib.calibration.accuracy.errors import AccuracyStats
from calib.calibration.estimators.outlier import Outlier
from calib.calibration.options import VCE_RTOL, CalibrationOptions
from calib.calibration.parameters import ParameterChoice
from calib.calibration.prepare import Setup
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.solvers.inverse import normal_inverse
from calib.solvers.lm import SolverResult
from calib.solvers.normal_equations import NormalEquations
from calib.solvers.problem import Problem

__all__ = ["NoiseEstimate", "GroupFit", "Fit", "Estimate", "Estimator", "Linearised", "linearised",
           "vce_fixed_point", "noise_estimate", "chi2_p_value"]


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
    touch (m per component), redundancy_touch, chi2_touch : the touch rows' group (None, 0, None
    without touch rows); with touch rows alone ``position`` is the unused default weight of the
    absent measured positions.
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
    touch: float | None = None
    redundancy_touch: float = 0.0
    chi2_touch: float | None = None

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
        return chi2_p_value(self.chi2, self.dof)

    def to_dict(self) -> dict:
        if self.touch is not None:
            return {"touch_mm": self.touch * 1e3, "position_mm": self.position * 1e3, "rotation_rad": self.rotation,
                    "estimated": self.estimated, "iterations": self.iterations, "reduced_chi2": self.reduced_chi2,
                    "dof": self.dof}
        return {"position_mm": self.position * 1e3, "rotation_rad": self.rotation,
                "estimated": self.estimated, "iterations": self.iterations,
                "reduced_chi2": self.reduced_chi2, "dof": self.dof,
                "chi2_test": None if self.estimated else {
                    "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                    "reduced_chi2_position": self.chi2_pos, "reduced_chi2_rotation": self.chi2_rot}}


#: The residual groups of a fit, their unit and their name in reports.
GROUP_NAMES = {"touch": ("m", "touch residuals"), "position": ("m", "measured positions"),
               "rotation": ("rad", "measured rotations")}


@dataclass(frozen=True)
class GroupFit:
    """One residual group of a fit of residual blocks (touch rows, and the rows measured by an
    instrument in the same data): ``"touch"`` (metres per component), ``"position"`` /
    ``"rotation"`` (metres / radians per axis). rows, components : its rows and residual
    components (the kept ones); rms_before / rms_after : RMS of its components at the start (the
    nominal model, the features fitted to it, the meas frame at the measured rows' registration)
    and at the solution; sigma : the noise its uncertainties are at (the given one, else
    ``estimated``); given : whether it was given; estimated : from the residuals (its weighted
    residual sum of squares over its redundancy); redundancy : its components minus its share of
    the fitted unknowns; cv_rms : RMS of its held-out components (None without cross-validation)."""

    name: str
    rows: int
    components: int
    rms_before: float
    rms_after: float
    sigma: float
    given: bool
    estimated: float
    redundancy: float
    cv_rms: float | None = None

    @property
    def unit(self) -> str:
        return GROUP_NAMES[self.name][0]

    def to_dict(self) -> dict:
        f, u = (1e3, "mm") if self.unit == "m" else (1.0, "rad")
        return {"name": self.name, "rows": self.rows, "components": self.components,
                f"rms_before_{u}": self.rms_before * f, f"rms_after_{u}": self.rms_after * f,
                f"noise_{u}": self.sigma * f, "noise_given": self.given, f"noise_estimated_{u}": self.estimated * f,
                "redundancy": self.redundancy,
                f"held_out_rms_{u}": None if self.cv_rms is None else self.cv_rms * f}

    def format(self) -> str:
        f, u = (1e3, "mm") if self.unit == "m" else (1.0, "rad")
        text = (f"{GROUP_NAMES[self.name][1]} ({self.rows} rows, {self.components} components): RMS "
                f"{self.rms_before * f:.4g} {u} before, {self.rms_after * f:.4g} {u} after; noise estimated "
                f"{self.estimated * f:.4g} {u}" + (f", given {self.sigma * f:.4g} {u}" if self.given else ""))
        if self.cv_rms is not None:
            text += f"; held out {self.cv_rms * f:.4g} {u}"
        return text


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


@dataclass(frozen=True, eq=False, repr=False)     # (array fields: nothing compares or prints them)
class Linearised:
    """The least-squares normal equations ``ne`` of a problem's rows at a solution, their
    (pseudo-)inverse ``inverse`` (the covariance of the free parameters, SI units; ``full_rank``
    False for a pseudo-inverse) and each group's redundancy: its number of residual components
    minus its share tr(A^-1 A_g) of the rank."""

    ne: NormalEquations
    inverse: np.ndarray
    full_rank: bool
    red_pos: float
    red_rot: float
    red_touch: float = 0.0

    def redundancies(self, n: int = 2) -> tuple[float, ...]:
        """The first ``n`` groups' redundancies: (position, rotation[, touch])."""
        return (self.red_pos, self.red_rot, self.red_touch)[:n]


def linearised(problem: Problem, x: np.ndarray) -> Linearised:
    """The :class:`Linearised` of ``problem``'s rows at x (least squares whatever its loss)."""
    ne = problem.derived(loss="linear").normal_equations(x)
    Ainv, full_rank = normal_inverse(ne.A)
    share_p = float(np.trace(Ainv @ ne.A_pos)) if ne.A_pos is not None else 0.0
    share_r = float(np.trace(Ainv @ ne.A_rot)) if ne.A_rot is not None else 0.0
    if ne.A_touch is None:
        return Linearised(ne, Ainv, full_rank, ne.n_pos - share_p, ne.n_rot - share_r)
    share_t = float(np.trace(Ainv @ ne.A_touch))
    return Linearised(ne, Ainv, full_rank, ne.n_pos - share_p, ne.n_rot - share_r, ne.n_touch - share_t)


def vce_fixed_point(ne: NormalEquations, sigmas: tuple[float, float], start: tuple[float, float],
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


def noise_estimate(problem: Problem, lin: Linearised, estimated: bool, iterations: int) -> NoiseEstimate:
    """The noise levels of ``problem`` and the residuals' agreement with them, from its
    linearisation ``lin`` at the solution."""
    ne, red_p, red_r = lin.ne, lin.red_pos, lin.red_rot
    dof = red_p + red_r
    chi2 = ne.rss_pos + ne.rss_rot
    has_rot = problem.has_orientation
    touch = {}
    if ne.A_touch is not None:
        dof, chi2 = dof + lin.red_touch, chi2 + ne.rss_touch
        touch = {"touch": problem.sigma_touch, "redundancy_touch": lin.red_touch,
                 "chi2_touch": ne.rss_touch / max(lin.red_touch, 1e-300)}
    return NoiseEstimate(problem.sigma_pos, problem.sigma_rot if has_rot else None, estimated,
                         red_p, red_r, ne.rss_pos / max(red_p, 1e-300),
                         ne.rss_rot / max(red_r, 1e-300) if has_rot else None, chi2, dof, iterations, **touch)


#: A residual group whose noise is estimated needs at least this redundancy (its components
#: minus its share of the unknowns): below it the fit passes through its rows and the "estimate"
#: would be the weight it started with.
MIN_GROUP_REDUNDANCY = 1.0
_GROUP_ADVICE = {"touch": ("touch rows", "--sigma-touch-mm, API sigma_touch"),
                 "position": ("measured rows", "--sigma-pos-mm, API sigma_pos"),
                 "rotation": ("measured rows", "--sigma-rot-rad, API sigma_rot")}


def check_group_redundancy(lin: Linearised, groups, given) -> None:
    """Raise DataError, naming what to add, when a residual group of a fit of residual blocks
    whose noise is estimated (``given``: per group of ("position", "rotation", "touch"), None:
    estimated) has a redundancy below MIN_GROUP_REDUNDANCY (3 measured positions mixed with touch
    rows: 9 components, 8.5 of them spent on the meas frame and the scale; their noise was
    printed as 'estimated' at the weight it started with, and the prediction in the meas frame
    at it). groups : the groups the fit has."""
    from calib.errors import DataError

    for k, (g, red) in enumerate(zip(("position", "rotation", "touch"), lin.redundancies(3))):
        if g in groups and given[k] is None and red < MIN_GROUP_REDUNDANCY:
            rows, flag = _GROUP_ADVICE[g]
            raise DataError(f"the {GROUP_NAMES[g][1]} have a redundancy of {red:.2g} (their components minus their "
                            f"share of the unknowns, below {MIN_GROUP_REDUNDANCY:g}): the fit passes through them and "
                            f"their noise cannot be estimated; add {rows}, or give their noise ({flag})")


def chi2_p_value(chi2: float, dof: float) -> float:
    """Two-sided p-value of a chi-square ``chi2`` with ``dof`` degrees of freedom: residuals far
    below the given noise disagree with it as much as far above (scipy.special's regularised
    incomplete gamma functions: scipy.stats costs seconds to import)."""
    from scipy.special import gammainc, gammaincc

    k = max(dof, 1e-9) / 2.0
    return float(min(1.0, 2.0 * min(gammaincc(k, chi2 / 2.0), gammainc(k, chi2 / 2.0))))


@dataclass(frozen=True, eq=False, repr=False)     # (a fit and its problem: nothing compares or prints it)
class Estimate:
    """What an :class:`Estimator`'s ``fit`` returns, whatever the estimator.

    fit : the :class:`Fit`; problem : the weighted problem of the kept rows at the fit's noise
    levels (statistics and cross-validation linearise it at ``fit.solver.x``); label : the
    parameter set as reports name it ("base", "auto: <chosen>", "eb-map", ...); record : the
    estimator's own record (the result's ``estimator`` field: its kind, its prior scales, ...);
    selection : the model selection's table when the estimator chose among candidate sets."""

    fit: Fit
    problem: Problem
    label: str
    record: dict
    selection: object | None = None
    #: the parameter choice the fit was made with (touch data: decided again at a first fit's
    #: model, :class:`~calib.calibration.estimators.least_squares.LeastSquares`); None: the given one
    choice: ParameterChoice | None = None


class Estimator(Protocol):
    """An estimator of the robot's parameters: ``fit`` identifies ``choice.free`` (the parameter
    choice of :func:`calib.calibration.parameters.choose_parameters`) on the calibration rows of
    ``setup`` with ``options`` and returns an :class:`Estimate`. ``name`` names it in reports."""

    name: str

    def fit(self, setup: Setup, choice: ParameterChoice, options: CalibrationOptions,
            kin: ChainKinematics) -> Estimate: ...
