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

import logging
import math
import time
from dataclasses import replace
from typing import Sequence

from calib.calibration.accuracy import pose_errors, register_measurement_frame, target_rows
from calib.calibration.fit import _solver_for, fit_stage
from calib.calibration.options import (
    AUTO_BELOW_COMPONENTS_PER_PARAM,
    CV_FOLDS,
    LM_VARIANTS,
    LOO_BELOW_ROWS,
    MIN_REDUNDANCY,
    PARAM_SETS,
    _check_options,
)
from calib.calibration.parameters import (
    _compliance_filter,
    _set_rank_deficit,
    candidate_sets,
    identifiable_set,
    select_parameters,
)
from calib.calibration.prepare import (
    _implausible_fit_notes,
    _implausible_length_notes,
    check_data_rank,
    prepare,
)
from calib.calibration.result import CalibrationResult, TargetAccuracy, _parameter_table
from calib.calibration.statistics import statistics_stage
from calib.calibration.validation import cross_validate, select_model
from calib.errors import DataError, ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.solvers.lm import LMOptions
from calib.solvers.problem import CHI2_ESCAPE

log = logging.getLogger(__name__)


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
