"""Pose targets compensated on a controlled branch (see :mod:`calib.compensation.configuration`).

A pose is reached by several joint solutions; the controller takes the one its program's
configuration, or its current joints, name. The corrected joints must be that solution moved by
the correction, never another branch: a target whose corrected joints left the branch of their
reference is given the status ``"branch"`` (refused: the row names how it left).

The reference, by precedence:

* starting joints (a seed column): the branch of the seed;
* a vendor configuration (KUKA Status/Turn, ABB confdata, FANUC configuration string): the
  nominal model's solution with exactly that configuration (:func:`configured_solutions`), found
  from the seed configurations of that configuration nearest the target;
* else the nominal model's own solution for the target (the one reached from the seed
  configuration nearest the target, near the middle of the joint ranges), which the controller,
  which runs the nominal model, would use.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.compensation.solver import (SEED_CONFIGURATIONS, SEED_ROTATION_M, STATUSES,
                                                   CompensationResult, finite_limits, solve_from,
                                                   solve_from_seeds)
from calib.compensation.configuration import (Configurations, branch_change, branch_key, format_configuration,
                                             vendor_configuration, with_turns)
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel

__all__ = ["check_branch", "from_nominal_solution", "configured_solutions", "from_configurations"]

#: Seeds of the configuration asked for tried per target, nearest first.
CONFIGURED_SEEDS = 8


def check_branch(result: CompensationResult, robot: RobotModel, q_ref: np.ndarray, reference: str,
                 *, keep: np.ndarray | None = None) -> CompensationResult:
    """``result`` with status "branch" for the targets (ok or limit) whose joints are on another
    branch than ``q_ref`` (N, n) rad, ``reference`` saying what q_ref is ("the seed's", ...); a
    target where ``keep`` (N,) bool is False keeps its status and detail."""
    details = branch_change(robot, result.q, q_ref)
    moved = np.array([bool(d) for d in details]) & np.isin(result.status, ("ok", "limit"))
    if keep is not None:
        moved &= keep
    branch = np.array([f"{d}: another branch than {reference}" if m else "" for d, m in zip(details, moved)],
                      dtype=object)
    if result.branch is not None:
        branch = np.where(moved, branch, result.branch)
    status = np.where(moved, "branch", result.status).astype("<U13")
    status.setflags(write=False)
    return replace(result, status=status, branch=branch)


def _worse(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ia = np.array([STATUSES.index(x) for x in a])
    ib = np.array([STATUSES.index(x) for x in b])
    return np.where(ia <= ib, a, b).astype("<U13")


def from_nominal_solution(calibrated: RobotModel, nominal: RobotModel, p_t, R_t, seed, singular_threshold,
                          tol_pos, tol_rot, max_iterations) -> CompensationResult:
    """Pose targets without a start: the nominal model's own solution (seeded as in
    :func:`calib.compensation.compensate.compensate_poses`), then the calibrated model from
    there, on its branch. A target the nominal model does not reach keeps the nominal solve's
    status (its solution is no reference)."""
    nom = solve_from_seeds(nominal, p_t, R_t, seed, singular_threshold, tol_pos, tol_rot, max_iterations)
    q0 = np.array(nom.q)
    res = solve_from(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)
    unreached = nom.status == "not_converged"
    if unreached.any():
        status = np.where(unreached, _worse(res.status, nom.status), res.status).astype("<U13")
        status.setflags(write=False)
        res = replace(res, status=status)
    return check_branch(res, calibrated, q0, "the nominal model's solution for the target", keep=~unreached)


def configured_solutions(nominal: RobotModel, p_t, R_t, configurations: Configurations, seed: int,
                         singular_threshold, tol_pos, tol_rot, max_iterations):
    """The nominal model's solution of each target with the configuration asked for.

    Returns (q (N, n) rad, NaN rows where none was found; why (N,) str, "" where found). Each
    target is solved from the ``CONFIGURED_SEEDS`` seed configurations (of 512 drawn within the
    joint limits with ``seed``, and the middle of the ranges) of its branch nearest it in pose;
    the solutions reached are moved by whole turns to the configuration's turns
    (:func:`calib.compensation.configuration.with_turns`) and taken when their whole configuration
    is the one asked for (then the one within the limits, nearest the middle of the ranges).
    """
    vendor, values = configurations.vendor, configurations.values
    N, n = len(p_t), nominal.n_joints
    lo, hi = finite_limits(nominal)
    mid, half = (lo + hi) / 2, np.where(hi > lo, (hi - lo) / 2, 1.0)
    seeds = np.vstack([mid[None], nominal.random_configurations(SEED_CONFIGURATIONS, seed)])
    seed_keys = [branch_key(vendor, v) for v in
                 vendor_configuration(nominal, seeds, vendor, T_base_frame=configurations.T_base_frame)]
    R_s, p_s = ChainKinematics(nominal).frame_poses(seeds)
    d = np.sum((p_s[None] - p_t[:, None]) ** 2, axis=2)
    if R_t is not None:
        d += SEED_ROTATION_M ** 2 * np.sum((R_s[None] - R_t[:, None]) ** 2, axis=(2, 3))
    pick = np.full((N, CONFIGURED_SEEDS), -1)
    for k in range(N):
        match = np.flatnonzero([key == configurations.branch_key(k) for key in seed_keys])
        if len(match):
            best = match[np.argsort(d[k, match])[:CONFIGURED_SEEDS]]
            pick[k, :len(best)] = best
    rows, cols = np.nonzero(pick >= 0)
    q_out = np.full((N, n), np.nan)
    why = np.array([f"no seed configuration has the branch of {format_configuration(vendor, values[k])}"
                    for k in range(N)], dtype=object)
    if not len(rows):
        return q_out, why
    sub = solve_from(nominal, seeds[pick[rows, cols]], p_t[rows], None if R_t is None else R_t[rows],
                 singular_threshold, tol_pos, tol_rot, max_iterations, start_counts=False, wrap=True)
    q = with_turns(nominal, np.array(sub.q), vendor, [values[k] for k in rows])
    got = vendor_configuration(nominal, q, vendor, T_base_frame=configurations.T_base_frame)
    reached = sub.position_error < tol_pos
    if sub.rotation_error is not None:
        reached &= sub.rotation_error < tol_rot
    within = (q >= nominal.lower - 1e-12).all(axis=1) & (q <= nominal.upper + 1e-12).all(axis=1)
    score = np.abs((q - mid) / half).max(axis=1) + np.where(within, 0.0, 10.0)
    for k in range(N):
        at = np.flatnonzero(rows == k)
        good = [j for j in at if reached[j] and tuple(got[j]) == tuple(values[k])]
        if good:
            j = min(good, key=lambda j: score[j])
            q_out[k] = q[j]
            why[k] = ""
        elif any(reached[j] for j in at):
            seen = sorted({format_configuration(vendor, got[j]) for j in at if reached[j]})
            why[k] = (f"the nominal model reaches the target with {', '.join(seen)} but not with "
                      f"{format_configuration(vendor, values[k])}")
        else:
            why[k] = f"the nominal model does not reach the target with {format_configuration(vendor, values[k])}"
    return q_out, why


def from_configurations(calibrated: RobotModel, nominal: RobotModel, p_t, R_t, configurations: Configurations,
                        seed, singular_threshold, tol_pos, tol_rot, max_iterations) -> CompensationResult:
    """Pose targets with the configuration asked for: the nominal model's solution with it
    (:func:`configured_solutions`), then the calibrated model from there; a target without such
    a solution, or whose corrected joints left its branch (the branch part of the
    configuration changed, or :func:`calib.compensation.configuration.branch_change`), is refused
    (status "branch", the detail naming the configuration)."""
    q_nom, why = configured_solutions(nominal, p_t, R_t, configurations, seed, singular_threshold, tol_pos,
                                      tol_rot, max_iterations)
    found = ~np.isnan(q_nom).any(axis=1)
    q0 = np.where(found[:, None], q_nom, (nominal.lower + nominal.upper) / 2 if np.isfinite(
        nominal.lower + nominal.upper).all() else 0.0)
    res = solve_from(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)
    vendor = configurations.vendor
    got = vendor_configuration(calibrated, res.q, vendor, T_base_frame=configurations.T_base_frame)
    branch = np.array(["" if found[k] else f"{why[k]}" for k in range(len(q0))], dtype=object)
    for k in np.flatnonzero(found):
        if branch_key(vendor, got[k]) != configurations.branch_key(k) and res.status[k] in ("ok", "limit"):
            branch[k] = (f"the corrected joints have {format_configuration(vendor, got[k])}, not "
                         f"{format_configuration(vendor, configurations.values[k])}")
    # (a target without such a solution is refused whatever the solve from elsewhere gave)
    refused = ~found | ((branch != "") & ~np.isin(res.status, ("singular",)))
    status = np.where(refused, "branch", res.status).astype("<U13")
    status.setflags(write=False)
    res = replace(res, status=status, branch=np.where(refused, branch, ""))
    return check_branch(res, calibrated, q0, f"the nominal model's solution with the configuration asked for",
                        keep=found & ~refused)
