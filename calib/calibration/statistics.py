"""The statistics stage (:class:`Statistics`): parameter covariance and the predicted accuracy of the
calibrated model (propagation of the covariance through the pose Jacobian).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.calibration.accuracy import target_rows
from calib.calibration.consistency import data_consistency
from calib.calibration.estimators.base import Fit
from calib.calibration.prepare import Setup
from calib.calibration.validation import row_traces
from calib.calibration.workspace import predict_workspace, propagate_covariance, propagated, workspace_notes
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
    configurations within the joint limits (:func:`calib.calibration.workspace.predict_workspace`;
    None when not computed). consistency : when many calibration rows were flagged as outliers,
    the held-out error of all of them beside the prediction for rows like the kept ones
    (:func:`calib.calibration.consistency.data_consistency`; None otherwise).
    """

    covariance: np.ndarray = field(repr=False)
    full_rank: bool
    rank: int
    predicted: dict
    predicted_holdout: dict
    where: str
    predicted_workspace: dict | None = None
    consistency: dict | None = None


# ---------------------------------------------------------------- statistics
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
    (:func:`calib.calibration.workspace.workspace_notes`)."""
    notes = workspace_notes(stats.predicted_holdout, stats.predicted_workspace)
    if stats.full_rank:
        return notes
    return notes + ["the free parameters are not all identifiable (rank-deficient set): standard "
            "deviations come from the pseudo-inverse and describe only the identifiable combinations"]
