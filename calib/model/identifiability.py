"""Which TM-MDH parameters the measurements can identify, and how they are tied to each other.

The analysis looks at the identification Jacobian over a set of configurations (random within
the joint limits unless given):

1. Rows are weighted by the measurement noise (1/sigma_pos for position rows, 1/sigma_rot for
   rotation rows), so that metres and radians enter as they would in a maximum-likelihood fit.
2. Columns are scaled to unit norm, so that a parameter in metres and one in radians compare by
   the shape of their effect, not by their unit.
3. Columns are taken in priority order (by default the order of Eq. (23): structural parameters
   joint by joint kind by kind, then u, then v). A column is identifiable if the part of it that
   the columns already kept cannot explain has norm above ``tol`` (default 1e-6: a parameter
   whose effect is reproduced by the others to one part in a million is tied to them; its
   variance would be amplified by at least 1e12). This is QR with a column order fixed by
   priority instead of by pivoting, so the structural parameters are kept and the redundant
   transform parameters dropped, as Section 4.2 of the paper recommends.
4. Each unidentifiable parameter is reported with the kept parameters it is tied to: the least
   squares coefficients c with ``J[:, p] ~ sum_k c_k J[:, k]`` in physical units (a change of p by
   delta acts as changes c_k delta of the partners), or "no effect" if its column is zero.

For BRTIRUS0707A with full-pose data this finds rank 30 of 37 and the seven relations of Section
4.2: d3-d2, u_z-d1, u_alpha-theta1, v_x-a6, v_z-d6, v_alpha-theta6, v_gamma-alpha6.

Observability indices of the identifiable columns (weighted rows, unit columns, singular values
sigma_1 >= ... >= sigma_r of an m x r matrix): O1 = (prod sigma)^(1/r) / sqrt(m) (Borm and Menq's
normalised product), O3 = sigma_r (the smallest), O4 = sigma_r^2 / sigma_1 (noise amplification,
Nahvi and Hollerbach), and the condition number sigma_1 / sigma_r.

This module holds the selection every calibration makes (:func:`select_identifiable`,
:func:`identifiable_names`); the full report (:func:`analyze_identifiability`,
:class:`IdentifiabilityReport`, the relations and observability indices) is in
:mod:`calib.model.identifiability_report`, loaded by the commands that print it.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from calib.checks import check_configurations, check_int, check_number, check_rng, check_target_indices
from calib.model.robot import MAX_CONFIGURATIONS, check_robot
from calib.errors import DataError, ParameterError
from calib.memo import Memo, content_digest
from calib.model.jacobian import MEASURES, identification_jacobian
from calib.model.robot import RobotModel
from calib.model.jacobian import NO_EFFECT_RTOL

#: Default noise levels used for row weighting (the paper's simulation, Section 4.3).
SIGMA_POS_M = 0.02e-3
SIGMA_ROT_RAD = 0.002
#: Default touch noise (metres per residual component of a touch row: a good probe in a good nest).
SIGMA_TOUCH_M = 0.02e-3
#: Default relative tolerance on the unexplained part of a unit column.
RANK_TOL = 1e-6
#: How many analyses :func:`analyze_identifiability` keeps for repeated calls.
CACHE_SIZE = 64
#: The reports (and identifiable names) of the last CACHE_SIZE analyses.
ANALYSES = Memo("identifiability", CACHE_SIZE, lru=True)
#: (the cache key of a Jacobian without the priority, the noise-weighted Jacobian) of the last
#: :func:`identifiable_names` that computed one.
LAST_JACOBIAN = Memo("identifiability jacobian", 1)


def weighted_jacobian(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float,
                      sigma_rot: float, targets: np.ndarray | None = None) -> np.ndarray:
    """The identification Jacobian with rows divided by their noise sigma (dimensionless rows);
    targets: (N,) each row's target index for a multi-target model."""
    J = identification_jacobian(robot, Q, measure, targets)
    k = 6 if measure == "pose" else 3
    w = np.array([1 / sigma_pos] * 3 + [1 / sigma_rot] * 3)[:k]
    return J * np.tile(w, len(J) // k)[:, None]


def observability_indices(J: np.ndarray) -> dict[str, float]:
    """O1, O3, O4 and the condition number of a (weighted, scaled) Jacobian (m x r)."""
    s = np.linalg.svd(J, compute_uv=False)
    m, r = J.shape
    with np.errstate(divide="ignore"):
        O1 = float(np.exp(np.mean(np.log(s))) / np.sqrt(m)) if s[-1] > 0 else 0.0
    return {"O1": O1, "O3": float(s[-1]), "O4": float(s[-1] ** 2 / s[0]),
            "condition_number": float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
            "singular_values": s}


def no_effect(norms: np.ndarray, j: int) -> bool:
    """Whether column j is zero up to rounding (relative to the largest column of the
    noise-weighted Jacobian, whose columns all have the dimension 1 / unit of the parameter)."""
    return bool(norms[j] <= NO_EFFECT_RTOL * norms.max())


def select_identifiable(J: np.ndarray, order: Sequence[int], tol: float = RANK_TOL):
    """Greedy rank-revealing selection of columns of J in the given priority order.

    Returns (kept column indices, dropped column indices), each in priority order.
    """
    norms = np.linalg.norm(J, axis=0)
    kept: list[int] = []
    dropped: list[int] = []
    order = list(order)
    basis = np.empty((len(order), J.shape[0]))   # the orthonormal basis, one vector per row
    cols = J.T.copy()      # (a column a contiguous row)
    for j in order:
        if no_effect(norms, j):
            dropped.append(j)
            continue
        c = cols[j] / norms[j]
        B = basis[:len(kept)]
        # (ndarray.dot: the products of @, at half its call overhead; math.sqrt(r.dot(r)): np.linalg.norm's value)
        r = c - B.dot(c).dot(B)
        r = r - B.dot(r).dot(B)  # re-orthogonalise (classical Gram-Schmidt twice)
        nr = math.sqrt(r.dot(r))
        if nr > tol:
            basis[len(kept)] = r / nr
            kept.append(j)
        else:
            dropped.append(j)
    return kept, dropped


def identifiable_names(robot: RobotModel, Q: np.ndarray, *, measure: str = "pose", tol: float = RANK_TOL,
                       sigma_pos: float = SIGMA_POS_M, sigma_rot: float = SIGMA_ROT_RAD,
                       priority: Sequence[str] | None = None, max_poses: int | None = 500,
                       targets: np.ndarray | None = None) -> tuple[str, ...]:
    """``analyze_identifiability(robot, Q, ...).identifiable`` (the same arguments, the same
    names in ``robot.names`` order) without the relations and observability indices of the
    report: the rank-revealing selection alone. The names are kept by content as the reports
    are, and the last noise-weighted Jacobian is reused for a call that differs from the one
    that computed it only by ``priority`` (the same model values, configurations and options)."""
    Q, targets = checked_rows(robot, Q, measure, 100, 0, tol, sigma_pos, sigma_rot, priority, max_poses, targets)
    key = analysis_key(robot, Q, measure, tol, sigma_pos, sigma_rot, priority, targets)
    report = ANALYSES.get(key)
    if report is not None:
        return report.identifiable
    names_key = ("names",) + key
    names = ANALYSES.get(names_key)
    if names is not None:
        return names
    J = LAST_JACOBIAN.get(key[:-1])
    if J is None:
        J = weighted_jacobian(robot, Q, measure, sigma_pos, sigma_rot, targets)
        J.setflags(write=False)         # (kept: handed out again by kept_weighted_jacobian)
        LAST_JACOBIAN.put(key[:-1], J)
    order = list(robot.indices(priority)) if priority else []
    order += [k for k in range(robot.n_params) if k not in order]
    kept, _ = select_identifiable(J, order, tol)
    names = tuple(robot.names[k] for k in sorted(kept))
    ANALYSES.put(names_key, names)
    return names


def kept_weighted_jacobian(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float,
                           sigma_rot: float, targets: np.ndarray | None = None) -> np.ndarray:
    """:func:`weighted_jacobian`, or the one the last :func:`identifiable_names` computed for
    the same model values, configurations, targets, measure and noise levels (the same array:
    read it, do not write it). A calibration's data-rank check asks for the Jacobian its
    identifiable set was just chosen with (the start model at the calibration rows; the key holds
    the gravity load of a model with compliance, whose torques its Jacobian depends on)."""
    J = LAST_JACOBIAN.get(analysis_key(robot, Q, measure, RANK_TOL, sigma_pos, sigma_rot, None, targets)[:-1])
    if J is not None:
        return J
    return weighted_jacobian(robot, Q, measure, sigma_pos, sigma_rot, targets)


def checked_rows(robot: RobotModel, Q, measure: str, n_poses: int, seed, tol: float, sigma_pos: float,
                  sigma_rot: float, priority, max_poses: int | None, targets) -> tuple:
    """The arguments of :func:`analyze_identifiability` checked, and the (configurations, target
    of each row) it analyses: random ones when Q is None, at most ``max_poses`` evenly spaced,
    every target at each configuration of a multi-target model without ``targets``."""
    check_robot(robot)
    if not isinstance(measure, str) or measure not in MEASURES:
        raise ParameterError(f"measure must be one of {', '.join(MEASURES)}, got {measure!r}")
    check_number(tol, "tol", minimum=0.0, maximum=1.0, strict=True)
    check_number(sigma_pos, "sigma_pos", minimum=1e-12, maximum=1.0)
    check_number(sigma_rot, "sigma_rot", minimum=1e-12, maximum=1.0)
    check_int(max_poses, "max_poses", minimum=1, allow_none=True)
    if priority is not None and (not isinstance(priority, (list, tuple))
                                 or not all(isinstance(n, str) for n in priority)):
        raise ParameterError(f"priority must be a list of parameter names, got {priority!r}")
    if Q is None:
        check_int(n_poses, "n_poses", minimum=1, maximum=MAX_CONFIGURATIONS)
        Q = robot.random_configurations(n_poses, check_rng(seed, "seed"))
    Q = check_configurations(Q, robot.n_joints)
    if len(Q) == 0:
        raise DataError("Q has no configurations")
    targets = check_target_indices(targets, len(Q), robot.n_targets)
    if max_poses is not None and len(Q) > max_poses:
        pick = np.linspace(0, len(Q) - 1, max_poses).astype(int)
        Q, targets = Q[pick], None if targets is None else targets[pick]
    if targets is None and robot.targets:
        Q, targets = np.repeat(Q, robot.n_targets, axis=0), np.tile(np.arange(robot.n_targets), len(Q))
    return Q, targets


def analysis_key(robot: RobotModel, Q: np.ndarray, measure: str, tol: float, sigma_pos: float,
               sigma_rot: float, priority, targets) -> tuple:
    """What the analysis depends on: the chain's structure and values, the gravity load of a model
    with compliance, the configurations, the options (a digest of the arrays, so that large data
    are not held by the cache)."""
    # (the model's content key holds the gravity load of a model with compliance: its columns are
    # the torques', which the load sets)
    rows = content_digest(np.asarray(Q, float), np.zeros(0) if targets is None else np.asarray(targets, float))
    return (robot.content_key, rows, measure, float(tol), float(sigma_pos), float(sigma_rot),
            None if priority is None else tuple(priority))
