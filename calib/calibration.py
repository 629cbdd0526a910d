"""The calibration API: identify a robot's TM-MDH parameters from measured tool poses.

``calibrate(robot, measurements)`` runs, in order:

1. parameter selection (``params``): ``"base"`` (default) the identifiable set of
   :mod:`calib.identifiability` at the calibration configurations, each redundant partner held at
   its nominal value; ``"paper"`` all but u_z, u_alpha, v_x, v_z, v_alpha, v_gamma (Section 4.2);
   ``"all"`` every parameter, the rank deficiency left to the LM damping (Tables 6-7); or a list
   of names.
2. closed-form frame initialisation (:mod:`calib.frames`) when the data put the measurement or
   tool frame far from the nominal one (more than ``FRAME_REBASE_M`` or ``FRAME_REBASE_RAD``):
   the model's constant reference transforms are moved to the estimates, u and v keep their
   nominal values relative to them.
3. identification by C-LM (default) or LM (:mod:`calib.solvers`), noise-weighted.
4. statistics: parameter covariance ``(J^T W J)^-1`` of the free parameters at the solution (the
   Cramer-Rao bound of an unbiased estimator for the given sigma), standard deviations, the
   predicted pose accuracy of the calibrated model from that covariance, and the achieved accuracy
   before and after on the calibration and validation rows.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import DataError, ParameterError
from .angles import RotationChain
from .frames import estimate_frames
from .identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, analyze_identifiability
from .jacobian import pose_jacobian
from .kinematics import ChainKinematics
from .measurements import Measurements
from .robot import RobotModel
from .solvers import LMOptions, LMTrace, Problem, cross_lm, levenberg_marquardt
from .spatial import inverse, log3_batch, zyx_parameters, zyx_transform

METHODS = ("search-lm", "c-lm", "lm")
#: search-lm: a fit whose reduced chi-square stays above this is not at the noise level, and the
#: angle search is tried again from it (a local minimum is the likely cause).
CHI2_ESCAPE = 10.0
PARAM_SETS = ("base", "paper", "all")
#: Parameters that Section 4.2 of the paper leaves out when the frames are well known.
PAPER_EXCLUDED = ("u_z", "u_alpha", "v_x", "v_z", "v_alpha", "v_gamma")
#: The closed-form frame estimate replaces the nominal frames beyond these distances.
FRAME_REBASE_M = 0.010
FRAME_REBASE_RAD = 0.02


# ====================================================================== accuracy
@dataclass(frozen=True)
class AccuracyStats:
    """Pose errors of a model against measurements (or the truth).

    position_errors : (N,) metres, |p_model - p_measured|; rotation_errors : (N,) radians, the
    angle of R_model R_measured^T (None for position-only data). Statistics in the same units.
    """

    position_errors: np.ndarray = field(repr=False)
    rotation_errors: np.ndarray | None = field(repr=False)

    @property
    def n_poses(self) -> int:
        return len(self.position_errors)

    @staticmethod
    def _stats(e: np.ndarray | None) -> dict[str, float] | None:
        if e is None or len(e) == 0:
            return None
        return {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(e ** 2))),
                "max": float(np.max(e)), "min": float(np.min(e))}

    @property
    def position(self) -> dict[str, float] | None:
        """mean, rms, max, min of the position error, metres."""
        return self._stats(self.position_errors)

    @property
    def rotation(self) -> dict[str, float] | None:
        """mean, rms, max, min of the orientation error, radians (None if position only)."""
        return self._stats(self.rotation_errors)

    def to_dict(self) -> dict:
        """JSON-ready: position in mm, rotation in rad."""
        pos = self.position
        return {"n_poses": self.n_poses,
                "position_mm": None if pos is None else {k: v * 1e3 for k, v in pos.items()},
                "rotation_rad": self.rotation}


def pose_errors(robot: RobotModel, Q: np.ndarray, position: np.ndarray,
                rotation: np.ndarray | None, kin: ChainKinematics | None = None) -> AccuracyStats:
    """Errors of ``robot``'s tool poses at Q (N, n) against positions (N, 3) m and rotations."""
    kin = kin or ChainKinematics(robot)
    if kin.values is not robot.values:
        kin.set_values(robot.values)
    R, p = kin.frame_poses(Q)
    pe = np.linalg.norm(p - position, axis=1)
    re = None
    if rotation is not None:
        re = np.linalg.norm(log3_batch(R @ np.transpose(rotation, (0, 2, 1))), axis=1)
    return AccuracyStats(pe, re)


def evaluate(robot: RobotModel, measurements: Measurements) -> AccuracyStats:
    """Accuracy of ``robot`` against all rows of ``measurements`` (tool pose in the meas frame)."""
    _check_compatible(robot, measurements)
    return pose_errors(robot, measurements.q, measurements.position, measurements.rotation)


# ====================================================================== result
@dataclass(frozen=True)
class Outlier:
    """A calibration row left out of the fit: its line in the file, its errors after the fit
    (metres, radians; rotation NaN for position-only data) and its residual RMS in sigma."""

    row: int
    position_error: float
    rotation_error: float
    sigmas: float


def _flag_outliers(model: RobotModel, cal: Measurements, keep: np.ndarray, sigma_pos: float,
                   sigma_rot: float, k: float) -> tuple[list[Outlier], bool]:
    """Rows still kept whose whitened residual RMS per component exceeds k (see calibrate), and
    whether they are too many (more than a quarter of the kept rows) to be outliers."""
    R, p = ChainKinematics(model).frame_poses(cal.q)
    dp = p - cal.position
    blocks = [dp / sigma_pos]
    rot = np.full(cal.n_poses, np.nan)
    if cal.rotation is not None:
        dr = log3_batch(R @ np.transpose(cal.rotation, (0, 2, 1)))
        blocks.append(dr / sigma_rot)
        rot = np.linalg.norm(dr, axis=1)
    w = np.concatenate(blocks, axis=1)
    rms = np.sqrt(np.mean(w ** 2, axis=1))
    bad = np.flatnonzero(keep & (rms > k))
    found = [Outlier(int(cal.rows[i]), float(np.linalg.norm(dp[i])), float(rot[i]), float(rms[i]))
             for i in bad]
    return found, len(bad) > 0.25 * keep.sum()


@dataclass(frozen=True)
class ParameterEstimate:
    """One row of the parameter table. Values in SI units (``unit``: m or rad).

    For u and v rows, ``nominal`` and ``identified`` are the Eq. (3) values of the whole
    transform (T_meas_base or T_flange_tool), so that they read the same whatever reference the
    model uses internally. ``std`` is NaN for parameters held fixed, and for free parameters in a
    rank-deficient set (``all``, ``paper``) it comes from the pseudo-inverse.
    """

    name: str
    unit: str
    nominal: float
    identified: float
    free: bool
    std: float

    @property
    def deviation(self) -> float:
        d = self.identified - self.nominal
        if self.unit == "rad":
            d = (d + math.pi) % (2 * math.pi) - math.pi
        return d


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate` returns (compare scipy's ``OptimizeResult``).

    robot : the calibrated model; nominal : the model calibration started from.
    parameters : the parameter table; free : names of the identified parameters.
    status : "converged", "max_iterations" or "diverged"; success : status == "converged".
    before, after : accuracy on the calibration rows; validation_before/after on the validation
    rows (None without validation data). predicted : the Cramer-Rao prediction of the calibrated
    model's RMS error against the true poses (position m, rotation rad) at the validation
    configurations (the calibration ones when there are none).
    covariance : (n_free, n_free) covariance of the free parameters (SI units).
    """

    robot: RobotModel
    nominal: RobotModel
    method: str
    param_set: str
    parameters: tuple[ParameterEstimate, ...]
    free: tuple[str, ...]
    status: str
    message: str
    iterations: int
    rounds: int
    wall_time: float
    cost: float
    reduced_chi2: float
    covariance: np.ndarray = field(repr=False)
    before: AccuracyStats = field(repr=False)
    after: AccuracyStats = field(repr=False)
    validation_before: AccuracyStats | None = field(repr=False)
    validation_after: AccuracyStats | None = field(repr=False)
    predicted: dict = field(repr=False)
    sigma_pos: float
    sigma_rot: float
    notes: tuple[str, ...] = ()
    outliers: tuple["Outlier", ...] = ()
    loss: str = "linear"

    @property
    def success(self) -> bool:
        return self.status == "converged"

    @property
    def x(self) -> np.ndarray:
        """Identified values of the free parameters (SI)."""
        return self.robot.values[self.robot.indices(self.free)]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def parameter(self, name: str) -> ParameterEstimate:
        for p in self.parameters:
            if p.name == name:
                return p
        raise ParameterError(f"unknown parameter {name!r}")

    def write_urdf(self, path: str | Path) -> None:
        """Write the calibrated model as a URDF (see :func:`calib.urdf_writer.write_calibrated_urdf`)."""
        from .urdf_writer import write_calibrated_urdf

        write_calibrated_urdf(self.robot, path, nominal=self.nominal)

    def to_dict(self) -> dict:
        """JSON-ready report: keys status, before, after, validation, parameters, ..."""
        return {
            "status": self.status,
            "success": self.success,
            "message": self.message,
            "method": self.method,
            "param_set": self.param_set,
            "iterations": self.iterations,
            "rounds": self.rounds,
            "wall_time_s": self.wall_time,
            "cost": self.cost,
            "reduced_chi2": self.reduced_chi2,
            "sigma_pos_mm": self.sigma_pos * 1e3,
            "sigma_rot_rad": self.sigma_rot,
            "notes": list(self.notes),
            "loss": self.loss,
            "outliers": [{"row": o.row, "position_error_mm": o.position_error * 1e3,
                          "rotation_error_rad": None if math.isnan(o.rotation_error) else o.rotation_error,
                          "sigmas": o.sigmas} for o in self.outliers],
            "before": self.before.to_dict(),
            "after": self.after.to_dict(),
            "validation": None if self.validation_after is None else {
                "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()},
            "predicted_rms": {"position_mm": self.predicted["position_rms"] * 1e3,
                              "rotation_rad": self.predicted.get("rotation_rms")},
            "parameters": [{"name": p.name, "unit": "mm" if p.unit == "m" else "rad",
                            "nominal": _out(p.nominal, p.unit), "identified": _out(p.identified, p.unit),
                            "deviation": _out(p.deviation, p.unit),
                            "std": None if math.isnan(p.std) else _out(p.std, p.unit),
                            "free": p.free} for p in self.parameters],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    def format(self) -> str:
        """The report for a person: parameter table, accuracy before/after, status."""
        lines = [f"Calibration: {self.method.upper()}, parameter set {self.param_set!r} "
                 f"({len(self.free)} identified of {len(self.parameters)}), {self.status}: {self.message}",
                 f"  {self.iterations} iterations, {self.rounds} rounds, {self.wall_time * 1e3:.1f} ms; "
                 f"reduced chi^2 {self.reduced_chi2:.3g} (1 when sigma_pos = {self.sigma_pos * 1e3:g} mm "
                 f"and sigma_rot = {self.sigma_rot:g} rad match the data)"]
        lines += [f"  note: {n}" for n in self.notes]
        for o in self.outliers:
            rot = "" if math.isnan(o.rotation_error) else f", {o.rotation_error:.3g} rad"
            lines.append(f"  outlier: row {o.row}: {o.position_error * 1e3:.3f} mm{rot} ({o.sigmas:.0f} sigma)")
        lines += ["", f"{'parameter':<10}{'unit':>5}{'nominal':>14}{'identified':>14}{'deviation':>13}{'std':>11}"]
        for p in self.parameters:
            unit = "mm" if p.unit == "m" else "rad"
            std = "fixed" if not p.free else f"{_out(p.std, p.unit):.3g}"
            lines.append(f"{p.name:<10}{unit:>5}{_out(p.nominal, p.unit):>14.6f}"
                         f"{_out(p.identified, p.unit):>14.6f}{_out(p.deviation, p.unit):>13.6f}{std:>11}")
        lines += ["", format_accuracy_table([("calibration rows, before", self.before),
                                             ("calibration rows, after", self.after)]
                                            + ([] if self.validation_after is None else
                                               [("validation rows, before", self.validation_before),
                                                ("validation rows, after", self.validation_after)]))]
        pr = self.predicted
        rot = "" if pr.get("rotation_rms") is None else f", rotation {pr['rotation_rms']:.3g} rad"
        lines.append(f"predicted RMS error of the calibrated model against the true poses (Cramer-Rao, "
                     f"{pr['where']}): position {pr['position_rms'] * 1e3:.4g} mm{rot}")
        return "\n".join(lines)


def _out(value: float, unit: str) -> float:
    return value * 1e3 if unit == "m" else value


def format_accuracy_table(rows: Sequence[tuple[str, AccuracyStats]]) -> str:
    """Mean, RMS, max, min of position (mm) and orientation (rad) errors, one line per row."""
    head = (f"{'':<28}{'poses':>6} | {'position/mm':^40} | {'orientation/rad':^44}\n"
            f"{'':<28}{'':>6} | {'mean':>9}{'rms':>10}{'max':>10}{'min':>10}"
            f"  | {'mean':>10}{'rms':>11}{'max':>11}{'min':>11}")
    lines = [head]
    for label, s in rows:
        p = s.position
        line = f"{label:<28}{s.n_poses:>6} | " + "".join(f"{p[k] * 1e3:>10.4f}" for k in ("mean", "rms", "max", "min"))
        r = s.rotation
        line += "  | " + ("".join(f"{r[k]:>11.3e}" for k in ("mean", "rms", "max", "min")) if r else f"{'(position only)':>44}")
        lines.append(line)
    return "\n".join(lines)


# ====================================================================== calibrate
def _check_compatible(robot: RobotModel, m: Measurements) -> None:
    if m.n_joints != robot.n_joints:
        raise DataError(f"the measurements have {m.n_joints} joint values per pose, the robot "
                        f"{robot.n_joints} joints ({', '.join(robot.joint_names)})")


def select_parameters(robot: RobotModel, params, Q: np.ndarray, measure: str, sigma_pos: float,
                      sigma_rot: float) -> tuple[str, tuple[str, ...]]:
    """(set label, free parameter names) for a ``params`` choice; see :func:`calibrate`."""
    if isinstance(params, str):
        key = params.lower()
        if key == "base":
            rep = analyze_identifiability(robot, Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot)
            return "base", rep.identifiable
        if key == "paper":
            return "paper", tuple(n for n in robot.names if n not in PAPER_EXCLUDED)
        if key == "all":
            return "all", robot.names
        names = [s.strip() for s in params.split(",") if s.strip()]
        if len(names) == 1 and names[0] not in robot.names:
            raise ParameterError(f"unknown parameter set {params!r}: expected base, paper, all or a "
                                 f"comma-separated list of parameter names ({', '.join(robot.names)})")
        params = names
    names = tuple(params)
    robot.indices(names)  # raises ParameterError for unknown names
    if len(set(names)) != len(names):
        raise ParameterError("a parameter is listed twice")
    return "list", tuple(n for n in robot.names if n in names)


def _rebase_frames(robot: RobotModel, m: Measurements, notes: list, always: bool = False) -> RobotModel:
    """Move the reference frames to closed-form estimates when the data put them far away
    (or ``always``)."""
    try:
        X, Y = estimate_frames(robot, m.q, m.position, m.rotation)
    except DataError as exc:
        notes.append(f"frames not initialised in closed form ({exc}); started from the nominal frames")
        return robot
    out = robot
    for label, T_nom, T_est in (("measurement->base", robot.T_meas_base(), X),
                                ("flange->tool", robot.T_flange_tool(), Y)):
        dT = inverse(T_nom) @ T_est
        dist = float(np.linalg.norm(dT[:3, 3]))
        ang = float(np.linalg.norm(log3_batch(dT[None, :3, :3])[0]))
        if always or dist > FRAME_REBASE_M or ang > FRAME_REBASE_RAD:
            if label == "measurement->base":
                out = replace(out, T_meas_base_ref=T_est @ inverse(zyx_transform(*robot.u())))
            else:
                out = replace(out, T_flange_tool_ref=inverse(zyx_transform(*robot.v())) @ T_est)
            notes.append(f"{label} initialised in closed form: {dist * 1e3:.1f} mm and {ang:.3g} rad "
                         f"from the nominal transform")
    return out


def _covariance(J: np.ndarray) -> tuple[np.ndarray, bool]:
    """(J^T J)^-1 of a weighted Jacobian, or its pseudo-inverse when rank deficient."""
    A = J.T @ J
    d = np.sqrt(np.diag(A))
    d[d == 0] = 1.0
    As = A / np.outer(d, d)
    s = np.linalg.svd(As, compute_uv=False)
    full_rank = s[-1] > 1e-12 * s[0]
    inv = np.linalg.inv(As) if full_rank else np.linalg.pinv(As, rcond=1e-12)
    return inv / np.outer(d, d), full_rank


def predicted_accuracy(robot: RobotModel, Q: np.ndarray, free: Sequence[str], covariance: np.ndarray) -> dict:
    """Cramer-Rao prediction of the RMS tool pose error at configurations Q (N, n).

    Returns position_rms (m) and rotation_rms (rad): sqrt of the mean over poses of the trace of
    the propagated 3x3 covariance ``J_v C J_v^T``.
    """
    _, _, J = pose_jacobian(ChainKinematics(robot), Q)
    Jf = J[:, :, robot.indices(free)]
    cov = (Jf @ covariance) @ np.transpose(Jf, (0, 2, 1))
    tr_p = np.trace(cov[:, :3, :3], axis1=1, axis2=2)
    tr_r = np.trace(cov[:, 3:, 3:], axis1=1, axis2=2)
    return {"position_rms": float(np.sqrt(np.mean(tr_p))), "rotation_rms": float(np.sqrt(np.mean(tr_r)))}


def calibrate(robot: RobotModel, measurements: Measurements, method: str = "search-lm",
              params: str | Sequence[str] = "base", sigma_pos: float = SIGMA_POS_M,
              sigma_rot: float = SIGMA_ROT_RAD, *, init_frames: bool | str = "auto",
              max_rounds: int = 20, fixed_rounds: int | None = None, options: LMOptions | None = None,
              validation: Measurements | None = None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0) -> CalibrationResult:
    """Identify the TM-MDH parameters of ``robot`` from ``measurements``.

    Parameters
    ----------
    robot : the nominal model (e.g. from :func:`calib.load_robot`).
    measurements : measured tool poses; rows with set ``val`` are held out for validation.
    method : "search-lm" (default): a closed-form search of the angular parameters on the
        rotation data (:mod:`calib.angles`), then LM on all free parameters, searching again if
        LM stops above the noise level; it converges from far larger joint-offset and twist
        errors than C-LM (docs/reproduction.md: 100% of the paper's Table 8 grid, against
        99.8% for C-LM and 93% for LM) at the same accuracy and speed. "c-lm": the paper's cross
        identification (Section 3.2.2). "lm": plain Levenberg-Marquardt. With position-only data
        the first two have no angle step and run as LM (a note in the result says so).
    params : "base" (identifiable set, default), "paper", "all", or parameter names.
    sigma_pos : position noise per axis, metres (default 0.02 mm, the paper's simulation).
    sigma_rot : orientation noise per axis, radians (default 0.002 rad).
    init_frames : "auto" (closed-form estimate of the measurement and tool frames, used when the
        data put them more than 10 mm / 0.02 rad from the nominal ones), True (always use it),
        False (never). With the estimate, the reference transforms move to it and u, v keep their
        nominal values relative to it.
    max_rounds : C-LM rounds at most (LM: ``options.max_iterations``); ``fixed_rounds`` runs
        exactly that many C-LM rounds (see :func:`calib.solvers.cross_lm`).
    validation : separate validation measurements; the statistics then use these, and the
        ``val`` rows of ``measurements`` are only held out.
    loss : "linear" (least squares, the maximum-likelihood fit for Gaussian noise), or a robust
        loss on each pose's whitened residual: "huber" or "soft_l1", with ``loss_scale`` in units
        of sigma (see :func:`calib.solvers.robust_scaling`).
    outlier_k : after the fit, a calibration row whose residual RMS per component exceeds
        ``outlier_k`` sigma is flagged, listed in the result (``outliers``) and the fit repeated
        without it (up to 3 passes). If more than a quarter of the rows exceed it, nothing is
        removed: the noise is then larger than sigma_pos / sigma_rot, and a note says so.
        None disables the check.

    Returns a :class:`CalibrationResult`; a non-converged or diverged fit is reported in its
    ``status``, never raised. Raises :class:`calib.CalibError` for unusable input.
    """
    if len(ids := getattr(measurements, "target_ids", ())) > 1:  # one flange->target transform only
        raise DataError(f"{measurements.source or '<measurements>'}: {len(ids)} targets ({', '.join(ids)}); "
                        f"calibrate takes one target per pose for now: keep one target's rows")
    t0 = time.perf_counter()
    method = method.lower()
    if method not in METHODS:
        raise ParameterError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    if not (sigma_pos > 0 and sigma_rot > 0):
        raise ParameterError("sigma_pos and sigma_rot must be positive")
    _check_compatible(robot, measurements)
    notes: list[str] = []
    cal = measurements.calibration()
    val = measurements.validation()
    if validation is not None:
        _check_compatible(robot, validation)
        if val is not None and val.n_poses:
            notes.append(f"the {val.n_poses} 'val' rows of the measurements are held out; the "
                         f"validation statistics use the separate validation set")
        val = validation
    if val is not None and val.n_poses == 0:
        val = None
    measure = "pose" if cal.has_orientation else "position"

    rows_per_pose = 6 if measure == "pose" else 3
    # the identifiable set needs as many equations as parameters at the very least
    needed = 0
    if cal.n_poses * rows_per_pose < robot.n_params:
        needed = analyze_identifiability(robot, robot.random_configurations(50, 0), measure=measure).rank
    if cal.n_poses * rows_per_pose < needed:
        where = f"{measurements.source}: " if measurements.source is not None else ""
        raise DataError(f"{where}{cal.n_poses} calibration poses give {cal.n_poses * rows_per_pose} equations, "
                        f"fewer than the {needed} identifiable parameters need; measure at least "
                        f"{-(-needed // rows_per_pose)} poses (several times more for accuracy)")

    start = _rebase_frames(robot, cal, notes, always=init_frames is True) if init_frames else robot
    # after the frame estimate: where the tool point lies decides what positions can identify
    label, free = select_parameters(start, params, cal.q, measure, sigma_pos, sigma_rot)
    kin = ChainKinematics(start)
    free_idx = start.indices(free)
    opts = options or LMOptions()
    trace = LMTrace()
    if method != "lm" and measure == "position":
        notes.append(f"position-only data: {method.upper()} needs orientations for its angle step; ran LM")
    keep = np.ones(cal.n_poses, bool)
    outliers: list[Outlier] = []
    x = start.values[free_idx]

    angular = np.array([start.parameters[k].is_angular for k in free_idx])

    def solve(x, fit_loss):
        fit = cal.subset(keep)
        problem = Problem(kin, fit.q, fit.position, fit.rotation, start.values, free_idx, sigma_pos,
                          sigma_rot, fit_loss, loss_scale)
        if method == "c-lm" and measure == "pose":
            return problem, *cross_lm(problem, x, angular, max_rounds=max_rounds,
                                      fixed_rounds=fixed_rounds, options=opts, trace=trace)
        if method == "search-lm" and measure == "pose":
            return problem, *search_lm(start, problem, x, free_idx[angular], fit, opts, trace)
        return problem, *levenberg_marquardt(problem, x, "pose", opts, trace), 1

    for _pass in range(4):
        problem, x, cost, status, message, rounds = solve(x, loss)
        if outlier_k is None or _pass == 3 or status == "diverged":
            break
        new, too_many = _flag_outliers(start.with_values(problem.full(x)), cal, keep, sigma_pos,
                                       sigma_rot, outlier_k)
        fitted = (problem, x, cost, status, message, rounds)
        if new and loss == "linear":
            # a least-squares fit spreads a gross error over its neighbours: judge the rows
            # against a robust (Huber) fit instead, then refit by least squares without them
            robust_problem, x_robust, *_ = solve(x, "huber")
            new, too_many = _flag_outliers(start.with_values(robust_problem.full(x_robust)), cal, keep,
                                           sigma_pos, sigma_rot, outlier_k)
            x = x_robust
        if too_many:
            notes.append(f"{len(new)} of {int(keep.sum())} rows have residuals above {outlier_k:g} sigma: "
                         f"the noise is larger than sigma_pos / sigma_rot (or the model cannot "
                         f"describe the data), so no row was removed as an outlier")
            new = []
        if not new:
            problem, x, cost, status, message, rounds = fitted  # the fit with the requested loss
            break
        outliers += new
        keep[[int(np.flatnonzero(cal.rows == o.row)[0]) for o in new]] = False
    calibrated = start.with_values(problem.full(x))
    if outliers:
        notes.append(f"{len(outliers)} outlier rows removed and the fit repeated without them: rows "
                     + ", ".join(str(o.row) for o in outliers))

    linear = Problem(kin, problem.Q, problem.p_meas, None, problem.values, free_idx, sigma_pos, sigma_rot)
    linear.R_meas_T = problem.R_meas_T
    r, J = linear.residuals_and_jacobian(x)
    cov, full_rank = _covariance(J)
    if not full_rank:
        notes.append("the free parameters are not all identifiable (rank-deficient set): standard "
                     "deviations come from the pseudo-inverse and describe only the identifiable "
                     "combinations")
    dof = max(len(r) - len(free), 1)
    chi2 = float(r @ r) / dof
    if status == "converged" and chi2 > CHI2_ESCAPE:
        notes.append(f"the fit converged but its residuals are {math.sqrt(chi2):.1f} times the given noise "
                     f"(reduced chi^2 {chi2:.3g}): a local minimum, a wrong sigma, or errors the "
                     f"model does not describe")
    where = "validation configurations" if val is not None else "calibration configurations"
    predicted = predicted_accuracy(calibrated, val.q if val is not None else cal.q, free, cov)
    if measure == "position":
        predicted["rotation_rms"] = None
    predicted["where"] = where

    nominal_kin = ChainKinematics(robot)
    before = pose_errors(robot, cal.q, cal.position, cal.rotation, nominal_kin)
    after = pose_errors(calibrated, cal.q, cal.position, cal.rotation, kin)
    vb = va = None
    if val is not None:
        vb = pose_errors(robot, val.q, val.position, val.rotation, nominal_kin)
        va = pose_errors(calibrated, val.q, val.position, val.rotation, kin)

    table = _parameter_table(robot, calibrated, free, cov)
    return CalibrationResult(outliers=tuple(outliers), loss=loss,
        robot=calibrated, nominal=robot, method=method, param_set=label, parameters=table,
        free=free, status=status, message=message, iterations=trace.iterations, rounds=rounds,
        wall_time=time.perf_counter() - t0, cost=float(cost), reduced_chi2=chi2, covariance=cov,
        before=before, after=after, validation_before=vb, validation_after=va, predicted=predicted,
        sigma_pos=sigma_pos, sigma_rot=sigma_rot, notes=tuple(notes))


def search_lm(model: RobotModel, problem: Problem, x: np.ndarray, angular_idx: np.ndarray,
              fit: Measurements, opts: LMOptions, trace: LMTrace, max_escapes: int = 3,
              chain: RotationChain | None = None):
    """search-lm: closed-form angle search on the rotation data (:mod:`calib.angles`), then LM
    on all free parameters; while the fit stays above the noise level (reduced chi-square above
    ``CHI2_ESCAPE``), search again from the LM solution and keep the LM result if it is better.
    ``model`` gives the chain's structure and reference frames (``chain``: a RotationChain of it
    to reuse). Returns (x, cost, status, message, rounds) like :func:`calib.solvers.cross_lm`."""
    chain = chain or RotationChain(model)
    values, _ = chain.search(problem.full(x), fit.q, fit.rotation, angular_idx, problem.sigma_rot)
    x, cost, status, message = levenberg_marquardt(problem, values[problem.free], "pose", opts, trace)
    dof = max(6 * fit.n_poses - len(problem.free), 1)
    rounds = 1
    for _ in range(max_escapes):
        if 2.0 * cost / dof <= CHI2_ESCAPE:
            break
        values, _ = chain.search(problem.full(x), fit.q, fit.rotation, angular_idx, problem.sigma_rot)
        x2, c2, s2, m2 = levenberg_marquardt(problem, values[problem.free], "pose", opts, trace)
        rounds += 1
        if not c2 < cost:
            break
        x, cost, status, message = x2, c2, s2, m2
    return x, cost, status, f"angle search + LM: {message}", rounds


def _parameter_table(nominal: RobotModel, calibrated: RobotModel, free, cov) -> tuple[ParameterEstimate, ...]:
    std = dict(zip(free, np.sqrt(np.maximum(np.diag(cov), 0.0))))
    frame_vals = {"u": (zyx_parameters(nominal.T_meas_base()), zyx_parameters(calibrated.T_meas_base())),
                  "v": (zyx_parameters(nominal.T_flange_tool()), zyx_parameters(calibrated.T_flange_tool()))}
    kinds = ("x", "y", "z", "alpha", "beta", "gamma")
    rows = []
    for k, p in enumerate(nominal.parameters):
        if p.group in frame_vals:
            i = kinds.index(p.kind)
            nom, ide = frame_vals[p.group][0][i], frame_vals[p.group][1][i]
        else:
            nom, ide = nominal.values[k], calibrated.values[k]
        rows.append(ParameterEstimate(p.name, p.unit, float(nom), float(ide), p.name in std,
                                      float(std.get(p.name, math.nan))))
    return tuple(rows)
