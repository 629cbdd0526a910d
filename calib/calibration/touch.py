"""Calibration from touch data (issue 24): the tool point touching fixed points, planes and
spheres of the cell, whose locations are identified with the robot's parameters, with the rows
measured by an instrument in the same data when there are some.

Stages, each callable on its own:

* :mod:`calib.calibration.touch_design`: :func:`check_touch_design` (designs refused, naming
  what to add) and :func:`touch_identifiability` (which parameters the rows determine; re-exported
  here).
* :func:`calibrate_touch` fits the identifiable robot parameters and the features by calib's LM
  (:class:`calib.solvers.touch_problem.TouchProblem`) from the nominal model (with measured
  rows, its meas frame first moved onto them by a rigid registration) and the features fitted
  to its tool points, each residual group's noise estimated (variance components), and returns a
  :class:`TouchResult`. A second pass decides the set again at the first fit's model (errors
  beyond the idealised nominal's snaps untie parameters); rows far off their feature (or
  measured rows far off the fit) are dropped as outliers and the rest fitted again; the
  held-out residuals are cross-validated (:func:`cross_validate_touch`).
* :mod:`calib.calibration.touch_accuracy`: the Cramer-Rao prediction of the calibrated tool
  positions' error after a best-fit rigid registration (without measured rows the base frame
  stays nominal: what a robot then located by touching its work sees; with them, also in the
  meas frame), and the registered error to a known truth.
"""
from __future__ import annotations

from dataclasses import field, replace
from typing import Sequence

import numpy as np

from calib.dataclass_code import dataclass
from calib.calibration.options import VCE_MAX_ITERATIONS, VCE_RTOL
from calib.calibration.plausibility import chain_implausibility, length_notes
from calib.calibration.touch_design import (MEAS_FRAME_MIN_ROWS, MIN_ROWS, PARAM_CHOICES, SCALE_ADVICE, SIGMA_TOUCH_M,  # noqa: F401
                                            TouchIdentifiability, check_touch_design, consistent_rows,
                                            touch_identifiability)
from calib.checks import check_choice, check_instance, check_int, check_number
from calib.errors import DataError, ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.spatial import best_fit_motion
from calib.model.touch import FeatureStart, TouchData, initial_features, plane_normals
from calib.solvers.lm import LMOptions, SolverResult, levenberg_marquardt
from calib.solvers.inverse import normal_inverse
from calib.solvers.problem import CHI2_ESCAPE
from calib.solvers.touch_problem import TouchProblem

#: Rows whose residual exceeds this many robust standard deviations are dropped (as calibrate's
#: --outlier-k).
OUTLIER_K = 5.0
#: A residual group's noise, its unit and its name in reports.
GROUP_UNITS = {"touch": "m", "position": "m", "rotation": "rad"}
_SIGMA_ARG = {"touch": "sigma", "position": "sigma_pos", "rotation": "sigma_rot"}


@dataclass(frozen=True)
class GroupFit:
    """One group of residuals of a touch fit: ``"touch"`` (the touch constraints, metres),
    ``"position"`` / ``"rotation"`` (the rows measured by an instrument, metres / radians per
    axis). rows, components : its rows and residual components; rms_before / rms_after : RMS of
    its components at the start (the nominal model, features fitted to it, the meas frame from
    the measured rows in closed form) and at the solution; sigma : the noise the uncertainties are
    at (the given one, else ``estimated``); given : whether it was given; estimated : from the
    residuals (variance-component estimation: its weighted residual sum of squares over its
    redundancy, components minus its share of the fitted unknowns); redundancy; cv_rms : RMS of
    its held-out components (None without cross-validation or held-out rows)."""

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
        return GROUP_UNITS[self.name]

    def to_dict(self) -> dict:
        f = 1e3 if self.unit == "m" else 1.0
        u = "mm" if self.unit == "m" else "rad"
        return {"name": self.name, "rows": self.rows, "components": self.components,
                f"rms_before_{u}": self.rms_before * f, f"rms_after_{u}": self.rms_after * f,
                f"noise_{u}": self.sigma * f, "noise_given": self.given, f"noise_estimated_{u}": self.estimated * f,
                "redundancy": self.redundancy,
                f"held_out_rms_{u}": None if self.cv_rms is None else self.cv_rms * f}

    def format(self) -> str:
        f, u = (1e3, "mm") if self.unit == "m" else (1.0, "rad")
        what = {"touch": "touch residuals", "position": "measured positions", "rotation": "measured rotations"}
        text = (f"{what[self.name]} ({self.rows} rows, {self.components} components): RMS {self.rms_before * f:.4g} {u} "
                f"before, {self.rms_after * f:.4g} {u} after; noise estimated {self.estimated * f:.4g} {u}"
                + (f", given {self.sigma * f:.4g} {u}" if self.given else ""))
        if self.cv_rms is not None:
            text += f"; held out {self.cv_rms * f:.4g} {u}"
        return text


@dataclass(frozen=True, eq=False)
class TouchResult:
    """What :func:`calibrate_touch` returns.

    robot : the calibrated model (the held parameters at their nominal values; u nominal).
    identifiability : the parameter choice. free : names of the fitted robot parameters.
    feature_names : (3 K,) names; feature_values, feature_std : (3 K,) SI (see
    :mod:`calib.model.touch`); plane_normals : (K, 3) unit normals (zeros for other kinds);
    plane_refs : (K, 3, 3). rms_before / rms_after : metres, RMS of the residual components at the
    nominal model (features fitted to it) and at the solution. sigma : metres, the noise the
    uncertainties are at (the given one, else sigma_estimated); sigma_given : whether it was
    given; sigma_estimated : from the residuals, sqrt(rss / (n_res - n_free)).
    std : (n_free_robot,) standard deviations of the robot parameters (SI, at ``sigma``);
    covariance : (m, m) of all free unknowns (robot, then features) at ``sigma``.
    status : the LM's status, or "implausible" (converged to a result that cannot be trusted:
    residuals far above a given noise, link lengths far from the nominal), message : why.
    solver : the LM's result. n_rows, n_residuals : the data used. cv_rms : metres, the RMS of
    the held-out touch residual components over ``cv_folds`` folds (None without).
    groups : a :class:`GroupFit` per residual group (touch, and with measured rows position and
    rotation); n_measured : the measured rows used (their outliers, as the touch rows', in
    ``outliers`` by line number). nominal_scale : the scale was left undetermined (no known
    length) and held at the nominal on request.
    notes : one-line remarks (the meas frame's closed-form start).
    rms_before, rms_after, sigma, sigma_given, sigma_estimated are those of the touch group.
    """

    robot: RobotModel
    identifiability: TouchIdentifiability
    free: tuple[str, ...]
    feature_names: tuple[str, ...]
    feature_values: np.ndarray = field(repr=False)
    feature_std: np.ndarray = field(repr=False)
    plane_normals: np.ndarray = field(repr=False)
    plane_refs: np.ndarray = field(repr=False)
    rms_before: float
    rms_after: float
    sigma: float
    sigma_given: bool
    sigma_estimated: float
    std: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)
    solver: SolverResult = field(repr=False)
    n_rows: int
    n_residuals: int
    cv_rms: float | None = None
    cv_folds: int = 0
    status: str = "converged"
    message: str = ""
    outliers: tuple[tuple[int, float], ...] = ()
    groups: tuple[GroupFit, ...] = ()
    n_measured: int = 0
    nominal_scale: bool = False
    notes: tuple[str, ...] = ()

    @property
    def success(self) -> bool:
        return self.status == "converged"

    def group(self, name: str) -> GroupFit | None:
        """The :class:`GroupFit` called ``name`` ("touch", "position", "rotation"), or None."""
        return next((g for g in self.groups if g.name == name), None)

    def format(self) -> str:
        lines = [f"touch calibration: {self.n_rows} touch rows"
                 + (f" and {self.n_measured} measured rows" if self.n_measured else "")
                 + f", {self.n_residuals} residual components, "
                 f"{len(self.free)} robot parameters and {len(self.feature_names)} feature unknowns fitted"]
        if self.n_measured:
            lines += [f"  {g.format()}" for g in self.groups]
        else:
            lines.append(f"residual RMS {self.rms_before * 1e3:.4f} mm before, {self.rms_after * 1e3:.4f} mm after "
                         f"(noise estimated {self.sigma_estimated * 1e3:.4f} mm"
                         + (f", given {self.sigma * 1e3:.4f} mm)" if self.sigma_given else ")"))
        if self.nominal_scale:
            lines.append("no known length: the scale is held at the nominal (nominal_scale); the model "
                         "is right up to scale")
        lines += list(self.notes)
        if self.outliers:
            lines.append(f"dropped {len(self.outliers)} outlier row(s): " + ", ".join(
                f"row {row} ({e * 1e3:.3f} mm)" for row, e in self.outliers))
        if self.cv_rms is not None:
            lines.append(f"held-out residual RMS ({self.cv_folds}-fold cross-validation): {self.cv_rms * 1e3:.4f} mm"
                         + "".join(f", measured positions {g.cv_rms * 1e3:.4f} mm" if g.unit == "m" else
                                   f", measured rotations {g.cv_rms:.3g} rad" for g in self.groups
                                   if g.name != "touch" and g.cv_rms is not None))
        for name, v, s in zip(self.feature_names, self.feature_values, self.feature_std):
            unit, f = ("rad", 1.0) if name[-2:] in ("_a", "_b") else ("mm", 1e3)
            lines.append(f"  {name:<24} {v * f:12.4f} +- {s * f:.4f} {unit}")
        return "\n".join(lines)


# ---------------------------------------------------------------- fit
@dataclass(frozen=True, eq=False)
class _Fitted:
    """One fit: the start model (``robot`` with, for measured rows, its meas frame moved to the
    closed-form estimate), the weighted problem at the final noise levels, the features' start,
    the LM result, the unweighted residuals at the start."""

    start_robot: RobotModel
    prob: TouchProblem
    start: FeatureStart
    sol: SolverResult
    r0: np.ndarray


def calibrate_touch(robot: RobotModel, data: TouchData, *, params: str = "auto",
                    sigma: float | None = None, sigma_pos: float | None = None, sigma_rot: float | None = None,
                    cv: int = 5, seed: int = 0, outlier_k: float | None = OUTLIER_K,
                    nominal_scale: bool = False, options: LMOptions = LMOptions()) -> TouchResult:
    """Calibrate ``robot`` from touch rows (see the module docstring), and the rows measured by
    an instrument in the same data (``data.measured``).

    robot : the nominal model (the start; u stays at it without measured rows). data : the rows
    (q in ``robot``'s chain order). params : "auto" (the identifiable geometric parameters) or
    "tool" (the flange->tool offset only, the classic TCP calibration; with measured rows the
    meas frame too). sigma : metres, the touch noise per residual component, or None to estimate
    it from the residuals; sigma_pos (m) / sigma_rot (rad): the measured rows' noise per axis,
    or None to estimate it. With measured rows, each group's noise is estimated by
    variance-component estimation (re-weighted fits until the levels change by less than
    VCE_RTOL); the uncertainties and the prediction are at the noise levels, and a given one is
    checked against its group's residuals (reduced chi-square above CHI2_ESCAPE: status
    "implausible"). cv : folds of the cross-validated held-out residuals
    (:func:`cross_validate_touch`; 0 or 1: none), drawn with ``seed``. outlier_k : after the
    fit, rows whose RMS residual per component exceeds outlier_k times their group's robust
    standard deviation (1.4826 times the median absolute residual; measured rows by their
    position) are dropped and the rest fitted again, once (a row naming the wrong feature, a
    slipped probe); None: none dropped. nominal_scale : with no known length (no sphere, no
    measured row) the scale is not determined and ``params="auto"`` is refused (the tool
    positions would err by the longest length's error over its length times their distance,
    which no noise-based prediction covers: a median 20-22 times the prediction over 20 seeds in
    scripts/touch_acceptance.py); True holds it at the nominal instead.
    Returns a :class:`TouchResult`.
    """
    check_robot(robot)
    check_instance(data, "data", TouchData, "calib.read_touch or calib.simulate_touch")
    check_choice(params, "params", PARAM_CHOICES)
    check_instance(options, "options", LMOptions, "calib.solvers.lm.LMOptions")
    for name, v, hi in (("sigma", sigma, 1.0), ("sigma_pos", sigma_pos, 1.0), ("sigma_rot", sigma_rot, 1.0)):
        if v is not None:
            check_number(v, name, minimum=1e-9, maximum=hi)
    check_int(cv, "cv", minimum=0, maximum=10_000)
    check_int(seed, "seed", minimum=0)
    if outlier_k is not None:
        check_number(outlier_k, "outlier_k", minimum=1.0)
    if not isinstance(nominal_scale, bool):
        raise ParameterError(f"nominal_scale must be True or False, got {nominal_scale!r}")
    given = {"touch": sigma, "position": sigma_pos, "rotation": sigma_rot}
    fit = _calibrate(robot, data, params, given, options, nominal_scale)
    outliers = ()
    if outlier_k is not None:
        bad_t, bad_m = _outlier_rows(fit, outlier_k)
        if bad_t.any() or bad_m.any():
            outliers = tuple(sorted(
                [(int(row), float(e)) for row, e in zip(data.rows[bad_t], fit[1].prob.row_residuals(fit[1].sol.x)[bad_t])]
                + ([(int(row), float(e)) for row, e in zip(data.measured.rows[bad_m],
                                                          fit[1].prob.measured_row_residuals(fit[1].sol.x)[bad_m])]
                   if bad_m.any() else [])))
            try:
                if bad_m.any():
                    data = data.measured_subset(~bad_m)
                data = data.subset(~bad_t)
                fit = _calibrate(robot, data, params, given, options, nominal_scale)
            except DataError as exc:
                shown = ", ".join(str(row) for row, _ in outliers)
                raise DataError(f"after dropping the outlier rows {shown} (residuals above {outlier_k:g} "
                                f"robust standard deviations; outlier_k=None keeps them): {exc}") from None
    ident, fitted = fit
    result = _result(robot, data, given, ident, fitted, nominal_scale)
    if cv > 1:
        noise = {g.name: g.sigma for g in result.groups}
        # (the folds start at the full fit's start: a fold's few measured rows may not place the meas frame)
        held = _cross_validate(fitted.start_robot, data, ident.robot_free, noise, cv, seed, options)
        result = replace(result, cv_rms=held.get("touch"), cv_folds=cv,
                         groups=tuple(replace(g, cv_rms=held.get(g.name)) for g in result.groups))
    return replace(result, outliers=outliers)


def _outlier_rows(fit, outlier_k: float) -> tuple[np.ndarray, np.ndarray]:
    """(touch rows, measured rows) masks of the rows beyond outlier_k robust standard
    deviations of their group."""
    prob, x = fit[1].prob, fit[1].sol.x
    r = prob.evaluate(x, jacobian=False)[0]
    rows = prob.row_residuals(x)
    bad_t = rows > outlier_k * 1.4826 * np.median(np.abs(r[prob.slices["touch"]]))
    bad_m = np.zeros(prob.n_measured, bool)
    if prob.n_measured:
        rm = prob.measured_row_residuals(x)
        bad_m = rm > outlier_k * 1.4826 * np.median(np.abs(r[prob.slices["position"]]))
    return bad_t, bad_m


def _calibrate(robot, data, params, given, options, nominal_scale):
    """(identifiability, :class:`_Fitted`) of the fit (with its second pass, :func:`_second_pass`)."""
    weights = _start_weights(given)
    ident = touch_identifiability(robot, data, params=params, **weights)
    if ident.scale_free and params == "auto" and not nominal_scale:
        raise DataError("the rows fix no length (points and planes only, no sphere, no measured row): the "
                        "robot's scale is not determined; " + SCALE_ADVICE)
    fitted = _fit(robot, data, robot.indices(ident.robot_free), given, options, declared=True)
    second = _second_pass(robot, data, params, given, options, ident, fitted)
    if second is not None:
        ident, fitted = second
    _check_group_redundancy(fitted, given)
    return ident, fitted


#: A residual group whose noise is estimated needs at least this redundancy (its components
#: minus its share of the unknowns): below it the fit passes through its rows and the "estimate"
#: would be the weight it started with.
MIN_GROUP_REDUNDANCY = 1.0
_GROUP_ADVICE = {"touch": ("touch residuals", "touch rows", "--sigma-touch-mm, API sigma"),
                 "position": ("measured positions", "measured rows", "--sigma-pos-mm, API sigma_pos"),
                 "rotation": ("measured rotations", "measured rows", "--sigma-rot-rad, API sigma_rot")}


def _check_group_redundancy(fitted: _Fitted, given: dict) -> None:
    """Raise DataError, naming what to add, when a group whose noise is estimated has a
    redundancy below MIN_GROUP_REDUNDANCY (3 measured positions mixed with touch rows: 9
    components, 8.5 of them spent on the meas frame and the scale; its noise was printed as
    'estimated' at the weight it started with, and the prediction in the meas frame at it)."""
    levels = _noise_levels(fitted.prob, fitted.sol.x)
    for g, (_, red) in levels.items():
        if given[g] is None and red < MIN_GROUP_REDUNDANCY:
            what, rows, flag = _GROUP_ADVICE[g]
            raise DataError(f"the {what} have a redundancy of {red:.2g} (their components minus their share "
                            f"of the unknowns, below {MIN_GROUP_REDUNDANCY:g}): the fit passes through them and "
                            f"their noise cannot be estimated; add {rows}, or give their noise ({flag})")


def _start_weights(given: dict) -> dict:
    """The noise levels a fit starts weighted by: the given ones, else calib's defaults."""
    return {"sigma": given["touch"] or SIGMA_TOUCH_M, "sigma_pos": given["position"],
            "sigma_rot": given["rotation"]}


def _noise_levels(prob: TouchProblem, x: np.ndarray) -> dict:
    """Group -> (estimated noise, redundancy) at x: each group's weighted residual sum of
    squares over its redundancy (its components minus its share tr(A^-1 A_g) of the unknowns),
    times its weight's noise."""
    shares = prob.group_shares(x)
    Ainv = normal_inverse(sum(a for a, _, _ in shares.values()))[0]
    out = {}
    for g, (A_g, rss, n) in shares.items():
        red = n - float(np.trace(Ainv @ A_g))
        out[g] = (prob.sigma_of(g) * float(np.sqrt(rss / red)) if red > 0.5 else prob.sigma_of(g), red)
    return out


def _result(robot, data, given, ident, fitted: _Fitted, nominal_scale: bool) -> TouchResult:
    """The :class:`TouchResult` of a fit (without cross-validation and outliers)."""
    prob, start, sol, r0 = fitted.prob, fitted.start, fitted.sol, fitted.r0
    free = robot.indices(ident.robot_free)
    x = sol.x
    r = prob.evaluate(x, jacobian=False)[0]
    levels = _noise_levels(prob, x)
    noise = {g: given[g] if given[g] is not None else levels[g][0] for g in prob.slices}
    # the normal matrix at the noise levels (the fit's weights are the estimates to VCE_RTOL,
    # or the given noise, or for touch rows alone the default weight)
    shares = prob.group_shares(x)
    A = sum(a * (prob.sigma_of(g) / noise[g]) ** 2 for g, (a, _, _) in shares.items())
    cov = normal_inverse(A)[0]
    std_all = np.sqrt(np.maximum(np.diag(cov), 0.0))
    mr = len(free)
    F = prob.feature_values(x)
    normals = np.zeros((len(data.features), 3))
    planes = [k for k, f in enumerate(data.features) if f.kind == "plane"]
    if planes:
        normals[planes] = plane_normals(start.plane_refs[planes], F[planes, 0], F[planes, 1])[0]
    calibrated = fitted.start_robot.with_values(prob.full(x))
    status, message = sol.status, sol.message
    notes = chain_implausibility(robot, calibrated, "position")     # (the one rule: calib.calibration.plausibility)
    what = {"touch": "touch residuals", "position": "measured positions", "rotation": "measured rotations"}
    for g in prob.slices:
        est = levels[g][0]
        if given[g] is not None and (est / given[g]) ** 2 > CHI2_ESCAPE:
            notes.insert(0, f"the fit converged but its {what[g]} are {est / given[g]:.1f} times the given noise "
                            f"(reduced chi^2 {(est / given[g]) ** 2:.3g}): a wrong sigma, rows naming the wrong "
                            f"feature, or errors the model does not describe; omit the noise to estimate it")
    if notes and status == "converged":
        status, message = "implausible", notes[0]
    rows = {"touch": data.n_rows, "position": data.n_measured, "rotation": data.n_measured}
    groups = tuple(GroupFit(g, rows[g], sl.stop - sl.start, float(np.sqrt(np.mean(r0[sl] ** 2))),
                            float(np.sqrt(np.mean(r[sl] ** 2))), float(noise[g]), given[g] is not None,
                            float(levels[g][0]), float(levels[g][1]))
                   for g, sl in prob.slices.items())
    touch = groups[0]
    return TouchResult(
        robot=calibrated, identifiability=ident, free=ident.robot_free,
        feature_names=ident.features, feature_values=x[mr:].copy(), feature_std=std_all[mr:],
        plane_normals=normals, plane_refs=start.plane_refs,
        rms_before=touch.rms_before, rms_after=touch.rms_after,
        sigma=touch.sigma, sigma_given=touch.given, sigma_estimated=touch.estimated, std=std_all[:mr],
        covariance=cov, solver=sol, n_rows=data.n_rows, n_residuals=len(r), status=status,
        message=message, groups=groups, n_measured=data.n_measured, nominal_scale=bool(ident.scale_free
                                                                                      and nominal_scale),
        notes=_frame_note(robot, fitted.start_robot) + tuple(length_notes(robot, calibrated)))


def _frame_note(robot: RobotModel, start: RobotModel) -> tuple[str, ...]:
    """The note of a meas frame started at the measured rows' registration (its u are then
    relative to that start), or ()."""
    from calib.model.spatial import inverse, log3_batch

    dT = inverse(robot.T_meas_base_ref) @ start.T_meas_base_ref
    if np.array_equal(dT, np.eye(4)):
        return ()
    return (f"measurement->base initialised by a rigid registration onto the measured rows: "
            f"{np.linalg.norm(dT[:3, 3]) * 1e3:.1f} mm and {np.linalg.norm(log3_batch(dT[None, :3, :3])[0]):.3g} rad "
            f"from the nominal transform (u are relative to it)",)


def _second_pass(robot, data, params, given, options, ident, fitted: _Fitted):
    """The parameter set decided again at the first fit's model, and the fit with it when it is
    larger and lowers the cost significantly: (identifiability, :class:`_Fitted`), or None. Ties
    and "no effect" are decided at an idealised model (exact right angles,
    zero small lengths); a robot whose errors are larger than that idealisation snaps (1 mm,
    0.05 rad: a tool point millimetres off the last axis) breaks some of them (the last joint's
    offset then moves the tool point), and holding those parameters nominal leaves residuals of
    several times the noise (UR10, errors of 5 mm / 10 mrad: 3 times, the tool positions 2-5 times
    the Cramer-Rao prediction; with the second pass at the noise and the prediction). Kept when
    the likelihood-ratio statistic of the extra parameters exceeds its chi-square 99 % point
    (the residuals weighted by the noise levels of the second fit)."""
    prob, sol = fitted.prob, fitted.sol
    first = fitted.start_robot.with_values(prob.full(sol.x))
    again = touch_identifiability(first, data, params=params, first=ident.robot_free, require_redundancy=False,
                                  **_start_weights(given))
    extra = set(again.robot_free) - set(ident.robot_free)
    if not extra or not set(ident.robot_free) <= set(again.robot_free):
        return None
    if prob.n_residuals <= len(again.robot_free) + len(again.features):     # (no redundancy left)
        return None
    fitted2 = _fit(first, data, first.indices(again.robot_free), given, options, declared=True)
    prob2, sol2 = fitted2.prob, fitted2.sol
    levels = _noise_levels(prob2, sol2.x)
    w = np.empty(prob2.n_residuals)
    for g, sl in prob2.slices.items():
        w[sl] = 1.0 / (given[g] if given[g] is not None else levels[g][0])
    r1 = prob.evaluate(sol.x, jacobian=False)[0] * w
    r2 = prob2.evaluate(sol2.x, jacobian=False)[0] * w
    from scipy.stats import chi2

    if r1 @ r1 - r2 @ r2 <= chi2.ppf(0.99, len(extra)):
        return None
    # (the first fit moved only its free parameters: the fixed ones of prob2 are robot's)
    return again, fitted2


def _fit(robot: RobotModel, data: TouchData, free: np.ndarray, given: dict, options: LMOptions,
         declared: bool, noise: dict | None = None) -> _Fitted:
    """The fit of the robot parameters ``free`` and the features, from ``robot`` (with measured
    rows, its meas frame first moved onto them: :func:`_meas_frame_start`) and the features fitted
    to its tool points; ``declared``: the free set is identifiable (no direction held, see
    Problem). given : group -> the given noise or None (estimated: with measured rows the
    groups' weights change the fit, which is repeated at the estimated levels until they change
    by less than VCE_RTOL). noise : group -> fixed weights (cross-validation folds: no estimation)."""
    robot = _meas_frame_start(robot, data)
    kin = ChainKinematics(robot)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    weights = _start_weights(given) if noise is None else {_SIGMA_ARG[g]: v for g, v in noise.items()}
    prob = TouchProblem(kin, data, robot.values, free, start.plane_refs, **weights)
    x0 = prob.x0(start.values)
    if declared:
        prob.set_rank_deficit(0)
    r0 = prob.evaluate(x0, jacobian=False)[0]
    sol = levenberg_marquardt(prob, x0, options=options)
    estimate = [g for g in prob.slices if given[g] is None]
    if noise is None and len(prob.slices) > 1 and estimate:
        for _ in range(VCE_MAX_ITERATIONS):
            if sol.status == "diverged":
                break
            levels = _noise_levels(prob, sol.x)
            new = {g: max(levels[g][0], 1e-12) for g in estimate}
            change = max(abs(new[g] / prob.sigma_of(g) - 1.0) for g in estimate)
            if change < VCE_RTOL:
                break
            prob = prob.derived(**{_SIGMA_ARG[g]: v for g, v in new.items()})
            if declared:
                prob.set_rank_deficit(0)
            sol = levenberg_marquardt(prob, sol.x, options=options)
    return _Fitted(robot, prob, start, sol, r0)


def _meas_frame_start(robot: RobotModel, data: TouchData) -> RobotModel:
    """``robot`` with its meas frame moved by the best-fit rigid motion of its tool positions at
    the measured rows onto the measured positions (the instrument stands anywhere: a fit started
    at the nominal meas frame would not converge), when there are MEAS_FRAME_MIN_ROWS or more
    measured rows not on one line (:func:`check_touch_design`); else ``robot``. The reference
    transform moves, u keeps its value, as the measured pipeline's closed-form start does."""
    m = data.measured
    if m is None or m.n_poses < MEAS_FRAME_MIN_ROWS:
        return robot
    s = np.linalg.svd(m.position - m.position.mean(axis=0), compute_uv=False)
    if s[1] <= 1e-6 * max(s[0], 1e-300):
        return robot
    p = ChainKinematics(robot).frame_poses(m.q)[1]
    R, t, _ = best_fit_motion(p, m.position)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t
    return replace(robot, T_meas_base_ref=X @ robot.T_meas_base_ref)


def cross_validate_touch(robot: RobotModel, data: TouchData, free: Sequence[str], *,
                         sigma: float = SIGMA_TOUCH_M, sigma_pos: float | None = None,
                         sigma_rot: float | None = None, k: int = 5, seed: int = 0,
                         options: LMOptions = LMOptions()) -> float:
    """RMS (metres) of the held-out touch residual components over ``k`` folds: each fold's rows
    (drawn feature by feature, so that every feature keeps rows in every fit; measured rows
    drawn among themselves) predicted by the robot parameters ``free`` and the features fitted
    to the other rows, weighted by the noise levels given (see :func:`calibrate_touch`'s
    ``groups`` for the measured rows' held-out figures)."""
    check_int(k, "k", minimum=2)
    noise = {"touch": sigma, "position": sigma_pos or SIGMA_POS_M, "rotation": sigma_rot or SIGMA_ROT_RAD}
    return _cross_validate(robot, data, free, noise, k, seed, options)["touch"]


def _cross_validate(robot, data, free, noise: dict, k: int, seed: int, options: LMOptions) -> dict:
    """Group -> RMS of its held-out residual components over ``k`` folds (see
    :func:`cross_validate_touch`), the fits weighted by ``noise`` (group -> level)."""
    rng = np.random.default_rng(seed)
    fold = np.empty(data.n_rows, int)
    for f in range(len(data.features)):
        rows = rng.permutation(data.rows_of(f))
        fold[rows] = (np.arange(len(rows)) + rng.integers(k)) % k
    fold_m = np.empty(data.n_measured, int)
    if data.n_measured:
        fold_m[rng.permutation(data.n_measured)] = (np.arange(data.n_measured) + rng.integers(k)) % k
    free_idx = robot.indices(free)
    none = {g: None for g in ("touch", "position", "rotation")}
    sq: dict = {}
    for j in range(k):
        test, test_m = fold == j, fold_m == j
        train = ~test
        if not test.any() and not test_m.any():
            continue
        if len(set(data.feature[train].tolist())) < len(data.features):
            raise DataError(f"{k}-fold cross-validation leaves a feature without rows: fewer folds, or more rows")
        fit_data = data.subset(train)
        if data.n_measured:
            fit_data = fit_data.measured_subset(~test_m)
        fitted = _fit(robot, fit_data, free_idx, none, options, declared=False,
                      noise={g: noise[g] for g in noise if g in ("touch", "position", "rotation")})
        x_fit = fitted.sol.x
        model = fitted.start_robot.with_values(fitted.prob.full(x_fit))
        if test.any():
            used = sorted(set(data.feature[test].tolist()))
            held_data = data.subset(test)
            held_data = replace(held_data, measured=None)
            held = TouchProblem(ChainKinematics(model), held_data, model.values, free_idx,
                                fitted.start.plane_refs[used], 1.0)
            x = np.concatenate([x_fit[:len(free_idx)], fitted.prob.feature_values(x_fit)[used].reshape(-1)])
            r = held.evaluate(x, jacobian=False)[0]
            _add(sq, "touch", r)
        if test_m.any():
            m = data.measured.subset(test_m)
            R, p = ChainKinematics(model).frame_poses(m.q)
            _add(sq, "position", (p - m.position).reshape(-1))
            if m.rotation is not None:
                from calib.model.spatial import log3_batch

                _add(sq, "rotation", log3_batch(R @ np.transpose(m.rotation, (0, 2, 1))).reshape(-1))
    return {g: float(np.sqrt(a / n)) for g, (a, n) in sq.items()}


def _add(sq: dict, group: str, r: np.ndarray) -> None:
    a, n = sq.get(group, (0.0, 0))
    sq[group] = (a + float(r @ r), n + len(r))
