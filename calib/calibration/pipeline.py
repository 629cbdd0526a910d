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
   of :mod:`calib.model.identifiability` (``"base"``), the paper's set, all, a list of names, or
   ``"auto"``: nested candidate sets compared by cross-validated held-out error
   (:func:`calib.calibration.selection.select_and_fit`, :func:`~calib.calibration.selection.select_model`
   with its selection rule passed in).
3. **fit** (:func:`calib.calibration.fit.fit_stage` -> :class:`~calib.calibration.fit.Fit`):
   identification by search-lm, C-LM or LM (:func:`calib.solvers.dispatch.solve`), noise-weighted.
   Unless the noise levels are given, they are estimated from the residuals by variance-component
   estimation iterated with the fit (:class:`~calib.calibration.fit.NoiseEstimate`). Outlier rows
   are flagged against a robust fit and the fit repeated without them.
4. **statistics** (:func:`calib.calibration.statistics.statistics_stage`): parameter covariance,
   the predicted accuracy of the calibrated model against the true poses (``predicted_rms``, the
   Cramer-Rao figure) and against new measured rows (``predicted_holdout_rms``: parameter
   uncertainty inflated by the measured misfit, plus the measurement noise), chi-square
   consistency of given noise levels.
5. **cross-validation** (:func:`calib.calibration.validation.held_out_error`): K-fold held-out
   error when no validation rows are given.
6. **accuracy** before and after (:func:`calib.calibration.accuracy.accuracy_before`,
   :func:`~calib.calibration.accuracy.accuracy_after`) on the calibration and validation rows, raw
   and (for a measurement frame far from the base) after a best-fit registration of the
   measurement frame only; then the :class:`~calib.calibration.result.CalibrationResult`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Sequence

import numpy as np

from calib.calibration.accuracy import accuracy_after, accuracy_before
from calib.calibration.consistency import consistency_notes
from calib.calibration.diagnose import misreadings
from calib.calibration.fit import fit_with, method_notes
from calib.calibration.options import resolve_options
from calib.calibration.parameters import choose_parameters
from calib.calibration.plausibility import (compliance_refusal, implausibility, length_notes,
                                            validation_implausibility)
from calib.calibration.prepare import prepare, with_gravity_for
from calib.calibration.result import CalibrationResult, _parameter_table
from calib.calibration.statistics import statistics_notes, statistics_stage
from calib.calibration.terms import compliance_notes, payload_note, resolve_terms, warm_start
from calib.calibration.validation import held_out_error
from calib.errors import ParameterError
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
              terms: str | None = "auto", progress=None) -> CalibrationResult:
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
        identifiable set; each its own maximal identifiable subset) compared by cross-validated
        held-out error, the lowest chosen; "paper": all but u_z, u_alpha, v_x, v_z, v_alpha,
        v_gamma (Section 4.2); "all": every parameter (LM takes minimum-norm steps: combinations the data do not
        determine at the start stay there while the data barely see them, parameters without
        effect keep their values); or
        parameter names. Default (None): "auto" when the calibration rows hold fewer than
        AUTO_BELOW_COMPONENTS_PER_PARAM residual components per identifiable parameter (with
        ``estimator="ls"``; the default estimator runs EB-MAP there), else "base".
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
    periodic : also identify periodic joint errors (:mod:`calib.model.periodic`: coefficients of
        sin q_i, cos q_i, sin 2q_i, cos 2q_i added to each revolute joint's angle, rad): the
        identifiable ones join the free set. A ``robot`` that already has them keeps them fixed
        unless ``periodic`` is True.
    terms : "auto" (default): the joint terms (compliance when the URDF has real link masses, periodic
        errors) chosen by cross-validated held-out error when the data hold many residual
        components per parameter (:func:`calib.calibration.terms.choose_terms`; a note gives the
        table), unless ``compliance`` or ``periodic`` is True or a payload or gravity is given;
        None or "none": only those asked for. ``result.robot`` carries every term it
        was fitted with (its ``T_meas_tool(q)`` includes them; ``write_urdf`` writes them to the
        sidecar beside the URDF).
    lm_variant : "calib" (default) or "paper": the LM of Eq. (27)-(28) as printed (mu I, mu reset
        to 0.001 lambda^+-1, unweighted residuals in mm and rad; :mod:`calib.solvers.paper_lm`), for
        methods "lm" and "c-lm" (not "search-lm").
    estimator : "auto" (default): "map" when ``params`` is None, the calibration rows hold fewer
        than AUTO_BELOW_COMPONENTS_PER_PARAM residual components per identifiable parameter, the
        loss is linear, lm_variant "calib" and compliance off; else "ls". "map": the regularised
        EB-MAP estimate (:mod:`calib.calibration.regularised`: every structural parameter with an
        effect under a Gaussian prior centred on ``robot``, one scale per group chosen with the
        noise levels by the evidence, the frames unconstrained; rows judged for gross errors by
        the least-squares fit first; the result's covariance is the posterior one, its
        ``estimator`` record gives the prior scales). "ls": least squares on ``params``.

    progress : None, or a function called as ``progress(fraction_done, stage)`` (0..1, the
        stage's name) as each stage starts and ``progress(1.0, "done")`` at the end: the fraction
        from the stages' rough shares of the time (STAGE_SHARES), for a progress line with the
        time left.

    Returns a :class:`CalibrationResult`; a fit that did not converge is reported in its
    ``status``, never raised. Raises :class:`calib.CalibError` for unusable input.
    """
    t0 = time.perf_counter()
    if progress is not None:
        _check_progress(progress)
    stages = _Stages(progress)
    opts = resolve_options(robot, measurements, validation, method=method, params=params, sigma_pos=sigma_pos,
                           sigma_rot=sigma_rot, init_frames=init_frames, max_rounds=max_rounds,
                           fixed_rounds=fixed_rounds, options=options, loss=loss, loss_scale=loss_scale,
                           outlier_k=outlier_k, cv=cv, compliance=compliance, lm_variant=lm_variant,
                           estimator=estimator, periodic=periodic)
    stages.start("joint terms")
    opts, notes, terms_fit = resolve_terms(robot, measurements, opts, terms, payload, gravity)
    if terms_fit is None:                       # (the joint terms were not judged)
        stages.skip("joint terms")
    stages.start("prepare")
    robot, gravity_notes = with_gravity_for(robot, opts.compliance, payload, gravity)
    robot = robot.with_periodic() if opts.periodic else robot
    notes += gravity_notes
    setup, prepare_notes = prepare(robot, measurements, validation, opts.init_frames)
    notes += prepare_notes + method_notes(setup, opts.method)
    robot, start, cal, val = setup.nominal, setup.start, setup.cal, setup.val     # (with the measured targets)
    log.info("prepare: %d calibration rows, %d validation rows, %s data%s", cal.n_poses,
             0 if val is None else val.n_poses, setup.measure,
             "".join(f"; {r} frame estimated" for r in setup.rebased))

    choice = choose_parameters(setup, opts, source=measurements.source)
    notes += choice.notes
    kin = setup.kin or ChainKinematics(start)
    # the errors before calibration first: the fit's kinematics start at the nominal values when
    # the frames were not moved
    accuracy = accuracy_before(robot, start, cal, val, rebased=setup.rebased,
                               kin=kin if start is robot else ChainKinematics(robot))
    selection, label, estimator = None, choice.label, None
    stages.start("fit")
    if choice.auto:
        from calib.calibration.selection import select_and_fit

        selection, fit, problem = select_and_fit(setup, choice.free, opts, kin)
        label = f"auto: {selection.chosen}"
    elif choice.label == "map":
        # (imported here: EB-MAP and its evidence are 4 ms of a start-up that does not use them)
        from calib.calibration.regularised import map_fit_stage

        regular = map_fit_stage(setup, choice.free, opts, kin, rank_deficit=choice.deficit,
                                source=measurements.source)
        fit, problem, estimator = regular.fit, regular.problem, regular.estimate.to_dict()
        label = "eb-map"
    else:
        # after the joint terms were judged, the fit starts where the chosen candidate's fit ended
        # (the same model on the same rows, linearised at the geometric solution: a few LM
        # iterations instead of the method's scheme), without the rows the geometric fit's
        # outlier check left out (taken back when the chosen model explains them: no robust fit
        # of every row again, which cost the real iiwa rows 100 ms)
        warm = terms_fit is not None and not choice.deficit
        start_setup = setup
        if warm:
            gross = np.isin(cal.rows, terms_fit.outlier_rows)
            suspect = gross if setup.suspect is None else (setup.suspect | gross)
            start_setup = replace(setup, start=warm_start(setup.start, terms_fit.start, choice.free),
                                  suspect=suspect if suspect.any() else None)
        fit, problem = fit_with(start_setup, choice.free, opts, outlier_k=opts.outlier_k, kin=kin,
                                rank_deficit=choice.deficit, warm=warm)
    implausible = implausibility(robot, fit, sigma_pos_given=opts.sigma_pos is not None,
                                 sigma_rot_given=opts.sigma_rot is not None)
    causes = misreadings(setup, fit, opts, implausible=bool(implausible) or fit.solver.status != "converged")
    implausible = causes + implausible
    notes += list(fit.notes) + implausible + length_notes(robot, fit.model)
    status, message = fit.solver.status, fit.solver.message
    if implausible and (status == "converged" or causes):
        status, message = "implausible", implausible[0]

    stages.start("statistics")
    stats = statistics_stage(setup, fit, problem)
    log.info("statistics: rank %d, predicted held-out RMS %.4g mm", stats.rank,
             stats.predicted_holdout["position_rms"] * 1e3)
    # physics that contradicts itself (a joint turning against its load) is refused
    physics = compliance_refusal(fit.model, fit.free, stats.covariance, problem.Q)
    if physics and status == "converged":
        status, message = "implausible", physics[0]
    notes += statistics_notes(stats) + physics + \
        compliance_notes(fit.model, fit.free, stats.covariance, refused=bool(physics)) + payload_note(fit.model, problem)
    stages.start("cross-validation")
    cross, cv_notes = held_out_error(setup, fit, problem, selection, opts.folds, opts.lm)
    notes += cv_notes
    errors = fit.errors             # (made from the kept residuals: once for both uses below)
    accuracy = accuracy_after(accuracy, fit.model, errors, val, robot.targets, kin)
    # validation figures that cannot be right (positions in another unit) are refused
    units = validation_implausibility(fit.model, val, accuracy.val_rows, errors.subset(fit.keep),
                                      accuracy.validation_after)
    if units and status == "converged":
        status, message = "implausible", units[0]
    notes += units

    nz = fit.noise
    # a measurement frame estimated from the data is the instrument's: the robot's base frame in
    # it is reported apart (calib.calibration.base_frame), the URDF stays rooted at the robot
    mframe, in_base = None, fit.model
    if "measurement->base" in setup.rebased:
        from calib.calibration.base_frame import in_base_frame, robot_base_frame

        mframe = robot_base_frame(fit.model, robot, covariance=stats.covariance, free=fit.free,
                                  position_only=setup.measure == "position")
        in_base = in_base_frame(fit.model, mframe)
    stages.start("done")
    return CalibrationResult(
        robot=fit.model, nominal=robot, method=opts.method, param_set=label,
        parameters=_parameter_table(robot, in_base, fit.free, stats.covariance), free=fit.free,
        status=status, message=message, iterations=fit.iterations,
        rounds=fit.solver.rounds, wall_time=time.perf_counter() - t0, cost=float(fit.solver.cost),
        reduced_chi2=nz.reduced_chi2, covariance=stats.covariance, before=accuracy.before, after=accuracy.after,
        validation_before=accuracy.validation_before, validation_after=accuracy.validation_after,
        predicted=stats.predicted, sigma_pos=nz.position,
        sigma_rot=nz.rotation if nz.rotation is not None else opts.weights[1],
        notes=tuple(consistency_notes(stats.consistency) + notes),
        outliers=fit.outliers, loss=opts.loss, noise=nz, predicted_holdout=stats.predicted_holdout,
        cross_validation=cross, selection=selection, before_registered=accuracy.before_registered,
        validation_before_registered=accuracy.validation_before_registered, targets=accuracy.targets,
        after_without_outliers=errors.subset(fit.keep) if fit.outliers else None,
        estimated_frames=setup.rebased, predicted_workspace=stats.predicted_workspace,
        consistency=stats.consistency, estimator=estimator or {"kind": "least-squares", "param_set": label},
        measurement_frame=mframe)
