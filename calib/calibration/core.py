"""The calibration API: identify a robot's TM-MDH parameters from measured tool poses.

``calibrate(robot, measurements)`` runs named stages, each returning a small frozen object:

1. **prepare** (:class:`Setup`): the calibration and validation rows, what is measured (pose or
   position), and a closed-form estimate of the measurement and tool frames (:mod:`calib.calibration.frames`)
   when the data put them far from the nominal ones (more than ``FRAME_REBASE_M`` or
   ``FRAME_REBASE_RAD``): the model's constant reference transforms move to the estimates, u and
   v keep their nominal values relative to them.
2. **parameter set** (``params``): the identifiable set of :mod:`calib.model.identifiability`
   (``"base"``), the paper's set, all, a list of names, or ``"auto"``: nested candidate sets
   compared by cross-validated held-out error (:class:`ModelSelection`).
3. **fit** (:class:`Fit`): identification by search-lm, C-LM or LM (:mod:`calib.solvers.problem`),
   noise-weighted. Unless the noise levels are given, they are estimated from the residuals by
   variance-component estimation iterated with the fit (:class:`NoiseEstimate`). Outlier rows are
   flagged against a robust fit and the fit repeated without them.
4. **statistics** (:class:`Statistics`): parameter covariance, the predicted accuracy of the
   calibrated model against the true poses (``predicted_rms``, the Cramer-Rao figure) and against
   new measured rows (``predicted_holdout_rms``: parameter uncertainty inflated by the measured
   misfit, plus the measurement noise), chi-square consistency of given noise levels.
5. **cross-validation** (:class:`CrossValidation`): K-fold held-out error when no validation rows
   are given.
6. accuracy before and after on the calibration and validation rows, raw and (for a measurement
   frame far from the base) after a best-fit registration of the measurement frame only.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from calib.solvers.angles import RotationChain
from calib.checks import check_int, check_number
from calib.model.measurements import check_measurements
from calib.model.robot import check_robot
from calib.errors import DataError, ParameterError
from calib.calibration.frames import estimate_frames_robust, median
from calib.model.identifiability import (SIGMA_POS_M, SIGMA_ROT_RAD, analyze_identifiability,
                                         select_identifiable, weighted_jacobian)
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.compliance import URDF_NOTE
from calib.model.robot import RobotModel
from calib.solvers.problem import CHI2_ESCAPE, CHUNK_POSES, LOSSES, NormalEquations, Problem, normal_inverse
from calib.solvers.lm import LMOptions, LMTrace, SolverResult, levenberg_marquardt
from calib.solvers.schemes import cross_lm, search_lm
from calib.model.spatial import inverse, log3_batch, zyx_parameters, zyx_transform

log = logging.getLogger("calib.calibration.core")

METHODS = ("search-lm", "c-lm", "lm")
#: "calib": calib's LM (:mod:`calib.solvers.problem`); "paper": Eq. (27)-(28) as printed (:mod:`calib.solvers.paper_lm`).
LM_VARIANTS = ("calib", "paper")
PARAM_SETS = ("base", "paper", "all", "auto")
#: Parameters that Section 4.2 of the paper leaves out when the frames are well known.
PAPER_EXCLUDED = ("u_z", "u_alpha", "v_x", "v_z", "v_alpha", "v_gamma")
#: The closed-form frame estimate replaces the nominal frames beyond these distances.
FRAME_REBASE_M = 0.010
FRAME_REBASE_RAD = 0.02
#: Without ``params``, model selection ("auto") is used when the calibration rows hold fewer
#: residual components per identifiable parameter than this (scripts/bench_holdout.py).
AUTO_BELOW_COMPONENTS_PER_PARAM = 10.0
#: Variance-component estimation: at most this many re-weighted fits, stopping when both noise
#: levels change by less than VCE_RTOL.
VCE_MAX_ITERATIONS = 12
VCE_RTOL = 1e-3
#: The first fit of a noise estimate only places the residuals the estimate is made from: it
#: stops when an iteration lowers the cost by less than this fraction (the noise levels it
#: yields are then exact to ~1e-6, far inside VCE_RTOL); the re-weighted fits converge fully.
VCE_FIRST_FTOL = 1e-5
#: Damping at the start of a re-fit from a solution of the same rows (re-weighted, rows
#: removed): the solution is near, and the default start (LMOptions.mu0) would only slow the
#: first steps down; a rejected step raises it as usual.
WARM_MU0 = 1e-6
#: An explicit lm / c-lm fit is called a local minimum when an angle search from it, then LM,
#: reaches a cost below this fraction of its own.
LOCAL_MINIMUM_RATIO = 0.9
#: Measured positions farther than the robot's reach plus this from the measurement frame's
#: origin are refused (wrong units or gross errors): the longest-range laser trackers measure
#: to 160 m (Leica AT403, 320 m diameter), so 200 m bounds any tracker or camera set-up.
TRACKER_RANGE_M = 200.0
#: A calibrated model whose calibration rows keep a position RMS error above this fraction of
#: the robot's reach, or an orientation RMS error above IMPLAUSIBLE_ROT_RAD, does not describe
#: the data (a joint column in radians read as degrees leaves 60 % of a UR5's reach): a note
#: says so. Real set-ups stay far below (a camera on a UR5 with an unmodelled gear error: 2 mm,
#: 0.2 % of its reach, and 0.01 rad).
IMPLAUSIBLE_REACH_FRACTION = 0.05
IMPLAUSIBLE_ROT_RAD = 0.1
#: A joint's length parameter (d, a) identified further than this fraction of the reach from its
#: nominal value gets a note (no robot is built so far from its drawing; joint offsets and
#: twists can be off by any angle, and the frames by any distance).
IMPLAUSIBLE_LENGTH_FRACTION = 0.1
#: Below this many residual components per free parameter (a mean leverage above 10 %), the
#: outlier check always judges the rows against a robust (Huber) fit: a least-squares fit of
#: few rows spreads gross errors over the others and inflates the noise estimate until none
#: stands out (2 rows 4 mm off among 25 position-only UR10 rows of 0.05 mm noise, 2.8
#: components per parameter: the fit's true error was 0.81 mm RMS, 0.053 mm without them).
#: Above it a gross row keeps most of its residual and the least-squares residuals suffice (the
#: robust fit, ~70 Huber LM iterations, would cost 60 % more per calibration at 100 full poses).
ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM = 10
#: The robust fit of the outlier check and the noise levels of its residuals are iterated at
#: most this many times (until the levels change by less than 10 %).
ROBUST_CHECK_ITERATIONS = 3
#: Joint readings that agree to this (rad / m) are one configuration when counting distinct poses.
DISTINCT_Q_TOL = 1e-9
#: Residual components beyond the number of free parameters needed to estimate the noise.
MIN_REDUNDANCY = 6
#: Default number of cross-validation folds.
CV_FOLDS = 5
#: Model selection cross-validates leave-one-out below this many calibration rows.
LOO_BELOW_ROWS = 80


# ====================================================================== accuracy
@dataclass(frozen=True)
class AccuracyStats:
    """Pose errors of a model against measurements (or the truth).

    position_errors : (N,) metres, |p_model - p_measured|; rotation_errors : (N,) radians, the
    angle of R_model R_measured^T (None for position-only data). Statistics in the same units.
    """

    position_errors: np.ndarray = field(repr=False)
    rotation_errors: np.ndarray | None = field(repr=False)

    @staticmethod
    def from_residuals(dp: np.ndarray, dr: np.ndarray | None) -> "AccuracyStats":
        """The errors of position residuals dp (N, 3) metres and rotation residuals dr (N, 3)
        radians, the rotation vectors of R_model R_measured^T (None for position-only data)."""
        return AccuracyStats(np.linalg.norm(dp, axis=1), None if dr is None else np.linalg.norm(dr, axis=1))

    @property
    def n_poses(self) -> int:
        return len(self.position_errors)

    def subset(self, mask: np.ndarray) -> "AccuracyStats":
        """The errors of the rows selected by ``mask`` ((N,) bool or indices)."""
        return AccuracyStats(self.position_errors[mask],
                             None if self.rotation_errors is None else self.rotation_errors[mask])

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
                rotation: np.ndarray | None, kin: ChainKinematics | None = None,
                targets: np.ndarray | None = None) -> AccuracyStats:
    """Errors of ``robot``'s tool poses at Q (N, n) against positions (N, 3) m and rotations
    (targets: (N,) each row's target index for a multi-target model)."""
    kin = kin or ChainKinematics(robot)
    if kin.values is not robot.values:
        kin.set_values(robot.values)
    R, p = kin.frame_poses(Q, targets=targets)
    dr = None if rotation is None else log3_batch(R @ np.transpose(rotation, (0, 2, 1)))
    return AccuracyStats.from_residuals(p - position, dr)


def evaluate(robot: RobotModel, measurements: Measurements) -> AccuracyStats:
    """Accuracy of ``robot`` against all rows of ``measurements`` (tool pose in the meas frame).

    Rows of several targets are compared with the model's transform of their target; a model
    with one tool frame serves every target with it (:meth:`RobotModel.with_targets`).
    """
    check_robot(robot)
    check_measurements(measurements)
    _check_compatible(robot, measurements)
    robot = with_measured_targets(robot, measurements)
    return pose_errors(robot, measurements.q, measurements.position, measurements.rotation,
                       targets=target_rows(robot, measurements))


def with_measured_targets(robot: RobotModel, *measurements: Measurements | None) -> RobotModel:
    """A one-tool-frame ``robot`` with the targets of the measurements (two or more ids: one
    flange->target transform each, starting at the model's tool transform); unchanged for data
    of one target and for a model that has targets already (:func:`target_rows` then refuses
    an id it does not know)."""
    ids = tuple(dict.fromkeys(t for m in measurements if m is not None for t in m.target_ids))
    if len(ids) < 2 or robot.targets:
        return robot
    return robot.with_targets(ids)


def target_rows(robot: RobotModel, m: Measurements) -> np.ndarray | None:
    """(N,) int: each row's target index in ``robot.targets`` (None for a one-tool-frame model);
    an unknown id is a :class:`DataError` naming the file and row."""
    if not robot.targets:
        return None
    where = f"{m.source}: " if m.source is not None else ""
    if m.target is None:
        raise DataError(f"{where}the model has {robot.n_targets} targets ({', '.join(robot.targets)}): "
                        f"the measurements need a target column")
    for row, t in zip(m.rows, m.target):
        if t not in robot.targets:
            raise DataError(f"{where}row {row}, column target: {t!r} is not a target of the model "
                            f"({', '.join(robot.targets)})")
    return robot.target_rows(m.target)


# ====================================================================== stage objects
@dataclass(frozen=True)
class Outlier:
    """A calibration row left out of the fit: its line in the file, its errors after the fit
    (metres, radians; rotation NaN for position-only data) and its residual RMS in sigma."""

    row: int
    position_error: float
    rotation_error: float
    sigmas: float


@dataclass(frozen=True)
class Setup:
    """The prepare stage: what the fit works on.

    nominal : the model calibration started from (with the measured targets); start : the same
    with its reference frames moved to the closed-form estimates (or ``nominal``); cal / val :
    calibration and validation rows (val None without any); measure : "pose" or "position";
    rebased : which of "measurement->base", "flange->tool" (or "flange-><id>" per target) were
    moved; suspect : (N,) bool over the calibration rows, those the closed-form frame estimate
    left out as gross (the fit starts without them and takes back those its model explains), or
    None; kin : ``start``'s kinematics (a scratch workspace the stages share; None: built when
    needed).
    """

    nominal: RobotModel
    start: RobotModel
    cal: Measurements = field(repr=False)
    val: Measurements | None = field(repr=False)
    measure: str
    rebased: tuple[str, ...]
    suspect: np.ndarray | None = field(default=None, repr=False)
    kin: ChainKinematics | None = field(default=None, repr=False, compare=False)

    @property
    def components_per_pose(self) -> int:
        return 6 if self.measure == "pose" else 3


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
    p_value: float | None
    iterations: int

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.dof, 1e-300)

    def to_dict(self) -> dict:
        return {"position_mm": self.position * 1e3, "rotation_rad": self.rotation,
                "estimated": self.estimated, "iterations": self.iterations,
                "reduced_chi2": self.reduced_chi2, "dof": self.dof,
                "chi2_test": None if self.estimated else {
                    "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                    "reduced_chi2_position": self.chi2_pos, "reduced_chi2_rotation": self.chi2_rot}}


@dataclass(frozen=True)
class Fit:
    """The fit stage: the identified model and how it was reached.

    model : the calibrated model; free : names of the identified parameters; solver : the
    solver's result for the last fit (x, cost in the final noise weights, status, message, ...);
    keep : (N_cal,) bool, rows used (False for outliers); outliers; noise : the weights used and
    the residuals' agreement with them; iterations : LM iterations of every fit in the stage;
    covariance : (n_free, n_free) covariance of the free parameters (SI units) in the final noise
    weights, from the least-squares normal equations at the solution; full_rank : False when it
    is a pseudo-inverse; all_rows : the problem of every calibration row, kept or not.
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

    @property
    def errors(self) -> AccuracyStats:
        """The calibrated model's errors on every calibration row (outliers included); the fit's
        outlier check has computed them at the solution."""
        return AccuracyStats.from_residuals(*self.all_rows.pose_residuals(self.solver.x))


@dataclass(frozen=True)
class Statistics:
    """The statistics stage.

    covariance : (n_free, n_free) covariance of the free parameters (SI units), from the noise
    levels of the fit; full_rank : False when it is a pseudo-inverse. rank : rank of the weighted
    Jacobian. predicted : RMS error of the calibrated model against the true poses at ``where``
    (position_rms m, rotation_rms rad): the covariance propagated to the poses. predicted_holdout :
    RMS error against new measured rows: the covariance inflated by the measured misfit, plus the
    measurement noise (inflated likewise).
    """

    covariance: np.ndarray = field(repr=False)
    full_rank: bool
    rank: int
    predicted: dict
    predicted_holdout: dict
    where: str


@dataclass(frozen=True)
class CrossValidation:
    """K-fold cross-validated held-out error of a fit: each fold's rows predicted by the model
    fitted on the other folds. position_rms (m) and rotation_rms (rad, None position only) pooled
    over every held-out row; per_fold : per fold (rows, position_rms, rotation_rms);
    row_scores : (n,) whitened squared held-out error of each kept row (position and rotation,
    weighted by the fit's noise levels; rows in the order of the calibration rows);
    score / score_se : their mean and its standard error."""

    folds: int
    position_rms: float
    rotation_rms: float | None
    per_fold: tuple[tuple[int, float, float | None], ...]
    score: float
    score_se: float
    row_scores: np.ndarray = field(repr=False, default=None)

    def to_dict(self) -> dict:
        return {"folds": self.folds, "position_rms_mm": self.position_rms * 1e3,
                "rotation_rms_rad": self.rotation_rms,
                "per_fold": [{"rows": n, "position_rms_mm": p * 1e3, "rotation_rms_rad": r}
                             for n, p, r in self.per_fold]}


@dataclass(frozen=True)
class Candidate:
    """One candidate parameter set of the model selection and its cross-validated error."""

    label: str
    free: tuple[str, ...]
    cv: CrossValidation


@dataclass(frozen=True)
class ModelSelection:
    """``params="auto"``: the candidates (smallest first) and the chosen one: the smallest whose
    cross-validated score exceeds the best one's by at most one standard error of their paired
    row-by-row difference (the one-standard-error rule)."""

    candidates: tuple[Candidate, ...]
    chosen: str
    best: str

    def to_dict(self) -> dict:
        return {"chosen": self.chosen, "best": self.best, "rule": "one standard error",
                "candidates": [{"label": c.label, "n_free": len(c.free), "score": c.cv.score,
                                "score_se": c.cv.score_se, "position_rms_mm": c.cv.position_rms * 1e3,
                                "rotation_rms_rad": c.cv.rotation_rms} for c in self.candidates]}

    def format(self) -> str:
        lines = [f"model selection ({self.candidates[0].cv.folds}-fold cross-validation, one-standard-error "
                 f"rule toward the smaller set; score: mean noise-weighted squared held-out error per row):",
                 f"  {'candidate':<26}{'params':>7}{'score':>10}{'+-se':>9}{'pos rms/mm':>12}{'rot rms/rad':>13}"]
        for c in self.candidates:
            rot = "-" if c.cv.rotation_rms is None else f"{c.cv.rotation_rms:.3e}"
            mark = "  <- chosen" if c.label == self.chosen else ("  (lowest)" if c.label == self.best else "")
            lines.append(f"  {c.label:<26}{len(c.free):>7}{c.cv.score:>10.3f}{c.cv.score_se:>9.3f}"
                         f"{c.cv.position_rms * 1e3:>12.4f}{rot:>13}{mark}")
        return "\n".join(lines)


# ====================================================================== result
@dataclass(frozen=True)
class TargetAccuracy:
    """Accuracy on the rows of one target of a multi-target calibration (see
    :class:`AccuracyStats`): before / after on the calibration rows, and on the validation rows
    (None without validation data)."""

    target: str
    before: AccuracyStats = field(repr=False)
    after: AccuracyStats = field(repr=False)
    validation_before: AccuracyStats | None = field(default=None, repr=False)
    validation_after: AccuracyStats | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"before": self.before.to_dict(), "after": self.after.to_dict(),
                "validation": None if self.validation_after is None else {
                    "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()}}


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
    status : "converged", "max_iterations", "diverged" or "local_minimum" (an explicit lm / c-lm
    fit that a search from another start beats); success : status == "converged".
    before, after : accuracy on the calibration rows (outliers included); after_without_outliers :
    the same without the rows flagged as outliers (None when none were); validation_before/after
    on the validation rows (None without validation data); before_registered /
    validation_before_registered : the nominal model after a best-fit registration of the
    measurement frame, with the tool (or target) frames at their closed-form estimates when those
    were far from the nominal ones (None unless a frame was: the nominal model's errors otherwise).
    noise : the noise levels of the fit (:class:`NoiseEstimate`); sigma_pos, sigma_rot : the same
    numbers (sigma_rot is that of the weighting also for position-only data).
    predicted : the Cramer-Rao prediction of the calibrated model's RMS error against the true
    poses (position_rms m, rotation_rms rad, where); predicted_holdout : the RMS error expected on
    new measured rows (:class:`Statistics`). cross_validation, selection : see
    :class:`CrossValidation`, :class:`ModelSelection` (None when not run).
    covariance : (n_free, n_free) covariance of the free parameters (SI units).
    estimated_frames : the frames estimated in closed form because the data put them far from the
    nominal ones ("measurement->base", "flange->tool" or "flange-><id>" per target; () if none):
    the calibrated model's base frame is then the instrument's, its tool the measured point.
    targets : per target of a multi-target calibration, its accuracy (:class:`TargetAccuracy`;
    the overall figures are ``before``/``after``); () for one target.
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
    outliers: tuple[Outlier, ...] = ()
    loss: str = "linear"
    noise: NoiseEstimate | None = None
    predicted_holdout: dict | None = field(default=None, repr=False)
    cross_validation: CrossValidation | None = field(default=None, repr=False)
    selection: ModelSelection | None = field(default=None, repr=False)
    before_registered: AccuracyStats | None = field(default=None, repr=False)
    validation_before_registered: AccuracyStats | None = field(default=None, repr=False)
    targets: tuple[TargetAccuracy, ...] = field(default=(), repr=False)
    after_without_outliers: AccuracyStats | None = field(default=None, repr=False)
    estimated_frames: tuple[str, ...] = ()

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
        """Write the calibrated model as a URDF (see :func:`calib.io.urdf_writer.write_calibrated_urdf`).

        The URDF holds the geometry; with compliance, the compliances go to the sidecar
        :func:`calib.io.compliance_file.sidecar_path` beside it (:func:`calib.io.compliance_file.write_sidecar`)."""
        from calib.io.urdf_writer import write_calibrated_urdf

        write_calibrated_urdf(self.robot.geometry(), path, nominal=self.nominal.geometry(),
                              estimated=self.estimated_frames)
        if self.robot.has_compliance:
            from calib.io.compliance_file import sidecar_path, write_sidecar

            write_sidecar(sidecar_path(path), self.compliance_record())

    def compliance_record(self) -> dict | None:
        """The compliances with their std, payload and gravity (:func:`calib.io.compliance_file.compliance_record`),
        None for a model without compliance."""
        if not self.robot.has_compliance:
            return None
        from calib.io.compliance_file import compliance_record

        return compliance_record(self.robot, {p.name: p.std for p in self.parameters if p.free})

    def to_dict(self) -> dict:
        """JSON-ready report: keys status, before, after, validation, parameters, noise, ..."""
        has_rot = self.predicted.get("rotation_rms") is not None
        ph = self.predicted_holdout
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
            "noise": None if self.noise is None else self.noise.to_dict(),
            "notes": list(self.notes),
            "loss": self.loss,
            "outliers": [{"row": o.row, "position_error_mm": o.position_error * 1e3,
                          "rotation_error_rad": None if math.isnan(o.rotation_error) else o.rotation_error,
                          "sigmas": o.sigmas} for o in self.outliers],
            "before": self.before.to_dict(),
            "after": self.after.to_dict(),
            "estimated_frames": list(self.estimated_frames),
            "after_without_outliers": None if self.after_without_outliers is None
            else self.after_without_outliers.to_dict(),
            "before_registered": None if self.before_registered is None else {
                "calibration": self.before_registered.to_dict(),
                "validation": None if self.validation_before_registered is None
                else self.validation_before_registered.to_dict()},
            "validation": None if self.validation_after is None else {
                "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()},
            "targets": {t.target: t.to_dict() for t in self.targets} or None,
            "predicted_rms": {"position_mm": self.predicted["position_rms"] * 1e3,
                              "rotation_rad": self.predicted.get("rotation_rms"),
                              "where": self.predicted.get("where")},
            "predicted_holdout_rms": None if ph is None else {
                "position_mm": ph["position_rms"] * 1e3,
                "rotation_rad": ph["rotation_rms"] if has_rot else None},
            "cross_validation": None if self.cross_validation is None else self.cross_validation.to_dict(),
            "model_selection": None if self.selection is None else self.selection.to_dict(),
            "compliance": self.compliance_record(),
            "parameters": [{"name": p.name, "unit": _unit(p.unit),
                            "nominal": _out(p.nominal, p.unit), "identified": _out(p.identified, p.unit),
                            "deviation": _out(p.deviation, p.unit),
                            "std": None if math.isnan(p.std) else _out(p.std, p.unit),
                            "free": p.free} for p in self.parameters],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    def format(self) -> str:
        """The report for a person: parameter table, accuracy before/after, status."""
        nz = self.noise
        lines = [f"Calibration: {self.method.upper()}, parameter set {self.param_set!r} "
                 f"({len(self.free)} identified of {len(self.parameters)}), {self.status}: {self.message}",
                 f"  {self.iterations} LM iterations in all (every fit of the calibration), {self.rounds} rounds, {self.wall_time * 1e3:.1f} ms"]
        if nz is not None:
            rot = "" if nz.rotation is None else f", orientation {nz.rotation:.3g} rad"
            if nz.estimated:
                lines.append(f"  noise estimated from the residuals ({nz.iterations} re-weighted fits): "
                             f"position {nz.position * 1e3:.4g} mm{rot} per axis")
            else:
                lines.append(f"  noise given: position {nz.position * 1e3:g} mm{rot} per axis; residuals "
                             f"vs that noise: reduced chi^2 {nz.reduced_chi2:.3g} over {nz.dof:.0f} degrees "
                             f"of freedom (p = {nz.p_value:.3g}{', consistent' if nz.p_value > 0.01 else ', NOT consistent'})")
        lines += [f"  note: {n}" for n in self.notes]
        for o in self.outliers:
            rot = "" if math.isnan(o.rotation_error) else f", {o.rotation_error:.3g} rad"
            lines.append(f"  outlier: row {o.row}: {o.position_error * 1e3:.3f} mm{rot} ({o.sigmas:.0f} sigma)")
        if self.selection is not None:
            lines += ["", self.selection.format()]
        w = max([10] + [len(p.name) + 1 for p in self.parameters])
        lines += ["", f"{'parameter':<{w}}{'unit':>5}{'nominal':>14}{'identified':>14}{'deviation':>13}{'std':>11}"]
        if self.robot.has_compliance:
            lines.insert(-1, f"  note: {URDF_NOTE}")
        for p in self.parameters:
            unit = _unit(p.unit)
            std = "fixed" if not p.free else f"{_out(p.std, p.unit):.3g}"
            lines.append(f"{p.name:<{w}}{unit:>5}{_out(p.nominal, p.unit):>14.6f}"
                         f"{_out(p.identified, p.unit):>14.6f}{_out(p.deviation, p.unit):>13.6f}{std:>11}")
        rows = [("calibration rows, before", self.before)]
        if self.before_registered is not None:
            rows.append(("  before, frame registered", self.before_registered))
        rows.append(("calibration rows, after", self.after))
        if self.after_without_outliers is not None:
            rows.append(("  after, without outliers", self.after_without_outliers))
        if self.validation_after is not None:
            rows.append(("validation rows, before", self.validation_before))
            if self.validation_before_registered is not None:
                rows.append(("  before, frame registered", self.validation_before_registered))
            rows.append(("validation rows, after", self.validation_after))
        for t in self.targets:
            rows += [(f"target {t.target}, before", t.before), (f"target {t.target}, after", t.after)]
            if t.validation_after is not None:
                rows += [(f"target {t.target}, val. before", t.validation_before),
                         (f"target {t.target}, val. after", t.validation_after)]
        lines += ["", format_accuracy_table(rows)]
        if self.cross_validation is not None:
            cv = self.cross_validation
            rot = "" if cv.rotation_rms is None else f", orientation {cv.rotation_rms:.3g} rad"
            kind = "leave-one-out" if cv.folds == sum(n for n, _, _ in cv.per_fold) else f"{cv.folds}-fold"
            lines.append(f"cross-validated ({kind}) held-out RMS error: position "
                         f"{cv.position_rms * 1e3:.4g} mm{rot}")
        pr = self.predicted
        rot = "" if pr.get("rotation_rms") is None else f", orientation {pr['rotation_rms']:.3g} rad"
        if self.predicted_holdout is not None:
            ph = self.predicted_holdout
            rot_h = "" if pr.get("rotation_rms") is None else f", orientation {ph['rotation_rms']:.3g} rad"
            lines.append(f"predicted RMS error on new measured rows ({pr['where']}): position "
                         f"{ph['position_rms'] * 1e3:.4g} mm{rot_h}")
        lines.append(f"predicted RMS error of the calibrated model against the true poses (Cramer-Rao, "
                     f"{pr['where']}): position {pr['position_rms'] * 1e3:.4g} mm{rot}")
        return "\n".join(lines)


#: Units at the edges (tables, JSON) for each SI unit of a parameter, and the factor from SI.
_EDGE_UNITS = {"m": ("mm", 1e3), "rad": ("rad", 1.0), "rad/(N m)": ("urad/(N m)", 1e6),
               "m/N": ("um/N", 1e6)}


def _out(value: float, unit: str) -> float:
    return value * _EDGE_UNITS[unit][1]


def _unit(unit: str) -> str:
    return _EDGE_UNITS[unit][0]


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


# ====================================================================== stages
def _check_compatible(robot: RobotModel, m: Measurements) -> None:
    if m.n_joints != robot.n_joints:
        raise DataError(f"the measurements have {m.n_joints} joint values per pose, the robot "
                        f"{robot.n_joints} joints ({', '.join(robot.joint_names)})")


def _check_options(method, sigma_pos, sigma_rot, init_frames, max_rounds, fixed_rounds, loss,
                   loss_scale, outlier_k, cv) -> str:
    """Every option of :func:`calibrate` checked before any work (as scipy's least_squares does)."""
    if not isinstance(method, str) or method.lower() not in METHODS:
        raise ParameterError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    check_number(sigma_pos, "sigma_pos", minimum=0.0, strict=True, allow_none=True)
    check_number(sigma_rot, "sigma_rot", minimum=0.0, strict=True, allow_none=True)
    for value, name in ((sigma_pos, "sigma_pos"), (sigma_rot, "sigma_rot")):
        if value is not None and not 1e-12 <= value <= 1.0:
            raise ParameterError(f"{name} must be between 1e-12 and 1 (metres / radians), got {value!r}")
    if init_frames not in (True, False, "auto"):
        raise ParameterError(f"init_frames must be True, False or 'auto', got {init_frames!r}")
    check_int(max_rounds, "max_rounds", minimum=1)
    check_int(fixed_rounds, "fixed_rounds", minimum=1, allow_none=True)
    if loss not in LOSSES:
        raise ParameterError(f"unknown loss {loss!r}: expected one of {', '.join(LOSSES)}")
    check_number(loss_scale, "loss_scale", minimum=0.0, strict=True)
    check_number(outlier_k, "outlier_k", minimum=0.0, strict=True, allow_none=True)
    if cv is not None and (isinstance(cv, bool) or not isinstance(cv, (int, np.integer)) or cv < 0 or cv == 1):
        raise ParameterError(f"cv must be 0 (off) or a number of folds >= 2, got {cv!r}")
    return method.lower()


def prepare(robot: RobotModel, measurements: Measurements, validation: Measurements | None = None,
            init_frames: bool | str = "auto") -> tuple[Setup, list[str]]:
    """The prepare stage: rows, what is measured, closed-form frames (see the module docstring).
    Returns the :class:`Setup` and notes for the user. Data of several targets give the nominal
    model one flange->target transform per target (:func:`with_measured_targets`)."""
    _check_compatible(robot, measurements)
    robot = with_measured_targets(robot, measurements, validation)
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
    _check_plausible_positions(robot, measurements)
    if validation is not None:
        _check_plausible_positions(robot, validation)
    distinct = distinct_configurations(cal.q)
    needed = 0
    if distinct * rows_per_pose < robot.n_params:
        needed = analyze_identifiability(robot, robot.random_configurations(50, 0), measure=measure).rank
    if distinct * rows_per_pose < needed:
        where = f"{measurements.source}: " if measurements.source is not None else ""
        what = (f"{cal.n_poses} calibration poses" if distinct == cal.n_poses else
                f"{cal.n_poses} calibration rows at {distinct} distinct configuration(s)")
        raise DataError(f"{where}{what} give {distinct * rows_per_pose} "
                        f"{'' if distinct == cal.n_poses else 'independent '}equations, "
                        f"fewer than the {needed} identifiable parameters need; measure at least "
                        f"{-(-needed // rows_per_pose)} distinct poses (several times more for accuracy)")
    notes += _duplicate_row_notes(cal, val)
    start, rebased, suspect = robot, (), None
    kin = ChainKinematics(robot)
    if init_frames:
        start, rebased, suspect = _rebase_frames(robot, cal, notes, always=init_frames is True, kin=kin)
    return Setup(robot, start, cal, val, measure, rebased, suspect,
                 kin if start is robot else ChainKinematics(start)), notes


def _earliest_equal_rows(*ms: Measurements) -> np.ndarray:
    """For the rows of ``ms`` one after the other, the index of the first row equal to each (its
    own index when none before it is): joint values, measured pose and target, bit for bit."""
    x = np.concatenate([m.position[:, 0] for m in ms]) + 0.0       # + 0.0: -0.0 equals 0.0
    first = np.arange(len(x))
    # equal rows have an equal measured x: only rows whose x recurs are compared in full (a
    # sort of all 19 columns takes 0.8 s on 200,000 rows)
    o = np.argsort(x, kind="stable")
    same_x = np.flatnonzero(x[o][1:] == x[o][:-1])
    cand = np.unique(np.concatenate([o[same_x], o[same_x + 1]]))
    if not cand.size:
        return first
    ids = {t: k for k, t in enumerate(dict.fromkeys(t for m in ms if m.target is not None for t in m.target))}
    blocks = []
    for m in ms:
        parts = [m.q, m.position] + ([m.rotation.reshape(m.n_poses, 9)] if m.rotation is not None else [])
        code = [ids[t] for t in m.target] if m.target is not None else np.full(m.n_poses, -1)
        blocks.append(np.column_stack(parts + [np.asarray(code, float)]))
    K = np.vstack(blocks)[cand] + 0.0
    order = np.lexsort(K.T[::-1])          # stable: equal rows stay in their order
    S = K[order]
    starts = np.concatenate([[True], np.any(S[1:] != S[:-1], axis=1)])
    first[cand[order]] = cand[order[np.flatnonzero(starts)[np.cumsum(starts) - 1]]]
    return first


def _duplicate_row_notes(cal: Measurements, val: Measurements | None) -> list[str]:
    """Notes naming rows that repeat an earlier row exactly (joints, measured pose and target):
    a copy (a row pasted twice, a file appended to itself) is not a second measurement, yet the
    noise estimate, the standard deviations and the predicted errors would count it as one, and
    a validation row that copies a calibration row validates nothing."""
    def listing(rows, firsts):
        shown = ", ".join(f"{r} = {f}" for r, f in list(zip(rows, firsts))[:8])
        return shown + (f" and {len(rows) - 8} more" if len(rows) > 8 else "")

    notes = []
    first = _earliest_equal_rows(cal)
    k = np.flatnonzero(first != np.arange(cal.n_poses))
    if k.size:
        notes.append(f"{k.size} calibration row(s) repeat an earlier row exactly (joints and measured "
                     f"pose; row = earlier row: {listing(cal.rows[k], cal.rows[first[k]])}): a copy is "
                     f"not a new measurement, but the noise estimate, the standard deviations and the "
                     f"predicted errors count it as one and are too optimistic; remove the copies")
    if val is not None and val.n_poses and val.has_orientation == cal.has_orientation:
        first = _earliest_equal_rows(cal, val)[cal.n_poses:]
        k = np.flatnonzero(first < cal.n_poses)
        if k.size:
            notes.append(f"{k.size} validation row(s) repeat a calibration row exactly (validation row = "
                         f"calibration row: {listing(val.rows[k], cal.rows[first[k]])}): they are not "
                         f"held out, and the validation errors are too optimistic")
    return notes


def distinct_configurations(Q: np.ndarray, tol: float = DISTINCT_Q_TOL) -> int:
    """The number of distinct rows of Q (N, n) (rad / m), rows equal to ``tol`` counted once."""
    if len(Q) == 0:
        return 0
    # rows sorted lexicographically, then the changes counted: np.unique(axis=0) without its
    # import of numpy.ma (20 ms of the CLI's start); + 0.0 makes -0.0 equal to 0.0
    K = np.round(np.asarray(Q, float).reshape(len(Q), -1) / tol) + 0.0
    S = K[np.lexsort(K.T[::-1])]
    return 1 + int(np.count_nonzero(np.any(S[1:] != S[:-1], axis=1)))


#: Results that depend only on the robot model (structure, values, frames, limits, gravity) and
#: options, kept for the next calibrations of the same model: see :func:`_robot_memo`.
_ROBOT_MEMO: OrderedDict = OrderedDict()


def _robot_memo(kind: str, robot: RobotModel, options: tuple, compute):
    """``compute()``, or its value from an earlier call with the same ``kind``, model and
    ``options`` (the last 64 kept)."""
    from calib.model.identifiability import _cache_key

    limits = np.stack([robot.lower, robot.upper])
    key = (kind, _cache_key(robot, limits, "pose", 1.0, 1.0, 1.0, None, None),
           repr(getattr(robot, "gravity", None)), options)
    if key in _ROBOT_MEMO:
        _ROBOT_MEMO.move_to_end(key)
        return _ROBOT_MEMO[key]
    value = _ROBOT_MEMO[key] = compute()
    while len(_ROBOT_MEMO) > 64:
        _ROBOT_MEMO.popitem(last=False)
    return value


def _reach(robot: RobotModel) -> float:
    """The farthest tool position from the meas frame's origin over 256 random configurations
    (seed 0), metres."""
    _, p = ChainKinematics(robot).frame_poses(robot.random_configurations(256, 0))
    return float(np.linalg.norm(p, axis=1).max())


def _check_plausible_positions(robot: RobotModel, m: Measurements) -> None:
    """Refuse positions no tracker could have measured of this robot: farther from the meas
    frame's origin than the robot's reach (the farthest tool position over random
    configurations, from the nominal meas frame) plus :data:`TRACKER_RANGE_M`."""
    reach = _robot_memo("reach", robot, (), lambda: _reach(robot))
    bound = reach + TRACKER_RANGE_M
    dist = np.linalg.norm(m.position, axis=1)
    bad = np.flatnonzero(~(dist <= bound))
    if bad.size:
        rows = ", ".join(str(r) for r in m.rows[bad[:10]]) + (" ..." if bad.size > 10 else "")
        where = m.source or "<measurements>"
        raise DataError(f"{where}: row(s) {rows}: position {dist[bad[0]] * 1e3:.6g} mm from the "
                        f"measurement frame's origin, farther than any tracker measures this robot "
                        f"(reach {reach * 1e3:.0f} mm + {TRACKER_RANGE_M:g} m): wrong length unit "
                        f"in the column name, or gross errors")


def check_data_rank(robot: RobotModel, m: Measurements, measure: str, free: Sequence[str], *,
                    derived: bool, sigma_pos: float = SIGMA_POS_M, sigma_rot: float = SIGMA_ROT_RAD) -> None:
    """Refuse data whose own Jacobian identifies fewer parameter combinations than the model
    needs: the rank of the noise-weighted identification Jacobian at the rows' configurations
    (at most 500, evenly spaced) against its rank at 50 random configurations within the joint
    limits. ``free`` are the parameters to identify; ``derived`` (the set was chosen from these
    data: base, auto) compares all parameters, since a set chosen from degenerate data is
    degenerate too. A non-finite Jacobian is refused naming its parameters."""
    cols = list(range(robot.n_params)) if derived else list(robot.indices(free))
    Q = m.q if len(m.q) <= 500 else m.q[np.linspace(0, len(m.q) - 1, 500).astype(int)]
    options = (measure, float(sigma_pos), float(sigma_rot), tuple(cols))

    def data_rank():
        Jd = weighted_jacobian(robot, Q, measure, sigma_pos, sigma_rot)[:, cols]
        finite = np.isfinite(Jd).all(axis=0)
        if not finite.all():
            names = [robot.names[cols[k]] for k in np.flatnonzero(~finite)]
            raise DataError(f"{m.source or '<measurements>'}: the identification Jacobian is not finite "
                            f"for {', '.join(names)}")
        return tuple(select_identifiable(Jd, range(len(cols)))[0])

    # both ranks are kept per model (and data): a calibration repeated on the same data, e.g.
    # with another method, does not redo them
    digest = hashlib.blake2b(np.ascontiguousarray(Q, float).tobytes(), digest_size=20).hexdigest()
    kept_d = _robot_memo("data rank", robot, options + (Q.shape, digest), data_rank)

    def random_rank():
        Jr = weighted_jacobian(robot, robot.random_configurations(50, 0), measure, sigma_pos, sigma_rot)[:, cols]
        return tuple(select_identifiable(Jr, range(len(cols)))[0])

    kept_r = _robot_memo("random rank", robot, options, random_rank)
    if len(kept_d) < len(kept_r):
        lost = [robot.names[cols[k]] for k in kept_r if k not in set(kept_d)]
        n_q = distinct_configurations(m.q)
        raise DataError(f"{m.source or '<measurements>'}: the {m.n_poses} calibration rows ({n_q} distinct "
                        f"configurations) identify {len(kept_d)} parameter combinations, random poses "
                        f"{len(kept_r)}: the rows cannot identify {', '.join(lost)} (measure poses that "
                        f"move every joint over its range"
                        + (", or name the parameters to identify with params / --params)" if derived else ")"))


def _rebase_frames(robot: RobotModel, m: Measurements, notes: list, always: bool = False,
                   kin: ChainKinematics | None = None) -> tuple[RobotModel, tuple[str, ...], np.ndarray | None]:
    """Move the reference frames to closed-form estimates when the data put them far away
    (or ``always``; kin: ``robot``'s kinematics at its values, to reuse). Returns the model, the
    frames moved and the rows the robust estimate left out (bool mask, or None when none)."""
    try:
        est = estimate_frames_robust(robot, m.q, m.position, m.rotation, target_rows(robot, m), kin=kin)
    except DataError as exc:
        notes.append(f"frames not initialised in closed form ({exc}); started from the nominal frames")
        return robot, (), None
    X, Y = est.T_meas_base, est.T_flange_targets
    if not est.inliers.all():
        out_rows = m.rows[~est.inliers]
        shown = ", ".join(str(r) for r in out_rows[:20]) + (" ..." if len(out_rows) > 20 else "")
        notes.append(f"{len(out_rows)} row(s) left out of the closed-form frame estimate, their "
                     f"residuals beyond {est.threshold_position * 1e3:.3g} mm"
                     + (f" or {est.threshold_rotation:.3g} rad" if est.threshold_rotation is not None else "")
                     + f" (gross errors?): rows {shown}")
    out, moved = robot, []
    refs = robot.T_flange_tool_refs.copy()
    tools = [(f"flange->{t}" if robot.targets else "flange->tool", k) for k, t in
             enumerate(robot.targets or ("tool",))]
    for label, k in [("measurement->base", None)] + tools:
        T_nom, T_est = (robot.T_meas_base(), X) if k is None else (robot.T_flange_tool(k), Y[k])
        dT = inverse(T_nom) @ T_est
        dist = float(np.linalg.norm(dT[:3, 3]))
        ang = float(np.linalg.norm(log3_batch(dT[None, :3, :3])[0]))
        if always or dist > FRAME_REBASE_M or ang > FRAME_REBASE_RAD:
            if k is None:
                out = replace(out, T_meas_base_ref=T_est @ inverse(zyx_transform(*robot.u())))
            else:
                refs[k] = inverse(zyx_transform(*robot.v(k))) @ T_est
                out = replace(out, T_flange_tool_ref=refs[0],
                              T_flange_target_refs=refs.copy() if robot.targets else None)
            moved.append(label)
            notes.append(f"{label} initialised in closed form: {dist * 1e3:.1f} mm and {ang:.3g} rad "
                         f"from the nominal transform")
    return out, tuple(moved), (None if est.inliers.all() else ~est.inliers)


# ---------------------------------------------------------------- parameter sets
def _idealised(robot: RobotModel) -> RobotModel:
    """The model with its small deviations removed: angles within 0.05 rad of a multiple of pi/2
    and lengths within 1 mm of zero snapped there. Which parameters tie to which is decided on
    this model, so that it does not depend on where a perturbed model happens to be linearised."""
    v = robot.values
    angle = np.array([p.unit == "rad" for p in robot.parameters], bool)
    snapped = np.where(angle, np.round(v / (math.pi / 2)) * (math.pi / 2), 0.0)
    near = np.abs(v - snapped) < np.where(angle, 0.05, 1e-3)
    return robot.with_values(np.where(near, snapped, v))


def _set_rank_deficit(setup: Setup, free: Sequence[str], weights: tuple[float, float]) -> int:
    """How many directions the parameter set ``free`` leaves undetermined at the start model on
    the calibration rows: its size minus the identifiable parameters a greedy selection with
    ``free`` first keeps (a maximal independent part of it)."""
    kept = set(analyze_identifiability(setup.start, setup.cal.q, measure=setup.measure, sigma_pos=weights[0],
                                       sigma_rot=weights[1], priority=free,
                                       targets=target_rows(setup.start, setup.cal)).identifiable)
    return len(free) - sum(name in kept for name in free)


def identifiable_set(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                     sigma_rot: float = SIGMA_ROT_RAD, targets: np.ndarray | None = None) -> tuple[str, ...]:
    """The identifiable parameter names at configurations Q (N, n) (see
    :func:`calib.model.identifiability.analyze_identifiability`), chosen start-independently: the
    partners to hold fixed are picked on the idealised model (:func:`_idealised`) and kept when
    they are also a valid choice at ``robot``; the rank is ``robot``'s. targets: (N,) each
    row's target index for a multi-target model.

    With several targets, their v parameters come first in the priority: the last joint's
    parameters they are tied to are held instead (a rigid motion of the flange that every
    target's v absorbs exactly), never coordinates of single targets (a gauge that turns singular
    as the fit moves)."""
    first = [p.name for p in robot.parameters if p.group == "v"] if robot.targets else None
    ideal = analyze_identifiability(_idealised(robot), Q, measure=measure, sigma_pos=sigma_pos,
                                    sigma_rot=sigma_rot, targets=targets, priority=first).identifiable
    return analyze_identifiability(robot, Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                                   priority=ideal, targets=targets).identifiable


def select_parameters(robot: RobotModel, params, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                      sigma_rot: float = SIGMA_ROT_RAD,
                      targets: np.ndarray | None = None) -> tuple[str, tuple[str, ...]]:
    """(set label, free parameter names) for a ``params`` choice other than "auto"; see
    :func:`calibrate`."""
    if isinstance(params, str):
        key = params.strip().lower()
        if key == "base":
            return "base", identifiable_set(robot, Q, measure, sigma_pos, sigma_rot, targets)
        if key == "paper":
            return "paper", tuple(p.name for p in robot.parameters
                                  if p.name.split("@")[0] not in PAPER_EXCLUDED)
        if key == "all":
            return "all", robot.names
        names = [s.strip() for s in params.split(",") if s.strip()]
        if not names:
            raise ParameterError(f"empty parameter list {params!r}: expected {', '.join(PARAM_SETS)} "
                                 f"or a comma-separated list of parameter names")
        if len(names) == 1 and names[0] not in robot.names:
            raise ParameterError(f"unknown parameter set {params!r}: expected {', '.join(PARAM_SETS)} or a "
                                 f"comma-separated list of parameter names ({', '.join(robot.names)})")
        params = names
    if isinstance(params, (bytes, dict)) or not hasattr(params, "__iter__"):
        raise ParameterError(f"params must be a set name or a list of parameter names, got {params!r}")
    names = tuple(params)
    if not names:
        raise ParameterError("params is an empty list: name at least one parameter")
    if not all(isinstance(n, str) for n in names):
        raise ParameterError(f"params must be parameter names (strings), got {params!r}")
    robot.indices(names)  # raises ParameterError for unknown names
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise ParameterError(f"parameter listed twice: {', '.join(twice)}")
    return "list", tuple(n for n in robot.names if n in names)


def candidate_sets(robot: RobotModel, identifiable: Sequence[str]) -> list[tuple[str, tuple[str, ...]]]:
    """Nested parameter sets for ``params="auto"``, smallest first, each within the identifiable
    set: joint offsets (theta, or d of a prismatic joint) with the measurement and tool frames;
    + lengths (d, a); + twists (alpha, beta); the whole identifiable set. Duplicates dropped."""
    ident = set(identifiable)

    def offset(p) -> bool:
        if p.group != "joint":
            return False
        prismatic = robot.joints[p.joint - 1].is_prismatic
        return p.kind == ("d" if prismatic else "theta")

    steps = [("offsets+frames", lambda p: p.group in ("u", "v", "compliance") or offset(p)),
             ("+lengths", lambda p: p.kind in ("d", "a")),
             ("+twists", lambda p: p.kind in ("alpha", "beta"))]
    out, chosen = [], set()
    for label, pick in steps:
        chosen |= {p.name for p in robot.parameters if pick(p)}
        names = tuple(n for n in robot.names if n in chosen and n in ident)
        if names and (not out or names != out[-1][1]) and set(names) != ident:
            out.append((label, names))
    out.append(("identifiable set", tuple(n for n in robot.names if n in ident)))
    return out


# ---------------------------------------------------------------- fit
@dataclass(frozen=True)
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


def _noise_estimate(problem: Problem, lin: _Linearised, estimated: bool, iterations: int) -> NoiseEstimate:
    """The noise levels of ``problem`` and the residuals' agreement with them, from its
    linearisation ``lin`` at the solution."""
    ne, red_p, red_r = lin.ne, lin.red_pos, lin.red_rot
    dof = red_p + red_r
    chi2 = ne.rss_pos + ne.rss_rot
    p_value = None
    if not estimated:
        # chi-square distribution functions (scipy.special: scipy.stats costs seconds to import);
        # two-sided: residuals far below the given noise disagree with it as much as far above
        from scipy.special import gammainc, gammaincc

        k = max(dof, 1e-9) / 2.0
        p_value = float(min(1.0, 2.0 * min(gammaincc(k, chi2 / 2.0), gammainc(k, chi2 / 2.0))))
    has_rot = problem.has_orientation
    return NoiseEstimate(problem.sigma_pos, problem.sigma_rot if has_rot else None, estimated,
                         red_p, red_r, ne.rss_pos / max(red_p, 1e-300),
                         ne.rss_rot / max(red_r, 1e-300) if has_rot else None, chi2, dof, p_value, iterations)


def _flag_outliers(problem: Problem, x: np.ndarray, rows: np.ndarray, keep: np.ndarray, k: float,
                   sigma_pos: float, sigma_rot: float) -> tuple[list[Outlier], bool]:
    """Rows still kept whose whitened residual RMS per component exceeds k (with the given noise
    levels), and whether they are too many (more than a quarter of the kept rows) to be outliers.
    ``problem`` holds all calibration rows; rows : their line numbers."""
    dp, dr = problem.pose_residuals(x)
    blocks = [dp / sigma_pos]
    rot = np.full(len(dp), np.nan)
    if dr is not None:
        blocks.append(dr / sigma_rot)
        rot = np.linalg.norm(dr, axis=1)
    w = np.concatenate(blocks, axis=1)
    rms = np.sqrt(np.mean(w ** 2, axis=1))
    bad = np.flatnonzero(keep & (rms > k))
    found = [Outlier(int(rows[i]), float(np.linalg.norm(dp[i])), float(rot[i]), float(rms[i])) for i in bad]
    return found, len(bad) > 0.25 * keep.sum()


def _robust_sigmas(problem: Problem, x: np.ndarray, keep: np.ndarray, red_p: float, red_r: float):
    """Noise levels from the median absolute residual component of each group (1.4826 MAD,
    corrected for the fit's share of the degrees of freedom): what outliers cannot inflate."""
    dp, dr = problem.pose_residuals(x)
    n = keep.sum()
    f_p = max(red_p / (3 * n), 1e-3)
    sp = 1.4826 * median(np.abs(dp[keep])) / math.sqrt(f_p)
    sr = problem.sigma_rot
    if dr is not None:
        f_r = max(red_r / (3 * n), 1e-3)
        sr = 1.4826 * median(np.abs(dr[keep])) / math.sqrt(f_r)
    return max(sp, 1e-12), max(sr, 1e-12)


@dataclass(frozen=True)
class _Solve:
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
                 loose: bool = False) -> SolverResult:
        """The first fit (``first``: the method's own scheme) or a re-fit from a near solution
        (LM started with damping WARM_MU0); ``loose``: stop at VCE_FIRST_FTOL (calib's LM only)."""
        if self.lm_variant == "paper":
            return self._paper(problem, x, trace)
        opts = self.options
        if loose:   # (stopping at its last evaluated point, whose normal equations the estimate uses)
            opts = replace(opts, ftol=max(opts.ftol, VCE_FIRST_FTOL), last_step=False)
        if not first:
            return levenberg_marquardt(problem, x, "pose", replace(opts, mu0=min(opts.mu0, WARM_MU0)), trace)
        if self.measure == "position" or self.method == "lm":
            return levenberg_marquardt(problem, x, "pose", opts, trace)
        if self.method == "c-lm":
            return cross_lm(problem, x, self.angular, max_rounds=self.max_rounds,
                            fixed_rounds=self.fixed_rounds, options=opts, trace=trace)
        return search_lm(problem, x, self.angular, self.chain, options=opts, trace=trace)

    def _paper(self, problem: Problem, x: np.ndarray, trace: LMTrace) -> SolverResult:
        """The LM of Eq. (27)-(28) as printed (:mod:`calib.solvers.paper_lm`): unweighted residuals in mm
        and rad, so the noise levels do not change its solution; its cost is re-expressed in the
        fit's noise weights."""
        from calib.solvers.paper_lm import PaperLMOptions, paper_cross_lm, paper_lm

        popts = PaperLMOptions(max_iterations=self.options.max_iterations)
        if self.method == "c-lm" and self.measure == "pose":
            r = paper_cross_lm(problem, x, self.angular, options=popts, max_rounds=self.max_rounds,
                               fixed_rounds=self.fixed_rounds)
        else:
            r = paper_lm(problem, x, self.angular, options=popts)
        trace.iterations += r.iterations
        cost = 0.5 * float(np.sum(problem.residuals(r.x) ** 2))
        return SolverResult(r.x, cost, r.status, f"paper's LM as printed: {r.message}", r.iterations,
                            max(r.rounds, 1))


def _solver_for(setup: Setup, free: Sequence[str], method: str, options: LMOptions, max_rounds: int,
                fixed_rounds: int | None, lm_variant: str = "calib") -> _Solve:
    idx = setup.start.indices(free)
    angular = np.array([setup.start.parameters[k].is_angular for k in idx], bool)
    if method == "search-lm" and setup.start.targets:
        method = "lm"       # the angle search takes one tool frame (a note says so)
    chain = RotationChain(setup.start) if (method == "search-lm" and setup.measure == "pose") else None
    return _Solve(method, setup.measure, options, max_rounds, fixed_rounds, angular, chain, setup.start,
                  lm_variant)


def fit_stage(setup: Setup, free: Sequence[str], solve: _Solve, *, sigma_pos: float | None,
              sigma_rot: float | None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0, keep: np.ndarray | None = None,
              kin: ChainKinematics | None = None, rank_deficit: int = 0) -> tuple[Fit, Problem]:
    """The fit stage: identify ``free`` on the calibration rows of ``setup``.

    sigma_pos (m) / sigma_rot (rad): the noise per axis, or None to estimate it from the residuals
    (variance-component estimation: each group's weight is re-set to its weighted residual sum of
    squares over its redundancy, and the fit repeated, until both change by less than VCE_RTOL).
    With ``outlier_k``, rows whose whitened residual RMS exceeds it (judged against a robust fit,
    with noise levels that outliers cannot inflate) are removed and the fit repeated.
    rank_deficit : how many directions ``free`` leaves undetermined at the nominal model on these
    rows (0 for an identifiable set; see :meth:`calib.solvers.problem.Problem.set_rank_deficit`).
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
    first = True
    stuck = None
    unjudged = False
    vce_total = 0
    two_groups = setup.measure == "pose"
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
        for _ in range(VCE_MAX_ITERATIONS):
            problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
            # (pose data: the weights change the fit, so a re-weighted fit follows the first)
            loose = first and estimate and two_groups
            sol = _solve_logged(solve, problem, x, trace, first, loose=loose)
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
                est_p, est_r = _robust_sigmas(problem, x, np.ones(problem.n_poses, bool), red_p, red_r)
            new_sp = est_p if sigma_pos is None else sp
            new_sr = est_r if (sigma_rot is None and two_groups) else sr
            new_sp, new_sr = max(new_sp, 1e-12), max(new_sr, 1e-12)
            change = max(abs(new_sp / sp - 1.0), abs(new_sr / sr - 1.0))
            sp, sr = new_sp, new_sr
            if (change < VCE_RTOL and not loose) or (not two_groups and loss == "linear"):
                break   # (one group: the weights do not change the fit)
        if outlier_k is None or outlier_pass == 3 or sol.status == "diverged":
            break
        problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
        fsp, fsr = sp, sr
        if estimate:
            lin = linearised(problem, x)
            rsp, rsr = _robust_sigmas(everything, x, keep, lin.red_pos, lin.red_rot)
            fsp = rsp if sigma_pos is None else sp
            fsr = rsr if sigma_rot is None else sr
        new, too_many = _flag_outliers(everything, x, cal.rows, keep, outlier_k, fsp, fsr)
        few = everything.n_poses * (6 if two_groups else 3) < ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM * len(x)
        if loss == "linear" and (new or few):
            # a least-squares fit spreads a gross error over its neighbours: judge the rows
            # against a robust (Huber) fit instead, then refit by least squares without them;
            # on few rows always (there the spread can hide the gross rows altogether)
            x_robust = x
            for _ in range(ROBUST_CHECK_ITERATIONS):
                robust = problem.derived(loss="huber", sigma_pos=fsp, sigma_rot=fsr)
                x_robust = levenberg_marquardt(robust, x_robust, "pose", solve.options, trace).x
                if not estimate:
                    break
                # the noise levels from the robust fit's residuals (a least-squares fit's are
                # smeared by the gross rows), and the robust fit again with them: with several
                # gross rows the first threshold sits near them (5 rows 1-1.5 mm off among 40
                # UR5 rows of 0.05 mm noise: sigma 0.27 mm, none flagged)
                rsp, rsr = _robust_sigmas(everything, x_robust, keep, lin.red_pos, lin.red_rot)
                rsp, rsr = (rsp if sigma_pos is None else sp), (rsr if sigma_rot is None else sr)
                settled = max(abs(rsp / fsp - 1.0), abs(rsr / fsr - 1.0)) < 0.1
                fsp, fsr = rsp, rsr
                if settled:
                    break
            new, too_many = _flag_outliers(everything, x_robust, cal.rows, keep, outlier_k, fsp, fsr)
            if new and not too_many:
                x = x_robust
        if too_many:
            notes.append(f"{len(new)} of {int(keep.sum())} rows have residuals above {outlier_k:g} sigma: "
                         f"the noise is larger than the noise levels (or the model cannot describe the "
                         f"data), so no row was removed as an outlier")
            new = []
        if suspect is not None and not new:
            # the suspect rows against the fit of the others: those within outlier_k are taken
            # back (and the fit repeated), the others are outliers
            still, _ = _flag_outliers(everything, x, cal.rows, suspect, outlier_k, fsp, fsr)
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
        outliers += _flag_outliers(everything, x, cal.rows, suspect, -1.0, sp, sr)[0]
    problem = everything.derived(keep=keep, sigma_pos=sp, sigma_rot=sr)
    if sol.x is not x:   # the last change of x was not solved at these weights (robust start)
        sol = _solve_logged(solve, problem, x, trace, False)
        x = sol.x
    if stuck is not None:
        sol = replace(sol, status=stuck.status, message=stuck.message)
    lin = linearised(problem, x)
    noise = _noise_estimate(problem, lin, estimate, vce_total)
    model = start.with_values(problem.full(x))
    if outliers:
        notes.append(f"{len(outliers)} outlier rows removed and the fit repeated without them: rows "
                     + ", ".join(str(o.row) for o in outliers))
    # (least squares: the cost from the normal equations of the noise estimate)
    cost = lin.ne.cost if problem.loss == "linear" else 0.5 * float(np.sum(problem.residuals(x) ** 2))
    fit = Fit(model, free, replace(sol, cost=cost), keep, tuple(outliers), noise, trace.iterations,
              covariance=lin.inverse, full_rank=lin.full_rank, all_rows=everything, notes=tuple(notes))
    return fit, problem


def _solve_logged(solve: _Solve, problem: Problem, x, trace, first, loose: bool = False) -> SolverResult:
    t = time.perf_counter()
    sol = solve(problem, x, trace, first, loose=loose)
    log.info("fit (%s%s): %s, cost %.6g, %d iterations, %.1f ms", solve.method if first else "lm",
             "" if first else " re-weighted", sol.status, sol.cost, sol.iterations,
             (time.perf_counter() - t) * 1e3)
    return sol


def _check_local_minimum(sol: SolverResult, problem: Problem, solve: _Solve) -> SolverResult:
    """An explicit lm / c-lm fit: an angle search from its solution, then LM; if that reaches a
    clearly lower cost, the fit stopped in a local minimum and is not called converged."""
    if solve.measure != "pose" or solve.method == "search-lm" or sol.status != "converged":
        return sol
    if solve.model.targets:     # the angle search takes one tool frame
        return sol
    chain = solve.chain or RotationChain(solve.model)
    other = search_lm(problem, sol.x, solve.angular, chain, options=solve.options, max_escapes=0)
    # clearly lower: by a fraction of the cost and by more than chance (1 in chi^2 / 2 units)
    if other.cost < LOCAL_MINIMUM_RATIO * sol.cost and sol.cost - other.cost > 1.0:
        msg = (f"{solve.method.upper()} stopped in a local minimum: an angle search from its solution, "
               f"then LM, reaches a cost {other.cost:.4g} below its {sol.cost:.4g} (method search-lm "
               f"escapes it)")
        return replace(sol, status="local_minimum", message=msg)
    return sol


# ---------------------------------------------------------------- statistics
def _propagate(model: RobotModel, Q: np.ndarray, free: Sequence[str], C: np.ndarray,
               kin: ChainKinematics | None = None, targets: np.ndarray | None = None) -> tuple[float, float]:
    """(position, rotation) RMS over configurations Q of the pose error that a parameter error of
    covariance C (free parameters, SI) causes: sqrt of the mean trace of J C J^T (m, rad);
    targets: (N,) each row's target index for a multi-target model."""
    kin = kin or ChainKinematics(model)
    kin.set_values(model.values)
    idx = model.indices(free)
    jacobians = (pose_jacobian(kin, Q[s:s + CHUNK_POSES], idx,
                               targets=None if targets is None else targets[s:s + CHUNK_POSES])[2]
                 for s in range(0, len(Q), CHUNK_POSES))
    return _propagated(jacobians, len(Q), C)


def _propagated(jacobians, n: int, C: np.ndarray) -> tuple[float, float]:
    """(position, rotation) RMS over n poses of J C J^T, from their pose Jacobians (chunks of
    (k, 6, m))."""
    tr_p = tr_r = 0.0
    for Jf in jacobians:
        JC = Jf @ C
        tr_p += float(np.einsum("nij,nij->", JC[:, :3], Jf[:, :3]))
        tr_r += float(np.einsum("nij,nij->", JC[:, 3:], Jf[:, 3:]))
    n = max(n, 1)
    return math.sqrt(max(tr_p, 0.0) / n), math.sqrt(max(tr_r, 0.0) / n)


def predicted_accuracy(robot: RobotModel, Q: np.ndarray, free: Sequence[str], covariance: np.ndarray,
                       targets: np.ndarray | None = None) -> dict:
    """Cramer-Rao prediction of the RMS tool pose error at configurations Q (N, n): position_rms
    (m) and rotation_rms (rad), sqrt of the mean over poses of the trace of J C J^T (targets:
    (N,) each row's target index for a multi-target model)."""
    p, r = _propagate(robot, np.asarray(Q, float), free, covariance, targets=targets)
    return {"position_rms": p, "rotation_rms": r}


def statistics_stage(setup: Setup, fit: Fit, problem: Problem) -> Statistics:
    """Covariance and predictions (see :class:`Statistics`)."""
    x = fit.model.values[fit.model.indices(fit.free)]
    ne = problem.derived(loss="linear").normal_equations(x)
    C, full_rank = fit.covariance, fit.full_rank
    rank = int(round(float(np.trace(C @ ne.A))))
    where = "validation configurations" if setup.val is not None else "calibration configurations"
    Q = setup.val.q if setup.val is not None else setup.cal.q[fit.keep]
    rows = target_rows(fit.model, setup.val) if setup.val is not None else problem.targets
    kin = problem.kin

    def propagate(cov):
        if setup.val is not None:
            return _propagate(fit.model, Q, fit.free, cov, kin, rows)
        # at the calibration rows: the Jacobian of the fit's rows at its solution, computed once
        return _propagated((J for _, _, J in problem.derived(loss="linear").whitened_blocks(x, raw=True)), len(Q), cov)

    pos, rot = propagate(C)
    nz = fit.noise
    has_rot = setup.measure == "pose"
    # misfit: a group whose residuals exceed the given noise inflates both the parameter
    # uncertainty and the error of a new measurement (an estimated noise level already holds it)
    infl_p = 1.0 if nz.estimated else max(1.0, nz.chi2_pos)
    infl_r = 1.0 if (nz.estimated or not has_rot) else max(1.0, nz.chi2_rot)
    if infl_p == 1.0 and infl_r == 1.0:
        pos_e, rot_e = pos, rot
    else:
        A_eff = ne.A_pos / infl_p + (ne.A_rot / infl_r if ne.A_rot is not None else 0.0)
        C_eff, _ = normal_inverse(A_eff)
        pos_e, rot_e = propagate(C_eff)
    if setup.val is not None:
        # new rows at the validation configurations: the parameter error propagated there, plus
        # the measurement noise of the new row
        holdout_p = math.sqrt(pos_e ** 2 + 3.0 * nz.position ** 2 * infl_p)
        holdout_r = math.sqrt(rot_e ** 2 + 3.0 * nz.rotation ** 2 * infl_r) if has_rot else None
    else:
        # new rows like the calibration rows: a row's error when it is held out of the fit is
        # (I - H_ii)^-1 times its residual, H_ii its block of the hat matrix, so its expected
        # square is sigma^2 tr (I - H_ii)^-1 - on few rows far above sigma^2 (1 + tr H_ii)
        t_p, t_r = _held_out_traces(problem.derived(loss="linear"), x, C)
        holdout_p = math.sqrt(nz.position ** 2 * infl_p * t_p)
        holdout_r = math.sqrt(nz.rotation ** 2 * infl_r * t_r) if has_rot else None
    predicted = {"position_rms": pos, "rotation_rms": rot if has_rot else None, "where": where}
    holdout = {"position_rms": holdout_p, "rotation_rms": holdout_r, "where": where}
    return Statistics(C, full_rank, rank, predicted, holdout, where)


def _held_out_traces(problem: Problem, x: np.ndarray, C: np.ndarray) -> tuple[float, float]:
    """Means over the rows of tr (I - H_ii)^-1 over the position and the rotation components
    (whitened units), H_ii = Jw_i C Jw_i^T the row's block of the hat matrix. A row whose
    leverage reaches 1 (it alone determines a parameter) counts as leverage 0.99."""
    t_p = t_r = 0.0
    n = 0
    for _, Jw, _ in problem.whitened_blocks(x, raw=True):
        H = Jw @ C @ np.transpose(Jw, (0, 2, 1))                     # (n, k, k)
        M = np.empty_like(H)                                         # (I - H)^-1
        # H is positive semi-definite: a leverage can reach 0.99 only where its trace does
        high = np.trace(H, axis1=1, axis2=2) >= 0.99
        M[~high] = np.linalg.inv(np.eye(H.shape[1]) - H[~high])
        if high.any():
            w, V = np.linalg.eigh(H[high])
            w = np.minimum(w, 0.99)
            M[high] = (V / (1.0 - w)[:, None, :]) @ np.transpose(V, (0, 2, 1))
        d = np.diagonal(M, axis1=1, axis2=2)
        t_p += float(d[:, :3].sum())
        t_r += float(d[:, 3:].sum())
        n += len(Jw)
    return t_p / max(n, 1), t_r / max(n, 1)


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
    fold_of = np.empty(n, int)
    fold_of[np.random.default_rng(seed).permutation(n)] = np.arange(n) % folds
    kept = problem.derived(loss="linear")   # the kept rows, least squares
    x0 = fit.model.values[fit.model.indices(fit.free)]
    e_p, e_r = np.zeros(n), np.zeros(n)
    has_rot = setup.measure == "pose"
    if refit == "newton":
        # J^T J and J^T r of each fold's rows (their sums are the fit's normal equations)
        m = len(x0)
        A_fold, g_fold = np.zeros((folds, m, m)), np.zeros((folds, m))
        start = 0
        for r, Jw, _ in kept.whitened_blocks(x0, raw=True):
            lab = fold_of[start:start + len(r)]
            start += len(r)
            for f in range(folds):
                Jf, rf = Jw[lab == f].reshape(-1, m), r[lab == f].reshape(-1)
                A_fold[f] += Jf.T @ Jf
                g_fold[f] += Jf.T @ rf
        A_all, g_all = A_fold.sum(axis=0), g_fold.sum(axis=0)
        # the folds' refits: A without each fold's rows, inverted at once
        A_inv, full = normal_inverse(A_all[None] - A_fold)
        bad = np.flatnonzero(~full)
        if len(bad) and fit.full_rank:
            # without this fold the rows cannot identify the parameters: its prediction would be
            # the whole fit's, which has seen it (a leak), not a held-out error
            f = int(bad[0])
            raise DataError(f"cross-validation: without fold {f + 1} of {folds} the remaining "
                            f"{n - int(np.sum(fold_of == f))} rows cannot identify the "
                            f"{len(x0)} parameters")
        dx = -np.einsum("fij,fj->fi", A_inv, g_all[None] - g_fold)       # (folds, m)
        # each row's whitened residual at its fold's refit, r + Jw dx, back in m and rad
        start = 0
        for r, Jw, _ in kept.whitened_blocks(x0, raw=True):
            lab = fold_of[start:start + len(r)]
            pred = r + np.einsum("nkm,nm->nk", Jw, dx[lab])
            e_p[start:start + len(r)] = np.sum(pred[:, :3] ** 2, axis=1) * kept.sigma_pos ** 2
            if has_rot:
                e_r[start:start + len(r)] = np.sum(pred[:, 3:] ** 2, axis=1) * kept.sigma_rot ** 2
            start += len(r)
    else:
        for f in range(folds):
            where = fold_of == f
            x_f = levenberg_marquardt(kept.derived(keep=~where), x0, "pose", options).x
            dp, dr = kept.derived(keep=where).pose_residuals(x_f)
            e_p[where] = np.sum(dp ** 2, axis=1)
            if dr is not None:
                e_r[where] = np.sum(dr ** 2, axis=1)
    per_fold = [(int(np.sum(fold_of == f)), math.sqrt(float(np.mean(e_p[fold_of == f]))),
                 math.sqrt(float(np.mean(e_r[fold_of == f]))) if has_rot else None) for f in range(folds)]
    score = e_p / problem.sigma_pos ** 2 + (e_r / problem.sigma_rot ** 2 if has_rot else 0.0)
    return CrossValidation(folds, math.sqrt(float(np.mean(e_p))),
                           math.sqrt(float(np.mean(e_r))) if has_rot else None, tuple(per_fold),
                           float(np.mean(score)), _standard_error(score), score)


def _standard_error(values: np.ndarray) -> float:
    return float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


def select_model(setup: Setup, candidates: Sequence[tuple[str, tuple[str, ...]]], full: Fit,
                 full_problem: Problem, solve: _Solve, folds: int, kin: ChainKinematics,
                 options: LMOptions) -> tuple[ModelSelection, dict[str, tuple[Fit, Problem]]]:
    """Cross-validate each candidate set at the noise levels and kept rows of ``full`` (the fit of
    the largest set) and choose by the one-standard-error rule. Returns the selection and the
    candidates' fits."""
    sp, sr = full_problem.sigma_pos, full_problem.sigma_rot
    fits, cands = {}, []
    for label, free in candidates:
        if tuple(free) == full.free:
            fit, problem = full, full_problem
        else:
            s = _solver_for(setup, free, solve.method, options, solve.max_rounds, solve.fixed_rounds,
                            solve.lm_variant)
            fit, problem = fit_stage(setup, free, s, sigma_pos=sp, sigma_rot=sr, outlier_k=None,
                                     keep=full.keep, kin=kin)
        fits[label] = (fit, problem)
        try:
            cands.append(Candidate(label, tuple(free), cross_validate(setup, fit, problem, folds, options=options)))
        except DataError:
            continue            # too few rows to hold any out for this set: not a candidate
    if not cands:
        raise DataError(f"{setup.cal.n_poses} calibration rows are too few to compare parameter sets by "
                        f"cross-validation (no candidate can be identified with a row held out): "
                        f"measure more rows, or name the parameter set (params / --params)")
    best = min(cands, key=lambda c: c.cv.score)
    # one standard error of the paired difference: the candidates are scored on the same rows and
    # folds, so their row scores are strongly correlated and the difference is what is uncertain
    chosen = next(c for c in cands
                  if np.mean(c.cv.row_scores - best.cv.row_scores) <= _standard_error(c.cv.row_scores - best.cv.row_scores))
    return ModelSelection(tuple(cands), chosen.label, best.label), fits


# ---------------------------------------------------------------- before, registered
def register_measurement_frame(robot: RobotModel, measurements: Measurements) -> RobotModel:
    """``robot`` with its measurement frame moved by the rigid transform that best fits its tool
    positions to the measured ones (least squares over the positions only; the convention of
    tracker software for "before calibration" errors)."""
    from scipy.spatial.transform import Rotation

    _, p_nom = ChainKinematics(robot).frame_poses(measurements.q, targets=target_rows(robot, measurements))
    c_nom, c_meas = p_nom.mean(axis=0), measurements.position.mean(axis=0)
    R, _ = Rotation.align_vectors(measurements.position - c_meas, p_nom - c_nom)
    T = np.eye(4)
    T[:3, :3] = R.as_matrix()
    T[:3, 3] = c_meas - T[:3, :3] @ c_nom
    return replace(robot, T_meas_base_ref=T @ robot.T_meas_base_ref)


# ====================================================================== calibrate
def calibrate(robot: RobotModel, measurements: Measurements, method: str = "search-lm",
              params: str | Sequence[str] | None = None, sigma_pos: float | None = None,
              sigma_rot: float | None = None, *, init_frames: bool | str = "auto",
              max_rounds: int = 20, fixed_rounds: int | None = None, options: LMOptions | None = None,
              validation: Measurements | None = None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0, cv: int | None = None, compliance: bool = False,
              payload=None, gravity: Sequence[float] | None = None,
              lm_variant: str = "calib") -> CalibrationResult:
    """Identify the TM-MDH parameters of ``robot`` from ``measurements``.

    Parameters
    ----------
    robot : the nominal model (e.g. from :func:`calib.load_robot`).
    measurements : measured tool poses; rows with set ``val`` are held out for validation.
    method : "search-lm" (default): a closed-form search of the angular parameters on the
        rotation data (:mod:`calib.solvers.angles`), then LM on all free parameters, searching again if
        LM stops above the noise level; it converges from far larger joint-offset and twist
        errors than the others (docs/reproduction.md: 100% of the paper's Table 8 grid).
        "c-lm": the paper's cross-identification scheme (Section 3.2.2: rounds of LM on the
        angular parameters with the rotation residuals, then LM on all free parameters) run with
        calib's LM (noise-weighted residuals, SO(3) log, damping mu diag(J^T J), rejected steps
        retried), not the paper's LM of Eq. (27)-(28); ``lm_variant="paper"`` runs it on that LM
        as printed (:mod:`calib.solvers.paper_lm`). On the paper's Table 8 study (docs/reproduction.md,
        21x21 grid) search-lm converges in 100% of the cases, calib's C-LM in 99.1% and LM in
        90.9%, the paper's C-LM and LM as printed in 92.3% and 15.65% (the paper reports 53.16%
        and 22.45%). "lm": calib's Levenberg-Marquardt alone. With position-only data all run as
        LM (a note says so). An explicit lm / c-lm fit that an angle search from its solution
        beats is reported with status "local_minimum".
    params : "base": the identifiable set, each redundant partner held at its nominal value;
        "auto": nested candidate sets (joint offsets and frames; + lengths; + twists; the
        identifiable set) compared by cross-validated held-out error, the smallest within one
        standard error of the best chosen; "paper": all but u_z, u_alpha, v_x, v_z, v_alpha,
        v_gamma (Section 4.2); "all": every parameter (LM takes minimum-norm steps: combinations the data do not
        determine at the start stay there while the data barely see them, parameters without
        effect keep their values); or
        parameter names. Default (None): "auto" when the calibration rows hold fewer than
        AUTO_BELOW_COMPONENTS_PER_PARAM residual components per identifiable parameter, else "base".
    sigma_pos : position noise per axis, metres; sigma_rot : orientation noise per axis, radians.
        None (default): estimated from the residuals (variance-component estimation iterated with
        the fit). Given values are honoured and the result's ``noise`` says how consistent the
        residuals are with them (chi-square test).
    init_frames : "auto" (closed-form estimate of the measurement and tool frames, used when the
        data put them more than 10 mm / 0.02 rad from the nominal ones), True (always), False.
    max_rounds : C-LM rounds at most; ``fixed_rounds`` runs exactly that many.
    validation : separate validation measurements; the statistics then use these, and the
        ``val`` rows of ``measurements`` are only held out.
    loss : "linear" (least squares), or a robust loss on each pose's whitened residual: "huber"
        or "soft_l1", with ``loss_scale`` in units of sigma.
    outlier_k : a calibration row whose whitened residual RMS per component exceeds ``outlier_k``
        is flagged against a robust fit, listed in ``outliers`` and the fit repeated without it;
        None disables the check.
    cv : folds of the cross-validation run when there are no validation rows (default
        CV_FOLDS = 5; 0 turns it off).
    compliance : also identify the joint compliances ``c<i>`` under gravity (rad/(N m), m/N
        prismatic; :mod:`calib.model.compliance`): the identifiable ones join the free set. payload :
        a :class:`calib.model.compliance.Payload` (kg, centre of mass in the tool frame) carried during
        the measurements; gravity : (3,) m/s^2 in the URDF root frame (default -9.80665 along z).
        A ``robot`` that already has compliances (:meth:`RobotModel.with_compliance`) keeps them
        fixed unless ``compliance`` is True.
    lm_variant : "calib" (default) or "paper": the LM of Eq. (27)-(28) as printed (mu I, mu reset
        to 0.001 lambda^+-1, unweighted residuals in mm and rad; :mod:`calib.solvers.paper_lm`), for
        methods "lm" and "c-lm" (not "search-lm").

    Returns a :class:`CalibrationResult`; a fit that did not converge is reported in its
    ``status``, never raised. Raises :class:`calib.CalibError` for unusable input.
    """
    t0 = time.perf_counter()
    method = _check_options(method, sigma_pos, sigma_rot, init_frames, max_rounds, fixed_rounds, loss,
                            loss_scale, outlier_k, cv)
    if lm_variant not in LM_VARIANTS:
        raise ParameterError(f"unknown lm_variant {lm_variant!r}: expected one of {', '.join(LM_VARIANTS)}")
    if lm_variant == "paper" and method == "search-lm":
        raise ParameterError("lm_variant 'paper' is the paper's LM for methods 'lm' and 'c-lm'; "
                             "search-lm runs calib's LM")
    if lm_variant == "paper" and loss != "linear":
        raise ParameterError("lm_variant 'paper' fits unweighted least squares: loss must be 'linear'")
    if options is not None and not isinstance(options, LMOptions):
        raise ParameterError(f"options must be an LMOptions, got {type(options).__name__}")
    if not isinstance(robot, RobotModel):
        raise ParameterError(f"robot must be a RobotModel (calib.load_robot), got {type(robot).__name__}")
    if not isinstance(measurements, Measurements):
        raise ParameterError(f"measurements must be a Measurements (calib.read_measurements), got "
                             f"{type(measurements).__name__}")
    if validation is not None and not isinstance(validation, Measurements):
        raise ParameterError(f"validation must be a Measurements, got {type(validation).__name__}")
    opts = options or LMOptions()
    if not isinstance(compliance, bool):
        raise ParameterError(f"compliance must be True or False, got {compliance!r}")
    pre_notes: list[str] = []
    if compliance or payload is not None or gravity is not None:
        from calib.model.compliance import with_gravity

        if not (compliance or robot.has_compliance):
            raise ParameterError("a payload or gravity only matters for joint compliance: pass compliance=True")
        robot = with_gravity(robot, payload=payload if payload is not None else
                             (robot.gravity.payload if robot.has_compliance else None),
                             gravity=gravity if gravity is not None else
                             (robot.gravity.gravity if robot.has_compliance else None))
        if robot.gravity.note:
            pre_notes.append(robot.gravity.note)
    setup, notes = prepare(robot, measurements, validation, init_frames)
    notes = pre_notes + notes
    robot = setup.nominal       # with the measured targets
    start, cal, val = setup.start, setup.cal, setup.val
    if setup.measure == "position" and method != "lm":
        notes.append(f"position-only data: {method.upper()} needs orientations for its angle step; ran LM")
    elif method == "search-lm" and start.targets:
        notes.append("several targets: the angle search of SEARCH-LM takes one tool frame; ran LM")
    log.info("prepare: %d calibration rows, %d validation rows, %s data%s", cal.n_poses,
             0 if val is None else val.n_poses, setup.measure,
             "".join(f"; {r} frame estimated" for r in setup.rebased))

    # parameter set (after the frame estimate: where the tool point lies decides what
    # positions can identify)
    weights = (sigma_pos or SIGMA_POS_M, sigma_rot or SIGMA_ROT_RAD)
    want = params
    ident = None
    if params is None or (isinstance(params, str) and params.strip().lower() == "auto"):
        ident = _compliance_filter(start, identifiable_set(start, cal.q, setup.measure, *weights,
                                                          target_rows(start, cal)), compliance, notes)
        per_param = cal.n_poses * setup.components_per_pose / max(len(ident), 1)
        if params is None:
            few = per_param < AUTO_BELOW_COMPONENTS_PER_PARAM
            no_cv = cv is not None and cv < 2
            want = "auto" if (few and not no_cv) else "base"
            notes.append(f"parameter set {want!r} chosen by default: {cal.n_poses * setup.components_per_pose} "
                         f"residual components for {len(ident)} identifiable parameters "
                         f"({per_param:.1f} per parameter; 'auto' below {AUTO_BELOW_COMPONENTS_PER_PARAM:g}"
                         + (", but it compares the sets by cross-validation, which cv=0 turns off)"
                            if few and no_cv else ")"))
        else:
            want = "auto"
    if want == "base" and ident is not None:
        label, free = "base", ident     # (the identifiable set just found)
    elif want != "auto":
        label, free = select_parameters(start, want, cal.q, setup.measure, *weights, target_rows(start, cal))
    derived = want == "auto" or (isinstance(want, str) and want.strip().lower() == "base")
    check_data_rank(start, cal, setup.measure, ident if want == "auto" else free, derived=derived,
                    sigma_pos=weights[0], sigma_rot=weights[1])
    n_free = len(ident if want == "auto" else free)
    spare = cal.n_poses * setup.components_per_pose - n_free
    rank_note = ""
    deficit = 0         # (an identifiable set: full rank at the nominal model on these rows)
    if not derived:
        # a set given by name ("all", a list) may be rank deficient: the fit spends its rank only
        # (the greedy selection with the set first keeps a maximal independent part of it), and
        # LM holds the rest (Problem.set_rank_deficit)
        deficit = _set_rank_deficit(setup, free, weights)
        rank = n_free - deficit
        spare += deficit
        rank_note = f" (of rank {rank})" if rank < n_free else ""
    if (sigma_pos is None or sigma_rot is None) and spare < MIN_REDUNDANCY:
        where = f"{measurements.source}: " if measurements.source is not None else ""
        raise DataError(f"{where}{cal.n_poses} calibration rows give {cal.n_poses * setup.components_per_pose} "
                        f"residual components for {n_free} parameters{rank_note}: at least {MIN_REDUNDANCY} more are "
                        f"needed to estimate the noise (a fit with none to spare passes through every "
                        f"row and says nothing of its accuracy); measure more rows, or give the noise "
                        f"levels (sigma_pos / sigma_rot, --sigma-pos-mm / --sigma-rot-rad)")
    folds = CV_FOLDS if cv is None else cv
    kin = setup.kin or ChainKinematics(start)
    # the errors before calibration first: the fit's kinematics start at the nominal values when
    # the frames were not moved
    nominal_kin = kin if start is robot else ChainKinematics(robot)
    cal_rows = target_rows(robot, cal)
    before = pose_errors(robot, cal.q, cal.position, cal.rotation, nominal_kin, cal_rows)
    vb = val_rows = None
    if val is not None:
        val_rows = target_rows(robot, val)
        vb = pose_errors(robot, val.q, val.position, val.rotation, nominal_kin, val_rows)
    selection = None
    if want == "auto":
        if folds < 2:
            raise ParameterError("params 'auto' compares candidate sets by cross-validation: cv must be >= 2")
        label = "auto"
        full_solve = _solver_for(setup, ident, method, opts, max_rounds, fixed_rounds, lm_variant)
        full, full_problem = fit_stage(setup, ident, full_solve, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                                       loss=loss, loss_scale=loss_scale, outlier_k=outlier_k, kin=kin)
        # leave-one-out on small sets: far less noisy than K folds at a few ms per refit
        sel_folds = int(full.keep.sum()) if full.keep.sum() <= LOO_BELOW_ROWS else folds
        selection, fits = select_model(setup, candidate_sets(start, ident), full, full_problem, full_solve,
                                       sel_folds, kin, opts)
        free = next(c.free for c in selection.candidates if c.label == selection.chosen)
        label = f"auto: {selection.chosen}"
        solve = _solver_for(setup, free, method, opts, max_rounds, fixed_rounds, lm_variant)
        if free == full.free:
            fit, problem = full, full_problem
        else:
            fit, problem = fit_stage(setup, free, solve, sigma_pos=sigma_pos, sigma_rot=sigma_rot, loss=loss,
                                     loss_scale=loss_scale, outlier_k=None, keep=full.keep, kin=kin)
            fit = replace(fit, outliers=full.outliers, notes=full.notes + fit.notes)
        log.info("model selection: %s", selection.chosen)
    else:
        if label in PARAM_SETS:     # a named set; a list of names is honoured as given
            filtered = _compliance_filter(start, free, compliance, notes)
            if not derived and filtered != tuple(free):
                deficit = _set_rank_deficit(setup, filtered, weights)
            free = filtered
        solve = _solver_for(setup, free, method, opts, max_rounds, fixed_rounds, lm_variant)
        fit, problem = fit_stage(setup, free, solve, sigma_pos=sigma_pos, sigma_rot=sigma_rot, loss=loss,
                                 loss_scale=loss_scale, outlier_k=outlier_k, kin=kin, rank_deficit=deficit)
    notes += fit.notes
    nz = fit.noise
    if not nz.estimated and fit.solver.status == "converged" and nz.reduced_chi2 > CHI2_ESCAPE:
        notes.append(f"the fit converged but its residuals are {math.sqrt(nz.reduced_chi2):.1f} times the given "
                     f"noise (reduced chi^2 {nz.reduced_chi2:.3g}): a wrong sigma, or errors the model "
                     f"does not describe; omit the noise levels to estimate them from the data")
    notes += _implausible_fit_notes(robot, fit.errors) + _implausible_length_notes(robot, fit.model)

    stats = statistics_stage(setup, fit, problem)
    log.info("statistics: rank %d, predicted held-out RMS %.4g mm", stats.rank,
             stats.predicted_holdout["position_rms"] * 1e3)
    if not stats.full_rank:
        notes.append("the free parameters are not all identifiable (rank-deficient set): standard "
                     "deviations come from the pseudo-inverse and describe only the identifiable "
                     "combinations")
    cross = None
    if val is None and folds >= 2:
        if selection is not None:
            cross = next(c.cv for c in selection.candidates if c.label == selection.chosen)
        elif fit.keep.sum() >= folds:
            try:
                cross = cross_validate(setup, fit, problem, folds, options=opts)
            except DataError as exc:
                notes.append(f"no cross-validation: {exc}")
        else:
            notes.append(f"no cross-validation: fewer rows than the {folds} folds")

    calibrated = fit.model
    after = fit.errors
    va = None
    if val is not None:
        va = pose_errors(calibrated, val.q, val.position, val.rotation, kin, val_rows)
    breg = vbreg = None
    if setup.rebased:
        # the nominal geometry, with the tool or targets where the closed-form estimate put them
        # when it moved them (an SMR's unknown offset is not an error of the robot), and the
        # measurement frame registered by a best fit
        ref = robot if setup.rebased == ("measurement->base",) else replace(
            robot, T_flange_tool_ref=start.T_flange_tool_ref, T_flange_target_refs=start.T_flange_target_refs)
        registered = register_measurement_frame(ref, cal)
        breg = pose_errors(registered, cal.q, cal.position, cal.rotation, targets=cal_rows)
        if val is not None:
            vbreg = pose_errors(registered, val.q, val.position, val.rotation, targets=val_rows)
    per_target = tuple(
        TargetAccuracy(t, before.subset(cal_rows == k), after.subset(cal_rows == k),
                       None if val is None else vb.subset(val_rows == k),
                       None if val is None else va.subset(val_rows == k))
        for k, t in enumerate(robot.targets))

    table = _parameter_table(robot, calibrated, fit.free, stats.covariance)
    return CalibrationResult(
        robot=calibrated, nominal=robot, method=method, param_set=label, parameters=table, free=fit.free,
        status=fit.solver.status, message=fit.solver.message, iterations=fit.iterations,
        rounds=fit.solver.rounds, wall_time=time.perf_counter() - t0, cost=float(fit.solver.cost),
        reduced_chi2=nz.reduced_chi2, covariance=stats.covariance, before=before, after=after,
        validation_before=vb, validation_after=va, predicted=stats.predicted, sigma_pos=nz.position,
        sigma_rot=nz.rotation if nz.rotation is not None else weights[1], notes=tuple(notes),
        outliers=fit.outliers, loss=loss, noise=nz, predicted_holdout=stats.predicted_holdout,
        cross_validation=cross, selection=selection, before_registered=breg,
        validation_before_registered=vbreg, targets=per_target,
        after_without_outliers=after.subset(fit.keep) if fit.outliers else None,
        estimated_frames=setup.rebased)


def _implausible_fit_notes(robot: RobotModel, after: AccuracyStats) -> list[str]:
    """A note when the calibrated model leaves errors on its calibration rows that no robot and
    instrument give (:data:`IMPLAUSIBLE_REACH_FRACTION` of the reach, :data:`IMPLAUSIBLE_ROT_RAD`):
    the fit ran, but on data that do not belong to this robot as read."""
    reach = _robot_memo("reach", robot, (), lambda: _reach(robot))
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
        check.append("the orientation columns (quaternion order w, x, y, z; --euler sequence; angle "
                     "units) and the tool frame")
    if not what:
        return []
    return [f"the calibrated model does not describe these measurements: on the calibration rows it "
            f"leaves {' and '.join(what)}; check {', and '.join(check)}"]


def _implausible_length_notes(nominal: RobotModel, calibrated: RobotModel) -> list[str]:
    """A note naming the link lengths (d, a of the joints) identified further than
    :data:`IMPLAUSIBLE_LENGTH_FRACTION` of the reach from their nominal values: no robot is built
    that far from its drawing (positions in metres named _mm shrink a UR5's 425 mm link to
    0.6 mm and the fit converges at the noise; the URDF of another robot model)."""
    reach = _robot_memo("reach", nominal, (), lambda: _reach(nominal))
    far = [(p.name, b - a) for p, a, b in zip(nominal.parameters, nominal.values, calibrated.values)
           if p.group == "joint" and p.unit == "m" and abs(b - a) > IMPLAUSIBLE_LENGTH_FRACTION * reach
           and not (p.kind == "d" and nominal.prismatic[p.joint - 1])]   # (a slide's offset: any)
    if not far:
        return []
    shown = ", ".join(f"{name} {dev * 1e3:+.1f} mm" for name, dev in far)
    return [f"identified link lengths far from the URDF's: {shown} (more than "
            f"{100 * IMPLAUSIBLE_LENGTH_FRACTION:g} % of the robot's reach {reach * 1e3:.0f} mm); check the "
            f"length unit of the positions (metres named _mm?) and that the URDF is this robot's"]


def _compliance_filter(robot: RobotModel, free: Sequence[str], compliance: bool,
                       notes: list) -> tuple[str, ...]:
    """``free`` without the compliance parameters unless ``compliance``; with it, a note naming
    the compliances not in ``free`` (the identifiable set leaves out those the data cannot see)."""
    comp = set(robot.compliance_names)
    if not comp:
        return tuple(free)
    if not compliance:
        return tuple(n for n in free if n not in comp)
    unseen = [n for n in robot.compliance_names if n not in free]
    note = (f"compliance not identifiable from these poses (no gravity torque, or tied to "
            f"the geometry), held at its value: {', '.join(unseen)}")
    if unseen and note not in notes:
        notes.append(note)
    return tuple(free)


def _parameter_table(nominal: RobotModel, calibrated: RobotModel, free, cov) -> tuple[ParameterEstimate, ...]:
    std = dict(zip(free, np.sqrt(np.maximum(np.diag(cov), 0.0))))
    frame_vals = {("u", None): (zyx_parameters(nominal.T_meas_base()), zyx_parameters(calibrated.T_meas_base()))}
    for t in nominal.targets or (None,):
        frame_vals["v", t] = (zyx_parameters(nominal.T_flange_tool(t)), zyx_parameters(calibrated.T_flange_tool(t)))
    kinds = ("x", "y", "z", "alpha", "beta", "gamma")
    rows = []
    for k, p in enumerate(nominal.parameters):
        if p.group in ("u", "v"):
            i = kinds.index(p.kind)
            nom, ide = frame_vals[p.group, p.target][0][i], frame_vals[p.group, p.target][1][i]
        else:
            nom, ide = nominal.values[k], calibrated.values[k]
        rows.append(ParameterEstimate(p.name, p.unit, float(nom), float(ide), p.name in std,
                                      float(std.get(p.name, math.nan))))
    return tuple(rows)
