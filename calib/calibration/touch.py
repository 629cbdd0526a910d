"""Calibration from touch data (issue 24): the tool point touching fixed points, planes and
spheres of the cell, whose locations are identified with the robot's parameters.

Stages, each callable on its own:

* :func:`check_touch_design` refuses designs that cannot calibrate anything useful, in one line
  naming what to add (a point touched from fewer than 4 configurations, a plane or a sphere
  from fewer than 4, planes alone whose normals do not span space).
* :func:`touch_identifiability` finds which parameters the rows determine, numerically, by the
  rank-revealing selection of :mod:`calib.model.identifiability` on the combined noise-weighted
  Jacobian of the robot's geometric parameters and the features' unknowns, in the priority:
  features' unknowns first, then the robot's parameters in their order (Eq. 23) with the
  longest link length last. What such data leave free then shows as relations: the meas frame's
  u (a rigid motion of the whole cell moves the features with it), the joint-1 parameters tied
  to it, a plane's offset against the parameters along its normal, and, with no sphere (no known
  length), the scale, held by the longest length (its relative error, hence the scale's, is then
  the smallest).
* :func:`calibrate_touch` fits the identifiable robot parameters and the features by calib's LM
  (:class:`calib.solvers.touch_problem.TouchProblem`) from the nominal model and the features fitted to
  its tool points, and returns a :class:`TouchResult`.
  A second pass decides the set again at the first fit's model (errors beyond the idealised
  nominal's snaps untie parameters); rows far off their feature are dropped as outliers and
  the rest fitted again; the held-out residuals are cross-validated (:func:`cross_validate_touch`).
* :mod:`calib.calibration.touch_accuracy`: the Cramer-Rao prediction of the calibrated tool
  positions' error after a best-fit rigid registration (the base frame stays nominal: what a
  robot then located by touching its work sees), and the registered error to a known truth.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from calib.calibration.fit import _implausible_length_notes
from calib.calibration.parameters import _idealised
from calib.checks import check_choice, check_instance, check_int, check_number
from calib.errors import DataError, ParameterError
from calib.model.identifiability import RANK_TOL, Relation, select_identifiable, no_effect
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import (FeatureStart, TouchData, feature_parameter_names, initial_features,
                               plane_normals)
from calib.model.touch_simulate import reach_positions
from calib.solvers.lm import LMOptions, SolverResult, levenberg_marquardt
from calib.solvers.problem import CHI2_ESCAPE, normal_inverse
from calib.solvers.touch_problem import TouchProblem

#: Default touch noise (metres per residual component): a good probe in a good nest.
SIGMA_TOUCH_M = 0.02e-3
#: Rows a feature needs at least (a point from 3 orientations, 3 points of a plane, locate the
#: feature and leave almost nothing to calibrate the robot).
MIN_ROWS = {"point": 4, "plane": 4, "sphere": 4}
PARAM_CHOICES = ("auto", "tool")
#: Rows whose residual exceeds this many robust standard deviations are dropped (as calibrate's
#: --outlier-k).
OUTLIER_K = 5.0


@dataclass(frozen=True)
class TouchIdentifiability:
    """Which parameters touch rows determine (:func:`touch_identifiability`).

    robot_free : names of the identifiable robot parameters (in the robot's order);
    features : names of the features' unknowns (all identifiable: else the design is refused);
    unidentifiable : the robot parameters held at their nominal values, with the kept parameters
    (robot or feature) each is tied to; scale_free : True when no known length fixes the scale
    (no sphere rows), the scale then held by the longest length.
    """

    robot_free: tuple[str, ...]
    features: tuple[str, ...]
    unidentifiable: tuple[Relation, ...]
    scale_free: bool

    def to_dict(self) -> dict:
        """A JSON-ready dict (robot_free, features, held_nominal with tied partners, scale_free)."""
        return {"robot_free": list(self.robot_free), "features": list(self.features),
                "held_nominal": [{"name": r.parameter, "tied_to": [{"name": n, "coefficient": c}
                                                                   for n, c in r.partners],
                                  "reason": r.reason} for r in self.unidentifiable],
                "scale_free": self.scale_free}

    def format(self) -> str:
        lines = [f"identifiable robot parameters ({len(self.robot_free)}): {', '.join(self.robot_free)}",
                 f"feature unknowns ({len(self.features)}): {', '.join(self.features)}",
                 f"held nominal ({len(self.unidentifiable)}):"]
        lines += [f"  {r.describe()}" for r in self.unidentifiable]
        if self.scale_free:
            lines.append("no known length (no sphere rows): the scale is held by the longest link length")
        return "\n".join(lines)


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
    the held-out residual components over ``cv_folds`` folds (None without).
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

    @property
    def success(self) -> bool:
        return self.status == "converged"

    def format(self) -> str:
        lines = [f"touch calibration: {self.n_rows} rows, {self.n_residuals} residual components, "
                 f"{len(self.free)} robot parameters and {len(self.feature_names)} feature unknowns fitted",
                 f"residual RMS {self.rms_before * 1e3:.4f} mm before, {self.rms_after * 1e3:.4f} mm after "
                 f"(noise estimated {self.sigma_estimated * 1e3:.4f} mm"
                 + (f", given {self.sigma * 1e3:.4f} mm)" if self.sigma_given else ")")]
        if self.outliers:
            lines.append(f"dropped {len(self.outliers)} outlier row(s): " + ", ".join(
                f"row {row} ({e * 1e3:.3f} mm)" for row, e in self.outliers))
        if self.cv_rms is not None:
            lines.append(f"held-out residual RMS ({self.cv_folds}-fold cross-validation): {self.cv_rms * 1e3:.4f} mm")
        for name, v, s in zip(self.feature_names, self.feature_values, self.feature_std):
            unit, f = ("rad", 1.0) if name[-2:] in ("_a", "_b") else ("mm", 1e3)
            lines.append(f"  {name:<24} {v * f:12.4f} +- {s * f:.4f} {unit}")
        return "\n".join(lines)


# ---------------------------------------------------------------- checks
def check_touch_design(data: TouchData, params: str = "auto") -> None:
    """Raise DataError (one line, naming what to add) for designs that cannot calibrate anything
    useful: a feature with fewer rows than MIN_ROWS; planes alone whose normals (estimated from
    the rows' nominal tool points, given as ``data``'s feature order) are checked in
    :func:`touch_identifiability`; ``params="tool"`` without a point touched from 4 or more
    configurations."""
    check_instance(data, "data", TouchData, "a calib.model.touch.TouchData")
    for k, f in enumerate(data.features):
        n = len(data.rows_of(k))
        if n < MIN_ROWS[f.kind]:
            what = {"point": "orientations", "plane": "points", "sphere": "points"}[f.kind]
            raise DataError(f"{f.kind} {f.id!r} is touched in {n} rows: touch it from at least "
                            f"{MIN_ROWS[f.kind]} {what} (more rows, or more features)")
    if params == "tool" and not any(f.kind == "point" for f in data.features):
        raise DataError("--params tool needs a point touched from 4 or more orientations; the rows "
                        "touch no point")


def _priority(robot: RobotModel, candidates: Sequence[int]) -> list[int]:
    """The robot's candidate parameters in their order, the longest nominal length last."""
    order = list(candidates)
    lengths = [k for k in order if robot.parameters[k].unit == "m" and robot.parameters[k].group == "joint"]
    if lengths:
        longest = max(lengths, key=lambda k: abs(robot.values[k]))
        order.remove(longest)
        order.append(longest)
    return order


def touch_identifiability(robot: RobotModel, data: TouchData, *, params: str = "auto",
                          sigma: float = SIGMA_TOUCH_M, tol: float = RANK_TOL,
                          first: Sequence[str] = ()) -> TouchIdentifiability:
    """Which robot parameters ``data`` determine with the features (see the module docstring),
    at ``robot``'s idealised values. params : "auto" (every geometric parameter a candidate) or
    "tool" (the flange->tool offset v_x, v_y, v_z only, the robot held nominal). first : robot
    parameter names to keep before the others (after the features). Raises DataError
    naming what to add when a feature's unknowns or every robot parameter are undetermined, or
    when planes alone have normals that do not span space."""
    check_robot(robot)
    check_touch_design(data, params)
    if params not in PARAM_CHOICES:
        raise ParameterError(f"params must be one of {', '.join(PARAM_CHOICES)} for touch data, got {params!r}")
    if data.q.shape[1] != robot.n_joints:
        raise DataError(f"touch rows have {data.q.shape[1]} joint values, the robot {robot.n_joints} joints")
    if robot.targets:
        raise ParameterError("touch data calibrate a robot with one tool point; this model has several "
                             f"targets ({', '.join(robot.targets)})")
    model = _idealised(robot)
    if params == "tool":
        candidates = [model.index(n) for n in model.v_names()[:3]]
    else:
        candidates = [k for k, p in enumerate(model.parameters) if p.group != "compliance"]
    kin = ChainKinematics(model)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    _check_planes(data, start.plane_refs)
    data = consistent_rows(model, data, start)
    prob = TouchProblem(kin, data, model.values, candidates, start.plane_refs, sigma)
    J = prob.jacobian(prob.x0(start.values))
    mr = len(candidates)
    n_feat = J.shape[1] - mr
    ranked = _priority(model, candidates)
    lead = [k for k in model.indices(first) if k in ranked] if first else []
    ranked = lead + [k for k in ranked if k not in lead]
    order = list(range(mr, mr + n_feat)) + [candidates.index(k) for k in ranked]
    kept, dropped = select_identifiable(J, order, tol)
    fnames = feature_parameter_names(data.features)
    lost = [fnames[j - mr] for j in dropped if j >= mr]
    if lost:
        raise DataError(f"the rows cannot locate {', '.join(lost)}: touch each feature at configurations "
                        f"further apart (a plane at points not on one line)")
    robot_kept = sorted(j for j in kept if j < mr)
    if not robot_kept:
        raise DataError("the rows determine no robot parameter: add rows or features")
    norms = np.linalg.norm(J, axis=0)
    names = [model.names[k] for k in candidates] + list(fnames)
    relations = []
    for j in dropped:
        if no_effect(norms, j):
            relations.append(Relation(names[j], (), "no effect on the touched tool points"))
            continue
        coef = np.linalg.lstsq(J[:, kept], J[:, j], rcond=None)[0]
        scale = norms[kept] / norms[j]
        partners = tuple((names[k], float(c)) for k, c, s in zip(kept, coef, scale) if abs(c * s) > 1e-4)
        relations.append(Relation(names[j], partners, "its effect equals that of the listed parameters"))
    scale_free = not any(f.kind == "sphere" for f in data.features)
    return TouchIdentifiability(tuple(names[j] for j in robot_kept), tuple(fnames), tuple(relations),
                                scale_free)


def consistent_rows(model: RobotModel, data: TouchData, start: FeatureStart) -> TouchData:
    """``data`` with each row's configuration moved (by the robot's errors: a few mrad) so that
    ``model``'s tool point satisfies its constraint exactly, the features at ``start``: the
    projection of the tool point onto its feature, reached by damped least squares from the
    row's configuration. The ties of such data are exact (a rigid motion of the cell, the scale):
    at the rows as measured, whose tool points miss the features by the robot's errors, they
    hold only to that relative size (1e-3), above the rank tolerance. Rows that do not converge
    are left out (all of them kept when that would leave a feature without rows)."""
    prob = TouchProblem(ChainKinematics(model), data, model.values, np.zeros(0, int), start.plane_refs, 1.0)
    p = prob.kin.frame_poses(data.q)[1]
    F = start.values.reshape(-1, 3)
    target = p.copy()
    for k, f in enumerate(data.features):
        rows = data.rows_of(k)
        if f.kind == "point":
            target[rows] = F[k]
        elif f.kind == "plane":
            n = start.plane_refs[k][:, 2]
            target[rows] -= np.outer(p[rows] @ n - F[k, 2] - data.probe_radius, n)
        else:
            e = p[rows] - F[k]
            target[rows] = F[k] + f.radius * e / np.linalg.norm(e, axis=1)[:, None]
    Q, ok = reach_positions(model, target, starts=data.q)
    moved = replace(data, q=np.where(ok[:, None], Q, data.q))
    if ok.all() or len(set(data.feature[ok].tolist())) < len(data.features):
        return moved
    return moved.subset(ok)


def _check_planes(data: TouchData, plane_refs: np.ndarray) -> None:
    """Planes alone must have normals spanning space: one plane (or parallel ones) leaves the
    tool free along it, two leave the line where they meet."""
    if any(f.kind != "plane" for f in data.features):
        return
    normals = plane_refs[:, :, 2]
    s = np.linalg.svd(normals, compute_uv=False)
    span = int(np.sum(s > 0.1 * s[0]))     # directions at more than ~6 degrees
    if span < 3:
        raise DataError(f"the planes' normals span {span} direction{'s' if span > 1 else ''}: add "
                        f"{'two planes' if span == 1 else 'a plane'} not parallel to the touched ones "
                        f"(three faces of a cube), or a point or a sphere")


# ---------------------------------------------------------------- fit
def calibrate_touch(robot: RobotModel, data: TouchData, *, params: str = "auto",
                    sigma: float | None = None, cv: int = 5, seed: int = 0,
                    outlier_k: float | None = OUTLIER_K, options: LMOptions = LMOptions()) -> TouchResult:
    """Calibrate ``robot`` from touch rows (see the module docstring).

    robot : the nominal model (the start; u stays at it). data : the rows (q in ``robot``'s chain
    order). params : "auto" (the identifiable geometric parameters) or "tool" (the flange->tool
    offset only, the classic TCP calibration). sigma : metres, the touch noise per residual
    component, or None to estimate it from the residuals; the uncertainties and the prediction
    are at it, and a given one is checked against the residuals (reduced chi-square above
    CHI2_ESCAPE: status "implausible"). cv : folds of the cross-validated held-out residuals
    (:func:`cross_validate_touch`; 0 or 1: none), drawn with ``seed``. outlier_k : after the
    fit, rows whose RMS residual per component exceeds outlier_k times the residuals' robust
    standard deviation (1.4826 times their median absolute value) are dropped and the rest fitted
    again, once (a row naming the wrong feature, a slipped probe); None: none dropped.
    Returns a :class:`TouchResult`.
    """
    check_robot(robot)
    check_instance(data, "data", TouchData, "calib.read_touch or calib.simulate_touch")
    check_choice(params, "params", PARAM_CHOICES)
    check_instance(options, "options", LMOptions, "calib.solvers.lm.LMOptions")
    if sigma is not None:
        check_number(sigma, "sigma", minimum=1e-9, maximum=1.0)
    check_int(cv, "cv", minimum=0, maximum=10_000)
    check_int(seed, "seed", minimum=0)
    if outlier_k is not None:
        check_number(outlier_k, "outlier_k", minimum=1.0)
    weight = SIGMA_TOUCH_M if sigma is None else float(sigma)
    fit = _calibrate(robot, data, params, weight, sigma, options)
    outliers = ()
    if outlier_k is not None:
        rows = fit[1].row_residuals(fit[3].x)
        r = fit[1].evaluate(fit[3].x, jacobian=False)[0]
        bad = rows > outlier_k * 1.4826 * np.median(np.abs(r))
        if bad.any():
            outliers = tuple((int(row), float(e)) for row, e in zip(data.rows[bad], rows[bad]))
            try:
                data = data.subset(~bad)
                fit = _calibrate(robot, data, params, weight, sigma, options)
            except DataError as exc:
                shown = ", ".join(str(row) for row, _ in outliers)
                raise DataError(f"after dropping the outlier rows {shown} (residuals above {outlier_k:g} "
                                f"robust standard deviations; outlier_k=None keeps them): {exc}") from None
    ident, prob, start, sol, r0 = fit
    result = _result(robot, data, weight, sigma, ident, prob, start, sol, r0)
    cv_rms = cross_validate_touch(robot, data, ident.robot_free, sigma=weight, k=cv, seed=seed,
                                  options=options) if cv > 1 else None
    return replace(result, cv_rms=cv_rms, cv_folds=cv if cv > 1 else 0, outliers=outliers)


def _calibrate(robot, data, params, weight, sigma, options):
    """(identifiability, problem, feature start, LM result, residuals at the start) of the fit
    (with its second pass, :func:`_second_pass`)."""
    ident = touch_identifiability(robot, data, params=params, sigma=weight)
    prob, start, sol, r0 = _fit(robot, data, robot.indices(ident.robot_free), weight, options, declared=True)
    second = _second_pass(robot, data, params, weight, sigma, options, ident, prob, sol)
    if second is not None:
        ident, prob, start, sol = second
    return ident, prob, start, sol, r0


def _result(robot, data, weight, sigma, ident, prob, start, sol, r0) -> TouchResult:
    """The :class:`TouchResult` of a fit (without cross-validation and outliers)."""
    free = robot.indices(ident.robot_free)
    x = sol.x
    ne = prob.normal_equations(x)
    r = prob.evaluate(x, jacobian=False)[0]
    dof = max(len(r) - len(x), 1)
    sigma_est = float(np.sqrt(r @ r / dof))
    noise = weight if sigma is not None else sigma_est
    cov = normal_inverse(ne.A)[0] * (noise / weight) ** 2
    std_all = np.sqrt(np.maximum(np.diag(cov), 0.0))
    mr = len(free)
    F = prob.feature_values(x)
    normals = np.zeros((len(data.features), 3))
    planes = [k for k, f in enumerate(data.features) if f.kind == "plane"]
    if planes:
        normals[planes] = plane_normals(start.plane_refs[planes], F[planes, 0], F[planes, 1])[0]
    calibrated = robot.with_values(prob.full(x))
    status, message = sol.status, sol.message
    notes = _implausible_length_notes(robot, calibrated)
    if sigma is not None and (sigma_est / sigma) ** 2 > CHI2_ESCAPE:
        notes.insert(0, f"the fit converged but its residuals are {sigma_est / sigma:.1f} times the given noise "
                        f"(reduced chi^2 {(sigma_est / sigma) ** 2:.3g}): a wrong sigma, rows naming the wrong "
                        f"feature, or errors the model does not describe; omit the noise to estimate it")
    if notes and status == "converged":
        status, message = "implausible", notes[0]
    return TouchResult(
        robot=calibrated, identifiability=ident, free=ident.robot_free,
        feature_names=ident.features, feature_values=x[mr:].copy(), feature_std=std_all[mr:],
        plane_normals=normals, plane_refs=start.plane_refs,
        rms_before=float(np.sqrt(np.mean(r0 ** 2))), rms_after=float(np.sqrt(np.mean(r ** 2))),
        sigma=float(noise), sigma_given=sigma is not None, sigma_estimated=sigma_est, std=std_all[:mr],
        covariance=cov, solver=sol, n_rows=data.n_rows, n_residuals=len(r), status=status,
        message=message)


def _second_pass(robot, data, params, weight, sigma, options, ident, prob, sol):
    """The parameter set decided again at the first fit's model, and the fit with it when it is
    larger and lowers the cost significantly: (identifiability, problem, feature start, LM
    result), or None. Ties and "no effect" are decided at an idealised model (exact right angles,
    zero small lengths); a robot whose errors are larger than that idealisation snaps (1 mm,
    0.05 rad: a tool point millimetres off the last axis) breaks some of them (the last joint's
    offset then moves the tool point), and holding those parameters nominal leaves residuals of
    several times the noise (UR10, errors of 5 mm / 10 mrad: 3 times, the tool positions 2-5 times
    the Cramer-Rao prediction; with the second pass at the noise and the prediction). Kept when
    the likelihood-ratio statistic of the extra parameters exceeds its chi-square 99 % point."""
    first = robot.with_values(prob.full(sol.x))
    again = touch_identifiability(first, data, params=params, sigma=weight, first=ident.robot_free)
    extra = set(again.robot_free) - set(ident.robot_free)
    if not extra or not set(ident.robot_free) <= set(again.robot_free):
        return None
    prob2, start2, sol2, _ = _fit(first, data, first.indices(again.robot_free), weight, options, declared=True)
    r1 = prob.evaluate(sol.x, jacobian=False)[0]
    r2 = prob2.evaluate(sol2.x, jacobian=False)[0]
    dof2 = max(len(r2) - len(sol2.x), 1)
    noise = sigma if sigma is not None else float(np.sqrt(r2 @ r2 / dof2))
    from scipy.stats import chi2

    if (r1 @ r1 - r2 @ r2) / noise ** 2 <= chi2.ppf(0.99, len(extra)):
        return None
    # (the first fit moved only its free parameters: the fixed ones of prob2 are robot's)
    return again, prob2, start2, sol2


def _fit(robot: RobotModel, data: TouchData, free: np.ndarray, sigma: float, options: LMOptions,
         declared: bool):
    """(problem, feature start, LM result, residuals at the start) of the fit of the robot
    parameters ``free`` and the features, from ``robot`` and the features fitted to its tool
    points; ``declared``: the free set is identifiable (no direction held, see Problem)."""
    kin = ChainKinematics(robot)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    prob = TouchProblem(kin, data, robot.values, free, start.plane_refs, sigma)
    x0 = prob.x0(start.values)
    if declared:
        prob.set_rank_deficit(0)
    r0 = prob.evaluate(x0, jacobian=False)[0]
    return prob, start, levenberg_marquardt(prob, x0, options=options), r0


def cross_validate_touch(robot: RobotModel, data: TouchData, free: Sequence[str], *,
                         sigma: float = SIGMA_TOUCH_M, k: int = 5, seed: int = 0,
                         options: LMOptions = LMOptions()) -> float:
    """RMS (metres) of the held-out residual components over ``k`` folds: each fold's rows
    (drawn feature by feature, so that every feature keeps rows in every fit) predicted by the
    robot parameters ``free`` and the features fitted to the other rows."""
    check_int(k, "k", minimum=2)
    rng = np.random.default_rng(seed)
    fold = np.empty(data.n_rows, int)
    for f in range(len(data.features)):
        rows = rng.permutation(data.rows_of(f))
        fold[rows] = (np.arange(len(rows)) + rng.integers(k)) % k
    free_idx = robot.indices(free)
    sq, n = 0.0, 0
    for j in range(k):
        test = fold == j
        train = ~test
        if not test.any():
            continue
        if len(set(data.feature[train].tolist())) < len(data.features):
            raise DataError(f"{k}-fold cross-validation leaves a feature without rows: fewer folds, or more rows")
        prob, start, sol, _ = _fit(robot, data.subset(train), free_idx, sigma, options, declared=False)
        used = sorted(set(data.feature[test].tolist()))
        held = TouchProblem(ChainKinematics(robot), data.subset(test), prob.full(sol.x), free_idx,
                            start.plane_refs[used], sigma)
        x = np.concatenate([sol.x[:len(free_idx)], prob.feature_values(sol.x)[used].reshape(-1)])
        r = held.evaluate(x, jacobian=False)[0]
        sq, n = sq + float(r @ r), n + len(r)
    return float(np.sqrt(sq / n))
