"""Synthetic touch data (:mod:`calib.model.touch`): configurations of a "true" robot whose tool
point actually reaches a feature, within the joint limits, with noise on the touch.

Features are placed where the arm reaches them from many configurations: each point (and each
group's corner) is the tool point of a random configuration at a middle reach (between the 30th
and the 70th percentile of the distances from the base of 400 random tool points). The planes
of a design are perpendicular faces of a cube through one corner (their normals the columns of a
random rotation, in turn); a sphere's centre is such a point too. A row is found by inverse
kinematics of the position only (damped least squares on the true model, from a random start
within the limits, clamped at every step to LIMIT_MARGIN inside them): targets are the point
itself; a point of the plane within ``spread`` of the corner, the tool's z axis (the probe's direction) pointing into
the plane's front side, that of its normal, at least PROBE_MIN_SIN of it (a probe cannot touch
a plate from behind, nor along it); a point of the sphere in a random direction. The target is
moved by Gaussian noise of ``sigma`` per axis first (the touch's error: the recorded joint
values are where the arm really was). Random starts make the configurations, and so the tool
orientations, differ from row to row.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from calib.checks import check_int, check_number, check_rng
from calib.errors import DataError
from calib.model.chain import joint_variable_names
from calib.model.jacobian import damped_step
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import Feature, TouchData, frame_with_normal

#: Inverse kinematics: iterations, damping (metres), and the tolerance of a reached target.
IK_ITERATIONS = 200
IK_DAMPING = 1e-3
IK_TOL = 1e-10
#: Random starts tried per wanted row before a feature is moved elsewhere.
STARTS_PER_ROW = 12
#: A probe touching a plane: the sine of its angle to the plane, at least (about 17 degrees).
PROBE_MIN_SIN = 0.3
#: The most features and touch rows one simulation makes: each feature is placed and reached by
#: inverse kinematics from many random starts (about a second per feature of 100 rows), and a
#: touch calibration fits 3 unknowns per feature (100 features: 300, beside the robot's);
#: ``point:100000`` ran for days without a word.
MAX_FEATURES = 100
MAX_ROWS = 100_000
#: Simulated joint values stay this far inside each limit (rad, or m for prismatic joints; at
#: most 1 % of the range): a real controller's soft limits refuse a value on the limit itself.
LIMIT_MARGIN = 1e-3


@dataclass(frozen=True, eq=False)
class SimulatedTouch:
    """data : the rows; truth : (3 K,) the features' unknowns in the true robot's meas frame
    (point and sphere centres; planes as (a, b, d) about ``plane_refs``); plane_refs : (K, 3, 3);
    normals : (K, 3) each plane's unit normal (zeros for the other kinds)."""

    data: TouchData
    truth: np.ndarray
    plane_refs: np.ndarray
    normals: np.ndarray


def reach_positions(robot: RobotModel, targets: np.ndarray, rng=None, attempts: int = 1,
                    starts: np.ndarray | None = None,
                    margin: float = LIMIT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Configurations whose tool point is at ``targets`` (M, 3) metres, meas frame, by damped
    least squares from random starts within the joint limits (``attempts`` starts per target,
    the first that converges kept), or from ``starts`` (M, n) (one attempt), every iterate
    clamped to ``margin`` (rad or m, at most 1 % of the range) inside the limits (0: onto
    them). Returns (Q (M, n), reached (M,) bool)."""
    kin = ChainKinematics(robot)
    n = robot.n_joints
    cols = robot.indices(joint_variable_names(robot.joints))
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    inset = np.minimum(margin, 0.01 * (hi - lo))
    lo, hi = lo + inset, hi - inset            # strictly inside the limits when margin > 0
    targets = np.asarray(targets, float)
    M = len(targets)
    Q_out, ok = np.zeros((M, n)), np.zeros(M, bool)
    for _ in range(attempts):
        todo = np.flatnonzero(~ok)
        if not todo.size:
            break
        Q = (np.clip(robot.random_configurations(len(todo), rng), lo, hi) if starts is None
             else np.array(starts, float)[todo])
        for _ in range(IK_ITERATIONS):
            _, p, J = kin.poses_and_jacobian(Q, cols)
            e = targets[todo] - p
            if np.all(np.einsum("ij,ij->i", e, e) < IK_TOL ** 2):
                break
            Q = np.clip(Q + damped_step(J[:, :3], e, IK_DAMPING), lo, hi)
        p = kin.frame_poses(Q)[1]
        hit = np.linalg.norm(targets[todo] - p, axis=1) < 1e-9
        Q_out[todo[hit]], ok[todo[hit]] = Q[hit], True
    return Q_out, ok


def _candidate_points(robot: RobotModel, rng, n: int = 400) -> np.ndarray:
    p = ChainKinematics(robot).frame_poses(robot.random_configurations(n, rng))[1]
    base = robot.T_meas_base()[:3, 3]
    r = np.linalg.norm(p - base, axis=1)
    lo, hi = np.percentile(r, [30, 70])
    return p[(r >= lo) & (r <= hi)]


def simulate_touch(true_robot: RobotModel, features: Sequence[Feature], rows: Sequence[int], *,
                   sigma: float = 0.02e-3, rng=None, probe_radius: float = 0.0,
                   spread: float = 0.15, max_tries: int = 20) -> SimulatedTouch:
    """Touch rows of ``true_robot``: ``rows[k]`` rows on ``features[k]`` (see the module docstring).

    sigma : metres, the touch noise per axis; probe_radius : metres, a ball tip's radius (plane
    rows: the tool point lies at it from the plane); spread : metres, the half-size of the
    square of a plane's touched points around its corner. Raises DataError when a feature
    cannot be reached from enough configurations after ``max_tries`` placements.
    """
    check_robot(true_robot, "true_robot")
    check_number(sigma, "sigma", minimum=0.0)
    check_number(probe_radius, "probe_radius (m)", minimum=0.0, maximum=1.0)
    check_number(spread, "spread", minimum=0.0, strict=True)
    rng = check_rng(rng)
    check_int(max_tries, "max_tries", minimum=1, maximum=10_000)
    if not isinstance(features, (list, tuple)) or not features or not all(isinstance(f, Feature) for f in features):
        raise DataError("features must be a non-empty list of Feature values (calib.Feature)")
    features = tuple(features)
    if len(features) > MAX_FEATURES:
        raise DataError(f"{len(features)} features: at most {MAX_FEATURES} per simulation (each is reached by "
                        f"inverse kinematics from many starts; a touch calibration fits 3 unknowns per feature)")
    if (not isinstance(rows, (list, tuple, np.ndarray)) or len(rows) != len(features)
            or not all(isinstance(r, (int, np.integer)) and not isinstance(r, bool) and 1 <= r <= MAX_ROWS
                       for r in rows)):
        raise DataError(f"rows must give a number of rows (1 to {MAX_ROWS:,}) for each of the {len(features)} features")
    if sum(int(r) for r in rows) > MAX_ROWS:
        raise DataError(f"{sum(int(r) for r in rows):,} touch rows in all: at most {MAX_ROWS:,} per simulation")
    cand = _candidate_points(true_robot, rng)
    K = len(features)
    truth, refs, normals = np.zeros((K, 3)), np.tile(np.eye(3), (K, 1, 1)), np.zeros((K, 3))
    corner = cand[rng.integers(len(cand))]
    faces = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    n_planes = 0
    Qs, feat = [], []
    for k, (f, n_rows) in enumerate(zip(features, rows)):
        n_rows = int(n_rows)
        for _ in range(max_tries):
            if f.kind == "plane":
                n = faces[:, n_planes % 3]
                R = frame_with_normal(n)
                st = rng.uniform(-spread, spread, (STARTS_PER_ROW * n_rows, 2))
                targets = corner + st @ R[:, :2].T + probe_radius * n
                truth[k], refs[k], normals[k] = (0.0, 0.0, float(n @ corner)), R, n
            else:
                c = cand[rng.integers(len(cand))]
                if f.kind == "point":
                    targets = np.repeat(c[None], STARTS_PER_ROW * n_rows, axis=0)
                else:
                    u = rng.normal(size=(STARTS_PER_ROW * n_rows, 3))
                    targets = c + f.radius * u / np.linalg.norm(u, axis=1)[:, None]
                truth[k] = c
            noisy = targets + (rng.normal(0.0, sigma, targets.shape) if sigma > 0 else 0.0)
            Q, ok = reach_positions(true_robot, noisy, rng)
            if f.kind == "plane":       # the probe (along the tool's z) comes from the front (+n) side
                ok &= ChainKinematics(true_robot).frame_poses(Q)[0][:, :, 2] @ normals[k] < -PROBE_MIN_SIN
            if ok.sum() >= n_rows:
                Qs.append(Q[np.flatnonzero(ok)[:n_rows]])
                feat += [k] * n_rows
                n_planes += f.kind == "plane"
                break
            if f.kind == "plane":     # move the cube elsewhere
                corner = cand[rng.integers(len(cand))]
        else:
            raise DataError(f"{f.kind} {f.id!r}: reached from fewer than {n_rows} configurations "
                            f"after {max_tries} placements; ask for fewer rows")
    data = TouchData(np.concatenate(Qs), np.array(feat, int), features, probe_radius,
                     joint_names=true_robot.joint_names)
    return SimulatedTouch(data, truth.reshape(-1), refs, normals)
