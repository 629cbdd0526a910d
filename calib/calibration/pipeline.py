"""The calibration API: identify a robot's TM-MDH parameters from measured tool poses.

``calibrate(robot, measurements)`` runs public stages, each taking and returning small frozen
values, so that a script or a test can call them one after the other:

0. **options** (:func:`calib.calibration.options.resolve_options`): every option checked once,
   one frozen :class:`~calib.calibration.options.CalibrationOptions`.
1. **prepare** (:func:`calib.calibration.prepare.prepare` -> :class:`~calib.calibration.prepare.Setup`):
   the calibration and validation rows, what is measured (pose or position), and a closed-form
   estimate of the measurement and tool frames (:mod:`calib.calibration.frames`) when the data
   put them far from the nominal ones (more than ``FRAME_REBASE_M`` or ``FRAME_REBASE_RAD``): the
   model's constant reference transforms move to the estimates, u and v keep their nominal values
   relative to them.
2. **parameter set** (:func:`calib.calibration.parameters.choose_parameters`): the identifiable set
   of :mod:`calib.model.identifiability` (``"base"``), the paper's set, all, a list of names,
   ``"auto"`` (nested candidate sets compared by cross-validated held-out error) or ``"map"``.
3. **fit**: one estimator (:mod:`calib.calibration.estimators`), chosen once by
   :func:`calib.calibration.estimators.resolve.resolve_estimator`, returns an
   :class:`~calib.calibration.estimators.base.Estimate` whatever it is: least squares
   (:class:`~calib.calibration.estimators.least_squares.LeastSquares`: search-lm, C-LM or LM,
   noise-weighted, the noise levels estimated by variance components unless given, outlier rows
   flagged against a robust fit and the fit repeated without them), EB-MAP
   (:class:`~calib.calibration.estimators.regularised.EBMap`) or model selection over nested
   candidate sets wrapping least squares
   (:class:`~calib.calibration.estimators.selection.SelectBest`). Then the :func:`verdict`.
4. **statistics** (:func:`calib.calibration.accuracy.statistics.statistics_stage`): parameter covariance,
   the predicted accuracy of the calibrated model against the true poses (``predicted_rms``, the
   Cramer-Rao figure) and against new measured rows (``predicted_holdout_rms``: parameter
   uncertainty inflated by the measured misfit, plus the measurement noise), chi-square
   consistency of given noise levels.
5. **cross-validation** (:func:`calib.calibration.accuracy.validation.held_out_error`): K-fold held-out
   error when no validation rows are given.
6. **accuracy** before and after (:func:`calib.calibration.accuracy.errors.accuracy_before`,
   :func:`~calib.calibration.accuracy.errors.accuracy_after`) on the calibration and validation rows, raw
   and (for a measurement frame far from the base) after a best-fit registration of the
   measurement frame only; then the :class:`~calib.calibration.result.CalibrationResult`.

Touch data (:class:`calib.model.touch.TouchData`: rows naming the point, plane or sphere the tool
touched, and rows measured by an instrument in the same data) take the same stages: prepare
builds the setup's residual blocks (:mod:`calib.solvers.residuals`), the parameter choice is their
identifiability, the estimator fits the robot and the features' unknowns together
(:class:`calib.solvers.blocks.BlockProblem`: one noise level per residual group, the one outlier
check), the statistics predict the tool error after a best-fit registration and judge the design
against the nominal model, cross-validation deals its folds within each feature, and the result
carries the features (``docs/touch.md``).
"""
from __future__ import annotations

import logging
import time
from typing import Sequence

import numpy as np

from calib.calibration.accuracy.errors import AccuracyStats, BeforeAfter, accuracy_after, accuracy_before, target_rows
from calib.calibration.accuracy.validation import consistency_notes
from calib.calibration.diagnose import misreadings
from calib.calibration.estimators.base import Estimate
from calib.calibration.estimators.least_squares import method_notes
from calib.calibration.estimators.readable import parameter_notes, tied_length_notes
from calib.calibration.estimators.resolve import resolve_estimator
from calib.calibration.options import CalibrationOptions, resolve_options
from calib.calibration.parameters import choose_parameters
from calib.calibration.plausibility import (compliance_refusal, implausibility, length_notes,
                                            validation_implausibility)
from calib.calibration.prepare import Setup, prepare, with_gravity_for
from calib.calibration.result import CalibrationResult, parameter_table
from calib.calibration.accuracy.statistics import Statistics, group_fits, statistics_notes, statistics_stage
from calib.calibration.terms import compliance_notes, payload_note, resolve_terms
from calib.calibration.accuracy.validation import held_out_error
from calib.errors import ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.solvers.lm import LMOptions
from calib.threads import api_call

log = logging.getLogger(__name__)

#: calibrate's stages in order and their rough shares of its time, for the fraction a
#: ``progress`` function is given (the 1,402 real iiwa rows, the joint terms judged: 52 % terms,
#: 40 % the fit, the rest 8 %); a stage that does not run (the joint terms not judged) gives its
#: share to the others.
STAGE_SHARES = (("joint terms", 0.45), ("prepare", 0.05), ("fit", 0.40), ("statistics", 0.05),
                ("cross-validation", 0.05))


class _Stages:
    """Calls ``progress(fraction_done, stage)`` at the start of each stage of STAGE_SHARES."""

    def __init__(self, progress):
        if progress is not None:
            _check_progress(progress)
        self.progress, self.skipped = progress, set()

    def skip(self, name: str) -> None:
        self.skipped.add(name)

    def start(self, name: str) -> None:
        if self.progress is None:
            return
        shares = [(n, w) for n, w in STAGE_SHARES if n not in self.skipped]
        names = [n for n, _ in shares]
        if name not in names:           # ("done")
            self.progress(1.0, name)
            return
        self.progress(sum(w for _, w in shares[:names.index(name)]) / sum(w for _, w in shares), name)


def _check_progress(progress) -> None:
    """Refuse a ``progress`` that is not a function taking (fraction, stage)."""
    import inspect

    try:
        ok = callable(progress)
        if ok:
            inspect.signature(progress).bind(0.0, "prepare")
    except TypeError:
        ok = False
    except ValueError:          # (a builtin without a signature: let it be)
        pass
    if not ok:
        raise ParameterError(f"progress must be None or a function progress(fraction, stage), got {progress!r:.60}")


# ====================================================================== calibrate
@api_call
def calibrate(robot: RobotModel, measurements: Measurements, method: str = "search-lm",
              params: str | Sequence[str] | None = None, sigma_pos: float | None = None,
              sigma_rot: float | None = None, *, init_frames: bool | str = "auto",
              max_rounds: int = 20, fixed_rounds: int | None = None, options: LMOptions | None = None,
              validation: Measurements | None = None, loss: str = "linear", loss_scale: float = 3.0,
              outlier_k: float | None = 5.0, cv: int | None = None, compliance: bool = False,
              payload=None, gravity: Sequence[float] | None = None,
              lm_variant: str = "calib", estimator: str = "auto", periodic: bool = False,
              terms: str | None = "auto", progress=None, sigma_touch: float | None = None,
              nominal_scale: bool = False) -> CalibrationResult:
    """Identify the TM-MDH parameters of ``robot`` (the nominal :class:`RobotModel`) from
    ``measurements`` (measured tool poses or positions, SI units; rows with ``val`` set are held
    out; or :class:`~calib.model.touch.TouchData`, rows naming the point, plane or sphere the tool
    touched, mixed with rows measured by an instrument: ``docs/touch.md``), by the stages of this
    module. Every parameter is described in ``docs/calibrate.md``: method ("search-lm", "c-lm",
    "lm"), params ("base", "auto", "paper", "all" or names; touch data "auto" or "tool"),
    sigma_pos (m) / sigma_rot (rad) / sigma_touch (m) (None: estimated), init_frames, max_rounds,
    fixed_rounds, options (LM), validation, loss and loss_scale, outlier_k, cv (folds),
    compliance, payload, gravity (m/s^2), lm_variant, estimator ("auto", "ls", "map"), periodic,
    terms, progress (a function of (fraction, stage)), nominal_scale (touch data without a length).

    Returns a :class:`CalibrationResult` (a fit that did not converge is in its ``status``,
    never raised). Raises :class:`calib.CalibError` for unusable input.
    """
    t0, stages = time.perf_counter(), _Stages(progress)
    opts = resolve_options(robot, measurements, validation, method=method, params=params, sigma_pos=sigma_pos,
                           sigma_rot=sigma_rot, init_frames=init_frames, max_rounds=max_rounds,
                           fixed_rounds=fixed_rounds, options=options, loss=loss, loss_scale=loss_scale,
                           outlier_k=outlier_k, cv=cv, compliance=compliance, lm_variant=lm_variant,
                           estimator=estimator, periodic=periodic, sigma_touch=sigma_touch, nominal_scale=nominal_scale)
    stages.start("joint terms")
    opts, notes, terms_fit = resolve_terms(robot, measurements, opts, terms, payload, gravity)
    if terms_fit is None:                       # (the joint terms were not judged)
        stages.skip("joint terms")
    stages.start("prepare")
    setup, prepare_notes = prepare_stage(robot, measurements, validation, opts, payload, gravity)
    choice = choose_parameters(setup, opts, source=measurements.source)
    notes += prepare_notes + list(choice.notes)
    if setup.touch is None and choice.label in ("base", "auto"):    # (which link lengths a frame offset took the tie of)
        notes += tied_length_notes(setup.start, setup.cal.q, setup.measure, opts.weights,
                                   target_rows(setup.start, setup.cal), choice.free)
    kin = setup.kin or ChainKinematics(setup.start)
    accuracy = before_stage(setup, kin)
    stages.start("fit")
    est = resolve_estimator(setup, choice, opts, terms_fit, measurements.source).fit(setup, choice, opts, kin)
    status, message, fit_notes = verdict(setup, est, opts)
    stages.start("statistics")
    stats = statistics_stage(setup, est.fit, est.problem)
    if stats.refusals:      # (touch data: a design that leaves the model worse than the nominal one)
        status, message = ("implausible", stats.refusals[0]) if status == "converged" else (status, message)
        fit_notes = list(stats.refusals) + fit_notes
    log.info("statistics: rank %d, predicted held-out RMS %.4g mm", stats.rank,
             (stats.predicted_holdout or stats.predicted)["position_rms"] * 1e3)
    # physics that contradicts itself (a joint turning against its load) is refused
    physics = [] if setup.touch is not None else compliance_refusal(est.fit.model, est.fit.free, stats.covariance,
                                                                     est.problem.Q)
    notes += fit_notes + statistics_notes(stats) + physics \
        + compliance_notes(est.fit.model, est.fit.free, stats.covariance, refused=bool(physics)) \
        + payload_note(est.fit.model, est.problem)
    stages.start("cross-validation")
    cross, cv_notes = held_out_error(setup, est.fit, est.problem, est.selection, opts.folds, opts.lm)
    errors = est.fit.errors             # (made from the kept residuals: once for both uses below)
    accuracy = accuracy_after(accuracy, est.fit.model, errors, setup.val, setup.nominal.targets, kin)
    # validation figures that cannot be right (positions in another unit) are refused
    units = validation_implausibility(est.fit.model, setup.val, accuracy.val_rows, errors.subset(est.fit.keep),
                                      accuracy.validation_after)
    refusal = next(iter(physics + units), None)
    if refusal is not None and status == "converged":
        status, message = "implausible", refusal
    stages.start("done")
    return make_result(setup, est, stats, opts, accuracy=accuracy, errors=errors, cross=cross,
                       status=(status, message), notes=notes + cv_notes + units, wall_time=time.perf_counter() - t0)


def prepare_stage(robot: RobotModel, measurements: Measurements, validation: Measurements | None,
                  opts: CalibrationOptions, payload=None, gravity=None) -> tuple[Setup, list[str]]:
    """The prepare stage of ``calibrate`` (:func:`calib.calibration.prepare.prepare`) on the robot
    with the gravity load its compliance sees and the periodic terms asked for, and its notes
    (the gravity's, the frames', the method's)."""
    robot, notes = with_gravity_for(robot, opts.compliance, payload, gravity)
    robot = robot.with_periodic() if opts.periodic else robot
    setup, prepare_notes = prepare(robot, measurements, validation, opts.init_frames)
    log.info("prepare: %d calibration rows, %d validation rows, %s data%s", len(setup.rows),
             0 if setup.val is None else setup.val.n_poses, setup.measure,
             "".join(f"; {r} frame estimated" for r in setup.rebased))
    return setup, notes + prepare_notes + method_notes(setup, opts.method)


def before_stage(setup: Setup, kin: ChainKinematics) -> BeforeAfter:
    """The errors before calibration (:func:`calib.calibration.accuracy.errors.accuracy_before`; its
    kinematics those of the fit, which start at the nominal values when the frames were not
    moved); touch data: every row's error (a touch row's distance to its feature) at the start
    (the meas frame at the measured rows' registration, the features fitted to the nominal
    model's tool points)."""
    if setup.touch is not None:
        problem = setup.block_problem(ChainKinematics(setup.start), np.zeros(0, int),
                                      (SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M))
        return BeforeAfter(AccuracyStats.from_residuals(*problem.pose_residuals(setup.features.values)))
    return accuracy_before(setup.nominal, setup.start, setup.cal, setup.val, rebased=setup.rebased,
                           kin=kin if setup.start is setup.nominal else ChainKinematics(setup.nominal))


def verdict(setup: Setup, est: Estimate, opts: CalibrationOptions) -> tuple[str, str, list[str]]:
    """The status and message of a fit (its solver's, or "implausible" with the first reason when
    the fit converged to a result that cannot be trusted, or the data look misread) and the
    fit's notes."""
    fit = est.fit
    implausible = implausibility(setup.nominal, fit, sigma_pos_given=opts.sigma_pos is not None,
                                 sigma_rot_given=opts.sigma_rot is not None,
                                 sigma_touch_given=opts.sigma_touch is not None)
    causes = misreadings(setup, fit, opts, implausible=bool(implausible) or fit.solver.status != "converged")
    implausible = causes + implausible
    far = length_notes(setup.nominal, fit.model)
    # (the parameters a user reads as the robot's: moved far, or a prior group not calibrated)
    notes = list(fit.notes) + implausible + (far or parameter_notes(setup.nominal, fit, est.record))
    status, message = fit.solver.status, fit.solver.message
    # (a fit stopped at its iteration limit whose result the checks find implausible is refused
    # as a converged one is: nothing worth writing for inspection; 8 rows of rotation vectors read
    # as angles: 1.13 rad of orientation error left, the outputs written)
    if implausible and (status in ("converged", "max_iterations") or causes):
        status, message = "implausible", implausible[0]
    return status, message, notes


def make_result(setup: Setup, est: Estimate, stats: Statistics, opts: CalibrationOptions, *, accuracy, errors,
                cross, status: tuple[str, str], notes: list[str], wall_time: float) -> CalibrationResult:
    """The :class:`CalibrationResult` of the stages' values. A measurement frame estimated from
    the data is the instrument's: the robot's base frame in it is reported apart
    (:mod:`calib.calibration.base_frame`), the URDF stays rooted at the robot."""
    fit, nominal, nz = est.fit, setup.nominal, est.fit.noise
    mframe, in_base = None, fit.model
    if "measurement->base" in setup.rebased:
        from calib.calibration.base_frame import in_base_frame, robot_base_frame

        mframe = robot_base_frame(fit.model, nominal, covariance=stats.covariance, free=fit.free,
                                  position_only=not setup.cal.has_orientation)
        in_base = in_base_frame(fit.model, mframe)
    return CalibrationResult(
        robot=fit.model, nominal=nominal, method=opts.method, param_set=est.label,
        parameters=parameter_table(nominal, in_base, fit.free, stats.covariance), free=fit.free,
        status=status[0], message=status[1], iterations=fit.iterations,
        rounds=fit.solver.rounds, wall_time=wall_time, cost=float(fit.solver.cost),
        reduced_chi2=nz.reduced_chi2, covariance=stats.covariance, before=accuracy.before, after=accuracy.after,
        validation_before=accuracy.validation_before, validation_after=accuracy.validation_after,
        predicted=stats.predicted, sigma_pos=nz.position,
        sigma_rot=nz.rotation if nz.rotation is not None else opts.weights[1],
        notes=tuple(consistency_notes(stats.consistency) + notes),
        outliers=fit.outliers, loss=opts.loss, noise=nz, predicted_holdout=stats.predicted_holdout,
        cross_validation=cross, selection=est.selection, before_registered=accuracy.before_registered,
        validation_before_registered=accuracy.validation_before_registered, targets=accuracy.targets,
        after_without_outliers=errors.subset(fit.keep) if fit.outliers else None,
        estimated_frames=estimated_frames(setup, fit), predicted_workspace=stats.predicted_workspace,
        consistency=stats.consistency, estimator=est.record, measurement_frame=mframe,
        nominal_registered=accuracy.registered,
        **({} if setup.touch is None else touch_fields(setup, est, opts, cross)))


def estimated_frames(setup: Setup, fit) -> tuple[str, ...]:
    """The frames the calibration estimated from the data: those the closed-form estimate moved
    (:class:`~calib.calibration.prepare.Setup`'s ``rebased``); of touch data, also the tool when its
    offset was fitted (the tool point the rows touched with)."""
    if setup.touch is None:
        return setup.rebased
    return setup.rebased + (("flange->tool",) if any(n.startswith("v_") for n in fit.free) else ())


def touch_fields(setup: Setup, est: Estimate, opts: CalibrationOptions, cross) -> dict:
    """The fields of a :class:`CalibrationResult` of touch data: the features' unknowns
    (:class:`~calib.model.touch.FeatureFit`), each residual group's figures
    (:func:`calib.calibration.accuracy.statistics.group_fits`), the parameter choice's identifiability."""
    from calib.model.touch import FeatureFit
    from calib.solvers.residuals.touch import TouchRows

    fit, problem = est.fit, est.problem
    m = len(fit.free)
    std = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))
    features = FeatureFit(setup.touch.features, fit.solver.x[m:].copy(), std[m:], setup.features.plane_refs)
    x0 = np.concatenate([setup.start.values[setup.start.indices(fit.free)], setup.features.values])
    n_touch = problem.blocks[problem.block_of(TouchRows)].n_rows
    rows = {"touch": n_touch, "position": problem.n_poses - n_touch, "rotation": problem.n_poses - n_touch}
    groups = group_fits(problem, fit, x0, (opts.sigma_pos, opts.sigma_rot, opts.sigma_touch), rows,
                        None if cross is None else cross.groups)
    choice = est.choice
    return {"features": features, "groups": groups, "nominal_scale": bool(opts.nominal_scale),
            "identifiability": None if choice is None else choice.identifiability}
