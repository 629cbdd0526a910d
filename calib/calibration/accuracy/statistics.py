"""The statistics stage (:class:`Statistics`): parameter covariance and the predicted accuracy of the
calibrated model (propagation of the covariance through the pose Jacobian); for touch data
(:func:`touch_statistics`) the tool positions' error over the workspace after a best-fit
registration, the design judged against the nominal model's expected error, and each residual
group's figures (:func:`group_fits`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.calibration.accuracy.errors import registered_residuals, target_rows
from calib.calibration.accuracy.validation import data_consistency
from calib.calibration.estimators.base import Fit, GroupFit
from calib.calibration.plausibility import LENGTH_FRACTION as IMPLAUSIBLE_LENGTH_FRACTION
from calib.calibration.prepare import Setup, reach_of
from calib.calibration.accuracy.validation import row_traces
from calib.calibration.accuracy.workspace import (predict_workspace, predicted_tool_error, propagate_covariance, propagated,
                                         workspace_configurations, workspace_notes)
from calib.model.kinematics import ChainKinematics
from calib.solvers.blocks import GROUPS
from calib.solvers.inverse import normal_inverse
from calib.solvers.problem import Problem


@dataclass(frozen=True, eq=False, repr=False)     # (array fields, an internal stage value: nothing compares or prints it)
class Statistics:
    """The statistics stage.

    covariance : (n_free, n_free) covariance of the free parameters (SI units), from the noise
    levels of the fit; full_rank : False when it is a pseudo-inverse. rank : rank of the weighted
    Jacobian. predicted : RMS error of the calibrated model against the true poses at ``where``
    (position_rms m, rotation_rms rad): the covariance propagated to the poses. predicted_holdout :
    RMS error against new measured rows: the covariance inflated by the measured misfit, plus the
    measurement noise (inflated likewise). predicted_workspace : the same over random
    configurations within the joint limits (:func:`calib.calibration.accuracy.workspace.predict_workspace`;
    None when not computed). consistency : when many calibration rows were flagged as outliers,
    the held-out error of all of them beside the prediction for rows like the kept ones
    (:func:`calib.calibration.accuracy.validation.data_consistency`; None otherwise). refusals : why the
    design cannot be trusted (touch data: :func:`touch_statistics`), which the verdict reports.
    """

    covariance: np.ndarray = field(repr=False)
    full_rank: bool
    rank: int
    predicted: dict
    predicted_holdout: dict
    where: str
    predicted_workspace: dict | None = None
    consistency: dict | None = None
    refusals: tuple[str, ...] = ()


# ---------------------------------------------------------------- statistics
def statistics_stage(setup: Setup, fit: Fit, problem: Problem) -> Statistics:
    """Covariance and predictions (see :class:`Statistics`; touch data: :func:`touch_statistics`)."""
    if setup.touch is not None:
        return touch_statistics(setup, fit, problem)
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
            return propagate_covariance(fit.model, Q, fit.free, cov, kin, rows)
        # at the calibration rows: the Jacobian of the fit's rows at its solution, computed once
        return propagated((J for _, _, J in problem.derived(loss="linear").whitened_blocks(x, raw=True)), len(Q), cov)

    if setup.val is None:
        # at the calibration rows, with the held-out traces below (one product J C for both)
        t_p, t_r, e_p, e_r = row_traces(problem.derived(loss="linear"), x, C)
        pos, rot = math.sqrt(max(e_p, 0.0)), math.sqrt(max(e_r, 0.0))
    else:
        pos, rot = propagate(C)
    nz = fit.noise
    has_rot = setup.measure == "pose"
    # misfit: a group whose residuals exceed the given noise inflates both the parameter
    # uncertainty and the error of a new measurement (an estimated noise level already holds it;
    # a robust fit's does not: its levels are the median residual's, which the tails it weighs
    # down exceed in RMS, and its predictions on the real sets were 0.80-0.90 of the observed
    # held-out error, now RMS figures: issue 39, item 5)
    robust = problem.loss != "linear"
    infl_p = 1.0 if (nz.estimated and not robust) else max(1.0, nz.chi2_pos)
    infl_r = 1.0 if ((nz.estimated and not robust) or not has_rot) else max(1.0, nz.chi2_rot)
    if infl_p == 1.0 and infl_r == 1.0:
        pos_e, rot_e, C_eff = pos, rot, C
    else:
        A_eff = ne.A_pos / infl_p + (ne.A_rot / infl_r if ne.A_rot is not None else 0.0)
        if fit.prior_precision is not None:
            # a regularised fit: its prior stays (without it the prediction jumped by 15 % as the
            # given noise crossed chi^2 = 1, to the least-squares one of the whole set)
            A_eff = A_eff + np.diag(fit.prior_precision)
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
        holdout_p = math.sqrt(nz.position ** 2 * infl_p * t_p)
        holdout_r = math.sqrt(nz.rotation ** 2 * infl_r * t_r) if has_rot else None
    predicted = {"position_rms": pos, "rotation_rms": rot if has_rot else None, "where": where}
    holdout = {"position_rms": holdout_p, "rotation_rms": holdout_r, "where": where}
    # the same covariance and noise over the workspace: poses bunched in a corner of it predict
    # themselves well and the rest badly
    workspace = predict_workspace(fit.model, fit.free, C_eff, nz.position * math.sqrt(infl_p),
                                  nz.rotation * math.sqrt(infl_r) if has_rot else None,
                                  calibration_q=setup.cal.q[fit.keep], kin=kin)
    # many flagged rows: what the prediction leaves out (none flagged: nothing to judge, no
    # problem derived for it)
    flagged = [o.row for o in fit.outliers + fit.unremoved]
    consistency = None if not flagged else data_consistency(
        fit.all_rows.derived(sigma_pos=problem.sigma_pos, sigma_rot=problem.sigma_rot, loss="linear"), x,
        fit.keep, C, holdout, rows=setup.cal.rows, flagged_rows=flagged)
    return Statistics(C, full_rank, rank, predicted, holdout, where, workspace, consistency)


def statistics_notes(stats: Statistics) -> list[str]:
    """A note when the free parameters are not all identifiable, and when the predicted error
    over the workspace is far above the one at the calibration configurations
    (:func:`calib.calibration.accuracy.workspace.workspace_notes`)."""
    notes = workspace_notes(stats.predicted_holdout, stats.predicted_workspace)
    if stats.full_rank:
        return notes
    return notes + ["the free parameters are not all identifiable (rank-deficient set): standard "
            "deviations come from the pseudo-inverse and describe only the identifiable combinations"]


#: Random configurations within the joint limits over which the tool error of a calibration from
#: touch data is predicted.
TOUCH_CONFIGURATIONS = 500
#: A touch design is refused when the predicted tool error over the workspace exceeds the nominal
#: model's expected error there, and this many times the touch noise (a calibration of a robot
#: already at its nominal values predicts the noise only: no design is refused for that).
DESIGN_NOISE_FACTOR = 5.0


def touch_statistics(setup: Setup, fit: Fit, problem) -> Statistics:
    """The statistics of a fit of touch data: the covariance of the robot parameters (the
    features' are in ``fit.covariance``); ``predicted``: the Cramer-Rao prediction of the tool
    positions' RMS error over TOUCH_CONFIGURATIONS random configurations after a best-fit rigid
    registration (similarity when no length fixes the scale), and in the meas frame when measured
    rows identified it (``meas_frame_rms``); the nominal model's expected error there
    (``nominal_rms``: the RMS of the correction the fit applies, registered the same way, less
    the part the noise makes of it, sqrt(correction^2 - prediction^2); against the nominal robot
    with the fitted tool offset: an unknown tool is no error of the robot's). Refused (the
    ``refusals`` the verdict reports): a correction beyond IMPLAUSIBLE_LENGTH_FRACTION of the
    reach (no robot is that far from its drawing; touch rows that contradict each other fit such
    a robot to the noise, where measured poses would not), and a design whose predicted error
    exceeds the nominal model's (and DESIGN_NOISE_FACTOR times the noise), naming what to add:
    the calibrated model is expected to be worse than the nominal one (a sphere touched only
    within an 11 degree cap: 9 mm predicted, the URDF 2.8 times worse than the nominal)."""
    m = len(fit.free)
    x = fit.solver.x
    C = fit.covariance[:m, :m]
    ne = problem.normal_equations(x)
    rank = int(round(float(np.trace(fit.covariance @ ne.A))))
    model = fit.model
    Q = workspace_configurations(model, TOUCH_CONFIGURATIONS)
    lengths = any(p.group == "joint" and p.unit == "m" for p in model.parameters if p.name in set(fit.free))
    registration = "similarity" if (setup.cal is None and lengths and not any(
        f.kind == "sphere" for f in setup.touch.features)) else "rigid"
    pred = predicted_tool_error(model, fit.free, C, Q, registration)
    p_cal = ChainKinematics(model).frame_poses(Q)[1]
    # (the nominal robot with the fitted tool: an unknown tool is no error of the robot's)
    v = setup.nominal.values.copy()
    tool = [k for k, p in enumerate(model.parameters) if p.group == "v" and p.name in set(fit.free)]
    v[tool] = model.values[tool]
    p_nom = ChainKinematics(setup.nominal.with_values(v)).frame_poses(Q)[1]
    correction = float(np.sqrt(np.mean(np.sum(registered_residuals(p_cal, p_nom, registration) ** 2, axis=1))))
    nominal = math.sqrt(max(correction ** 2 - pred ** 2, 0.0))
    where = (f"{TOUCH_CONFIGURATIONS} random configurations within the joint limits, after a best-fit "
             f"{registration} registration")
    predicted = {"position_rms": pred, "rotation_rms": None, "where": where, "registration": registration,
                 "configurations": TOUCH_CONFIGURATIONS, "correction_rms": correction, "nominal_rms": nominal,
                 "meas_frame_rms": None if setup.cal is None else predicted_tool_error(model, fit.free, C, Q, "none")}
    refusals = ()
    reach = reach_of(setup.nominal)
    if correction > IMPLAUSIBLE_LENGTH_FRACTION * reach:
        # (touch rows fix the robot relative to features they locate themselves: a robot bent far
        # from its drawing can fit them to the noise, where measured poses would not fit it)
        refusals = (f"the calibrated model is not this robot: its tool positions lie {correction * 1e3:.4g} mm "
                    f"({where}) from the URDF's, more than {100 * IMPLAUSIBLE_LENGTH_FRACTION:g} % of the robot's "
                    f"reach {reach * 1e3:.0f} mm, which no robot is from its drawing; the touch rows fit such a "
                    f"robot when they contradict each other (two features touched under one name: "
                    f"{', '.join(f'{f.kind} {f.id!r}' for f in setup.touch.features)}) or when the URDF is not "
                    f"this robot's",)
    elif pred > nominal and pred > DESIGN_NOISE_FACTOR * problem.sigma_touch:
        refusals = (f"the design cannot calibrate this robot: the predicted tool position error over the "
                    f"workspace ({where}) is {pred * 1e3:.3g} mm, more than the nominal model's expected "
                    f"{nominal * 1e3:.3g} mm (the fit's correction {correction * 1e3:.3g} mm less what the noise "
                    f"makes of it): the calibrated model would be worse than the nominal one; "
                    + design_advice(setup, fit),)
    return Statistics(C, bool(fit.full_rank), rank, predicted, None, predicted["where"], None, None, refusals)


def design_advice(setup: Setup, fit: Fit) -> str:
    """What to add to a touch design that determines the robot too weakly: the spheres touched
    over a small cap of their surface named, and rows spread over the workspace or more features."""
    touch, F = setup.touch, fit.solver.x[len(fit.free):].reshape(-1, 3)
    p = ChainKinematics(fit.model).frame_poses(touch.q)[1]
    caps = []
    for k, f in enumerate(touch.features):
        if f.kind == "sphere":
            e = p[touch.rows_of(k)] - F[k]
            e /= np.linalg.norm(e, axis=1)[:, None]
            mean = e.mean(axis=0) / max(np.linalg.norm(e.mean(axis=0)), 1e-300)
            angle = float(np.degrees(np.arccos(np.clip(e @ mean, -1.0, 1.0))).max())
            if angle < 60.0:
                caps.append(f"sphere {f.id!r} is touched within {angle:.0f} degrees of one direction from its "
                            f"centre: touch it over a wider cap (a hemisphere)")
    return "; ".join(caps + ["add rows spread over the workspace and other features (a sphere of known radius, "
                             "planes of three directions, points) or rows measured by an instrument"])


def group_fits(problem, fit: Fit, x0: np.ndarray, given: tuple, rows_of: dict, cv: dict | None = None
               ) -> tuple[GroupFit, ...]:
    """The :class:`GroupFit` of each residual group of a fit of residual blocks (``problem``: the
    kept rows at the fit's noise levels): its components' RMS at the start x0 and at the solution,
    its noise (``given`` per group, None: estimated), its redundancy, its held-out RMS (``cv``:
    group -> RMS per component); rows_of : group -> its rows."""
    x = fit.solver.x
    r0, r1 = problem.evaluate(x0, jacobian=False)[0], problem.evaluate(x, jacobian=False)[0]
    nz = fit.noise
    estimated = {"position": (nz.position, nz.redundancy_pos), "rotation": (nz.rotation, nz.redundancy_rot),
                 "touch": (nz.touch, nz.redundancy_touch)}
    out = []
    for g in sorted(problem.groups, key=("touch", "position", "rotation").index):     # (the touch rows first)
        k = GROUPS.index(g)
        sel = problem.component_group == k
        level, red = estimated[g]
        rss = float(r1[sel] @ r1[sel]) / problem.levels[k] ** 2
        est = problem.levels[k] * math.sqrt(rss / red) if red > 0.5 else problem.levels[k]
        out.append(GroupFit(g, rows_of[g], int(sel.sum()), float(np.sqrt(np.mean(r0[sel] ** 2))),
                            float(np.sqrt(np.mean(r1[sel] ** 2))), float(level), given[k] is not None, float(est),
                            float(red), None if cv is None else cv.get(g)))
    return tuple(out)
