"""Which parameters touch rows determine, and the designs refused (issue 24; the fit is
:mod:`calib.calibration.touch`).

* :func:`check_touch_design` refuses designs that cannot calibrate anything useful, in one line
  naming what to add (a point touched from fewer than 4 configurations, a plane or a sphere
  from fewer than 4, planes alone whose normals do not span space).
* :func:`touch_identifiability` finds which parameters the rows determine, numerically, by the
  rank-revealing selection of :mod:`calib.model.identifiability` on the combined noise-weighted
  Jacobian of the robot's geometric parameters and the features' unknowns (and of the rows
  measured by an instrument in the same data), in the priority: features' unknowns first, then
  the robot's parameters in their order (Eq. 23) with the longest link length last. What touch
  data leave free then shows as relations: the meas frame's u (a rigid motion of the whole cell
  moves the features with it) unless measured rows fix it, the joint-1 parameters tied to it, a
  plane's offset against the parameters along its normal, and, with no sphere and no measured
  row (no known length), the scale, held by the longest length (its relative error, hence the
  scale's, is then the smallest); :func:`calib.calibration.touch.calibrate_touch` then refuses
  the full model unless told to hold the scale nominal.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from calib.calibration.parameters import idealised
from calib.checks import check_instance
from calib.errors import DataError, ParameterError
from calib.model.identifiability import RANK_TOL, no_effect, select_identifiable
from calib.model.identifiability_report import Relation
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import FeatureStart, TouchData, feature_parameter_names, initial_features
from calib.model.touch_simulate import reach_positions
from calib.solvers.touch_problem import TouchProblem

#: Default touch noise (metres per residual component): a good probe in a good nest.
SIGMA_TOUCH_M = 0.02e-3
#: Rows a feature needs at least (a point from 3 orientations, 3 points of a plane, locate the
#: feature and leave almost nothing to calibrate the robot).
MIN_ROWS = {"point": 4, "plane": 4, "sphere": 4}
PARAM_CHOICES = ("auto", "tool")
#: Measured rows mixed with touch rows: at least this many, not on one line, to locate the
#: instrument's frame (the fit starts it at their rigid registration).
MEAS_FRAME_MIN_ROWS = 3
#: What no length fixes the scale of, and what to add (the refusal and the identifiability output).
SCALE_ADVICE = ("add a sphere of known radius (a ball bar), rows measured by an instrument, or calibrate "
                "the tool only (params='tool'); or accept the nominal scale (nominal_scale=True, "
                "--nominal-scale: the accuracy then holds up to scale)")


@dataclass(frozen=True)
class TouchIdentifiability:
    """Which parameters touch rows determine (:func:`touch_identifiability`).

    robot_free : names of the identifiable robot parameters (in the robot's order);
    features : names of the features' unknowns (all identifiable: else the design is refused);
    unidentifiable : the robot parameters held at their nominal values, with the kept parameters
    (robot or feature) each is tied to; scale_free : True when no known length fixes the scale
    (no sphere rows, no measured rows), the scale then held by the longest length.
    measured : rows measured by an instrument among the data (they identify the meas frame and
    the scale).
    """

    robot_free: tuple[str, ...]
    features: tuple[str, ...]
    unidentifiable: tuple[Relation, ...]
    scale_free: bool
    measured: int = 0

    def to_dict(self) -> dict:
        """A JSON-ready dict (robot_free, features, held_nominal with tied partners, scale_free)."""
        return {"robot_free": list(self.robot_free), "features": list(self.features),
                "held_nominal": [{"name": r.parameter, "tied_to": [{"name": n, "coefficient": c}
                                                                   for n, c in r.partners],
                                  "reason": r.reason} for r in self.unidentifiable],
                "scale_free": self.scale_free, "measured_rows": self.measured}

    def format(self) -> str:
        lines = [f"identifiable robot parameters ({len(self.robot_free)}): {', '.join(self.robot_free)}",
                 f"feature unknowns ({len(self.features)}): {', '.join(self.features)}",
                 f"held nominal ({len(self.unidentifiable)}):"]
        lines += [f"  {r.describe()}" for r in self.unidentifiable]
        if self.measured:
            lines.append(f"{self.measured} rows measured by an instrument: they identify the meas frame and "
                         f"the scale")
        if self.scale_free:
            lines.append("no known length (no sphere rows, no measured rows): the scale is not determined "
                         "(held by the longest link length). calibrate refuses the full model: " + SCALE_ADVICE)
        return "\n".join(lines)


# ---------------------------------------------------------------- checks
def check_touch_design(data: TouchData, params: str = "auto") -> None:
    """Raise DataError (one line, naming what to add) for designs that cannot calibrate anything
    useful: a feature with fewer rows than MIN_ROWS; planes alone whose normals (estimated from
    the rows' nominal tool points, given as ``data``'s feature order) are checked in
    :func:`touch_identifiability`; ``params="tool"`` without a point touched from 4 or more
    configurations; measured rows (``data.measured``) fewer than MEAS_FRAME_MIN_ROWS or on one
    line (they cannot locate the instrument's frame)."""
    check_instance(data, "data", TouchData, "a calib.model.touch.TouchData")
    if data.n_measured:
        m = data.measured
        s = np.linalg.svd(m.position - m.position.mean(axis=0), compute_uv=False) if m.n_poses > 1 else [0.0, 0.0]
        if m.n_poses < MEAS_FRAME_MIN_ROWS or s[1] <= 1e-6 * max(s[0], 1e-300):
            raise DataError(f"the {m.n_poses} measured rows {'lie on one line and ' if m.n_poses >= MEAS_FRAME_MIN_ROWS else ''}"
                            f"cannot locate the instrument's frame: give at least {MEAS_FRAME_MIN_ROWS} "
                            f"measured rows not on one line, or none")
    for k, f in enumerate(data.features):
        n = len(data.rows_of(k))
        if n < MIN_ROWS[f.kind]:
            what = {"point": "orientations", "plane": "points", "sphere": "points"}[f.kind]
            raise DataError(f"{f.kind} {f.id!r} is touched in {n} rows: touch it from at least "
                            f"{MIN_ROWS[f.kind]} {what} (more rows, or more features)")
    if params == "tool" and not any(f.kind == "point" for f in data.features) and not data.n_measured:
        raise DataError("--params tool needs a point touched from 4 or more orientations; the rows "
                        "touch no point")


def _priority(robot: RobotModel, candidates: Sequence[int]) -> list[int]:
    """The robot's candidate parameters in their order, the longest nominal length last."""
    order = list(candidates)
    lengths = [k for k in order if robot.parameters[k].unit == "m" and robot.parameters[k].group == "joint"]
    if lengths:
        longest = max(lengths, key=lambda k: abs(robot.values[k]))
        order.remove(longest)
        order.append(longest)
    return order


def touch_identifiability(robot: RobotModel, data: TouchData, *, params: str = "auto",
                          sigma: float = SIGMA_TOUCH_M, sigma_pos: float | None = None,
                          sigma_rot: float | None = None, tol: float = RANK_TOL,
                          first: Sequence[str] = (), require_redundancy: bool = True) -> TouchIdentifiability:
    """Which robot parameters ``data`` determine with the features (see the module docstring),
    at ``robot``'s idealised values. params : "auto" (every geometric parameter a candidate) or
    "tool" (the flange->tool offset v_x, v_y, v_z only, the robot held nominal; with measured
    rows the meas frame's u too). sigma, sigma_pos, sigma_rot : the groups' noise, the weights
    of the stacked Jacobian (metres, metres, radians; None: calib's defaults). first : robot
    parameter names to keep before the others (after the features). Raises DataError
    naming what to add when a feature's unknowns or every robot parameter are undetermined, when
    planes alone have normals that do not span space, or (``require_redundancy``) when the rows
    give no more residual components than the unknowns they determine (the fit would pass
    through every row: no noise to estimate, nothing left to check it, the "noise estimate" and
    the prediction an assumption; one sphere from 15 rows, one point from 6 rows for the full
    model). Measured rows (``data.measured``)
    stack their pose Jacobian under the touch rows': they determine the meas frame and the
    scale."""
    check_robot(robot)
    check_touch_design(data, params)
    if params not in PARAM_CHOICES:
        raise ParameterError(f"params must be one of {', '.join(PARAM_CHOICES)} for touch data, got {params!r}")
    if data.q.shape[1] != robot.n_joints:
        raise DataError(f"touch rows have {data.q.shape[1]} joint values, the robot {robot.n_joints} joints")
    if robot.targets:
        raise ParameterError("touch data calibrate a robot with one tool point; this model has several "
                             f"targets ({', '.join(robot.targets)})")
    model = idealised(robot)
    if params == "tool":
        candidates = [model.index(n) for n in model.v_names()[:3]]
        if data.n_measured:     # (the instrument's frame is unknown: the measured rows need u)
            candidates = [k for k, p in enumerate(model.parameters) if p.name.startswith("u_")] + candidates
    else:
        candidates = [k for k, p in enumerate(model.parameters) if p.group != "compliance"]
    kin = ChainKinematics(model)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    if not data.n_measured:     # (measured rows determine the robot: one plane is located by its rows)
        _check_planes(data, start.plane_refs)
    data = consistent_rows(model, data, start)
    prob = TouchProblem(kin, data, model.values, candidates, start.plane_refs, sigma, sigma_pos, sigma_rot)
    J = prob.jacobian(prob.x0(start.values))
    mr = len(candidates)
    n_feat = J.shape[1] - mr
    ranked = _priority(model, candidates)
    lead = [k for k in model.indices(first) if k in ranked] if first else []
    ranked = lead + [k for k in ranked if k not in lead]
    order = list(range(mr, mr + n_feat)) + [candidates.index(k) for k in ranked]
    kept, dropped = select_identifiable(J, order, tol)
    fnames = feature_parameter_names(data.features)
    lost = [fnames[j - mr] for j in dropped if j >= mr]
    if lost:
        raise DataError(f"the rows cannot locate {', '.join(lost)}: touch each feature at configurations "
                        f"further apart (a plane at points not on one line)")
    robot_kept = sorted(j for j in kept if j < mr)
    if not robot_kept:
        raise DataError("the rows determine no robot parameter: add rows or features")
    if require_redundancy and J.shape[0] <= len(kept):
        raise DataError(f"the rows give {J.shape[0]} residual components for {len(kept)} unknowns "
                        f"({len(robot_kept)} robot parameters, {n_feat} of the features): the fit would pass "
                        f"through every row, with no noise to estimate and nothing to check it; add rows (a "
                        f"point row gives 3 components, a plane or sphere row 1) or another feature"
                        + (", or calibrate the tool only (--params tool)"
                           if params != "tool" and any(f.kind == "point" for f in data.features) else ""))
    norms = np.linalg.norm(J, axis=0)
    names = [model.names[k] for k in candidates] + list(fnames)
    relations = []
    for j in dropped:
        if no_effect(norms, j):
            relations.append(Relation(names[j], (), "no effect on the rows' tool points"))
            continue
        coef = np.linalg.lstsq(J[:, kept], J[:, j], rcond=None)[0]
        scale = norms[kept] / norms[j]
        partners = tuple((names[k], float(c)) for k, c, s in zip(kept, coef, scale) if abs(c * s) > 1e-4)
        relations.append(Relation(names[j], partners, "its effect equals that of the listed parameters"))
    # (the tool offset alone, the robot held nominal: the nominal lengths fix the scale)
    scale_free = params != "tool" and not any(f.kind == "sphere" for f in data.features) and not data.n_measured
    return TouchIdentifiability(tuple(names[j] for j in robot_kept), tuple(fnames), tuple(relations),
                                scale_free, data.n_measured)


def consistent_rows(model: RobotModel, data: TouchData, start: FeatureStart) -> TouchData:
    """``data`` with each row's configuration moved (by the robot's errors: a few mrad) so that
    ``model``'s tool point satisfies its constraint exactly, the features at ``start``: the
    projection of the tool point onto its feature, reached by damped least squares from the
    row's configuration. The ties of such data are exact (a rigid motion of the cell, the scale):
    at the rows as measured, whose tool points miss the features by the robot's errors, they
    hold only to that relative size (1e-3), above the rank tolerance. Rows that do not converge
    are left out (all of them kept when that would leave a feature without rows)."""
    prob = TouchProblem(ChainKinematics(model), data, model.values, np.zeros(0, int), start.plane_refs, 1.0)
    p = prob.kin.frame_poses(data.q)[1]
    F = start.values.reshape(-1, 3)
    target = p.copy()
    for k, f in enumerate(data.features):
        rows = data.rows_of(k)
        if f.kind == "point":
            target[rows] = F[k]
        elif f.kind == "plane":
            n = start.plane_refs[k][:, 2]
            target[rows] -= np.outer(p[rows] @ n - F[k, 2] - data.probe_radius, n)
        else:
            e = p[rows] - F[k]
            target[rows] = F[k] + f.radius * e / np.linalg.norm(e, axis=1)[:, None]
    Q, ok = reach_positions(model, target, starts=data.q, margin=0.0)   # (measured rows may touch a limit)
    moved = replace(data, q=np.where(ok[:, None], Q, data.q))
    if ok.all() or len(set(data.feature[ok].tolist())) < len(data.features):
        return moved
    return moved.subset(ok)


def _check_planes(data: TouchData, plane_refs: np.ndarray) -> None:
    """Planes alone must have normals spanning space: one plane (or parallel ones) leaves the
    tool free along it, two leave the line where they meet."""
    if any(f.kind != "plane" for f in data.features):
        return
    normals = plane_refs[:, :, 2]
    s = np.linalg.svd(normals, compute_uv=False)
    span = int(np.sum(s > 0.1 * s[0]))     # directions at more than ~6 degrees
    if span < 3:
        raise DataError(f"the planes' normals span {span} direction{'s' if span > 1 else ''}: add "
                        f"{'two planes' if span == 1 else 'a plane'} not parallel to the touched ones "
                        f"(three faces of a cube), or a point or a sphere")
