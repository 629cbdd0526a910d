"""The prepare stage (:class:`Setup`): calibration and validation rows, what is measured, duplicate and
implausible rows, the data-rank check, and the closed-form estimate of the measurement and tool
frames; plus what depends only on the robot model, kept for the next calibrations (reach).

Touch data (:class:`calib.model.touch.TouchData`: rows naming the point, plane or sphere the tool
touched, and rows measured by an instrument in the same data) are prepared by
:func:`prepare_touch`: the designs that cannot calibrate anything are refused naming what to add
(:func:`check_touch_design`), the meas frame is started at the rigid registration of the tool
positions onto the measured rows, and the features' unknowns at the nominal tool points
(:func:`calib.model.touch.initial_features`); the setup's residual blocks
(:meth:`Setup.blocks`) are then the measured rows' and the touch rows'.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.calibration.accuracy.errors import target_rows, with_measured_targets
from calib.calibration.frames import estimate_frames_robust
from calib.calibration.options import (
    DISTINCT_Q_TOL,
    FRAME_REBASE_M,
    FRAME_REBASE_RAD,
    TRACKER_RANGE_M,
    check_compatible,
)
from calib.errors import DataError, ParameterError
from calib.memo import Memo, content_digest
from calib.model.identifiability import (
    kept_weighted_jacobian,
    SIGMA_POS_M,
    SIGMA_ROT_RAD,
    select_identifiable,
    weighted_jacobian,
)
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements, is_touch_data
from calib.model.robot import RobotModel
from calib.model.spatial import best_fit_motion, inverse, rotation_angle, zyx_transform

if TYPE_CHECKING:       # (touch data load their module: a calibration of measurements does not)
    from calib.model.touch import FeatureStart, TouchData


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Setup:
    """The prepare stage: what the fit works on.

    nominal : the model calibration started from (with the measured targets); start : the same
    with its reference frames moved to the closed-form estimates (or ``nominal``); cal / val :
    calibration and validation rows (val None without any); measure : "pose" or "position";
    rebased : which of "measurement->base", "flange->tool" (or "flange-><id>" per target) were
    moved; suspect : (N,) bool over the calibration rows, those the closed-form frame estimate
    left out as gross (the fit starts without them and takes back those its model explains), or
    None; kin : ``start``'s kinematics (a scratch workspace the stages share; None: built when
    needed). Touch data (measure "touch", :func:`prepare_touch`): touch : the touch rows (their
    measured rows are ``cal``, or None without any); features : the features' start values and
    the planes' reference rotations at ``start``.
    """

    nominal: RobotModel
    start: RobotModel
    cal: Measurements = field(repr=False)
    val: Measurements | None = field(repr=False)
    measure: str
    rebased: tuple[str, ...]
    suspect: np.ndarray | None = field(default=None, repr=False)
    kin: ChainKinematics | None = field(default=None, repr=False, compare=False)
    touch: TouchData | None = field(default=None, repr=False)
    features: FeatureStart | None = field(default=None, repr=False)

    @property
    def components_per_pose(self) -> int:
        return 6 if self.measure == "pose" else 3

    @property
    def rows(self) -> np.ndarray:
        """(N,) the line numbers of the calibration rows in the order of the fit's problem (the
        measured rows, then the touch rows)."""
        if self.touch is None:
            return self.cal.rows
        return self.touch.rows if self.cal is None else np.concatenate([self.cal.rows, self.touch.rows])

    def blocks(self) -> list:
        """The residual blocks of the calibration rows of touch data (:mod:`calib.solvers.residuals`):
        the measured rows' (when there are some), then the touch rows'."""
        from calib.solvers.residuals.pose import MeasuredRows
        from calib.solvers.residuals.touch import TouchRows

        m = self.cal
        measured = [] if m is None else [MeasuredRows(m.q, m.position, m.rotation, m.rows)]
        return measured + [TouchRows(self.touch, self.features.plane_refs)]

    def block_problem(self, kin: ChainKinematics, free: np.ndarray, levels, loss: str = "linear",
                      loss_scale: float = 3.0):
        """The :class:`calib.solvers.blocks.BlockProblem` of the calibration rows of touch data at
        ``start``'s values, the robot parameters ``free`` (indices) free, weighted by ``levels``
        (sigma_pos m, sigma_rot rad, sigma_touch m); its x starts at
        ``(start.values[free], features.values)``."""
        from calib.solvers.blocks import BlockProblem

        return BlockProblem(kin, self.start.values, free, self.blocks(), *levels, loss, loss_scale)


def prepare(robot: RobotModel, measurements: Measurements, validation: Measurements | None = None,
            init_frames: bool | str = "auto") -> tuple[Setup, list[str]]:
    """The prepare stage: rows, what is measured, closed-form frames (see the module docstring).
    Returns the :class:`Setup` and notes for the user. Data of several targets give the nominal
    model one flange->target transform per target (:func:`with_measured_targets`). Touch data:
    :func:`prepare_touch`."""
    if is_touch_data(measurements):
        return prepare_touch(robot, measurements)
    check_compatible(robot, measurements)
    robot = with_measured_targets(robot, measurements, validation)
    notes: list[str] = []
    cal = measurements.calibration()
    val = measurements.validation()
    if validation is not None:
        check_compatible(robot, validation)
        if val is not None and val.n_poses:
            notes.append(f"the {val.n_poses} 'val' rows of the measurements are held out; the "
                         f"validation statistics use the separate validation set")
        val = validation
    val, uncalibrated = _calibrated_targets_only(cal, val)
    notes += uncalibrated
    if val is not None and val.n_poses == 0:
        val = None
    measure = "pose" if cal.has_orientation else "position"
    _check_plausible_positions(robot, measurements)
    if validation is not None:
        _check_plausible_positions(robot, validation)
    notes += _duplicate_row_notes(cal, val)
    start, rebased, suspect = robot, (), None
    kin = ChainKinematics(robot)
    if init_frames:
        start, rebased, suspect = _rebase_frames(robot, cal, notes, always=init_frames is True, kin=kin)
    _check_enough_rows(start, cal, measure, measurements.source)
    return Setup(robot, start, cal, val, measure, rebased, suspect,
                 kin if start is robot else ChainKinematics(start)), notes


def _calibrated_targets_only(cal: Measurements, val: Measurements | None) -> tuple[Measurements | None, list[str]]:
    """The validation rows without those of targets that have no calibration rows, and a note
    for each such target: its offset is never calibrated (it stays where the model puts it), so
    its rows would measure that, not the calibration (a target measured only in validation rows
    put 40.7 mm into a validation summary of 0.05 mm ones)."""
    if val is None or val.target is None or cal.target is None:
        return val, []
    have = set(cal.target_ids)
    missing = [t for t in val.target_ids if t not in have]
    if not missing:
        return val, []
    ids = np.asarray(val.target, dtype=object)
    out = np.isin(ids, missing)
    notes = [f"target {t}: no calibration rows, not calibrated (its offset stays the model's); its "
             f"{int(np.count_nonzero(ids == t))} validation row(s) are left out of the validation "
             f"summary" for t in missing]
    return val.subset(~out), notes


def _check_enough_rows(start: RobotModel, cal: Measurements, measure: str, source) -> None:
    """Refuse calibration rows that give fewer independent equations than the identifiable
    parameters of ``start`` (the model after the closed-form frames: several targets then sit
    where the data put them, not all at the nominal tool) need at random configurations. Each
    distinct (configuration, target) pair counts: three reflectors measured at one configuration
    give three points."""
    rows_per_pose = 6 if measure == "pose" else 3
    rows = target_rows(start, cal)
    distinct = distinct_measured_points(cal.q, rows)
    if distinct * rows_per_pose >= start.n_params:
        return
    from calib.model.identifiability_report import analyze_identifiability

    spread = _distinct_targets(start)
    needed = analyze_identifiability(spread, start.random_configurations(50, 0), measure=measure).rank
    if distinct * rows_per_pose >= needed:
        return
    where = f"{source}: " if source is not None else ""
    n_q = distinct_configurations(cal.q)
    if rows is None:
        what = (f"{cal.n_poses} calibration poses" if distinct == cal.n_poses else
                f"{cal.n_poses} calibration rows at {distinct} distinct configuration(s)")
        more = f"{-(-needed // rows_per_pose)} distinct poses"
    else:
        what = (f"{cal.n_poses} calibration rows at {n_q} distinct configuration(s) of "
                f"{len(set(rows.tolist()))} of the {start.n_targets} targets ({distinct} distinct "
                f"configuration-target pairs)")
        # the targets on one rigid tool give fewer independent equations than 3 each per
        # configuration (three points: the 6 of a pose, plus their 3 distances once): the
        # fewest random configurations whose rows of every target reach the rank
        n = -(-needed // (rows_per_pose * start.n_targets))
        while n < 50 and analyze_identifiability(spread, start.random_configurations(n, 0),
                                                 measure=measure).rank < needed:
            n += 1
        more = f"{n} distinct configurations with every target"
    raise DataError(f"{where}{what} give {distinct * rows_per_pose} "
                    f"{'' if distinct == cal.n_poses else 'independent '}equations, "
                    f"fewer than the {needed} identifiable parameters need; measure at least "
                    f"{more} (several times more for accuracy)")


def _distinct_targets(robot: RobotModel) -> RobotModel:
    """``robot``, or for several targets at one point (the nominal model's targets before the
    closed-form frames placed them) the same with them at distinct points 0.1 m apart, for
    counting what the targets identify: reflectors at one point identify only what one point
    does, real ones are apart."""
    if not robot.targets:
        return robot
    refs = robot.T_flange_target_refs.copy()
    if np.min(np.linalg.norm(refs[:, None, :3, 3] - refs[None, :, :3, 3], axis=2)
              + np.eye(len(refs))) > 1e-3:
        return robot
    refs[:, :3, 3] += 0.1 * np.random.default_rng(0).normal(size=(len(refs), 3))
    return replace(robot, T_flange_tool_ref=refs[0], T_flange_target_refs=refs)


def distinct_measured_points(Q: np.ndarray, targets: np.ndarray | None = None) -> int:
    """The number of distinct (configuration, target) pairs of rows at configurations Q (N, n)
    measuring targets (N,) (target indices; None: one target): distinct configurations for one
    target."""
    if targets is None:
        return distinct_configurations(Q)
    return distinct_configurations(np.column_stack([np.asarray(Q, float), np.asarray(targets, float)]))


def _earliest_equal_rows(*ms: Measurements) -> np.ndarray:
    """For the rows of ``ms`` one after the other, the index of the first row equal to each (its
    own index when none before it is): joint values, measured pose and target, bit for bit."""
    x = np.concatenate([m.position[:, 0] for m in ms]) + 0.0       # + 0.0: -0.0 equals 0.0
    first = np.arange(len(x))
    # equal rows have an equal measured x: only rows whose x recurs are compared in full (a
    # sort of all 19 columns takes 0.8 s on 200,000 rows)
    o = np.argsort(x, kind="stable")
    same_x = np.flatnonzero(x[o][1:] == x[o][:-1])
    cand = np.sort(np.concatenate([o[same_x], o[same_x + 1]]))
    cand = cand[np.concatenate([[True], cand[1:] != cand[:-1]])] if cand.size else cand   # (np.unique imports numpy.ma: 15 ms)
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


DISTINCT_LAST = Memo("distinct configurations", 1)


def distinct_configurations(Q: np.ndarray, tol: float = DISTINCT_Q_TOL) -> int:
    """The number of distinct rows of Q (N, n) (rad / m), rows equal to ``tol`` counted once
    (the last answer kept by content: each candidate model of one calibration asks it)."""
    if len(Q) == 0:
        return 0
    Q = np.ascontiguousarray(Q, float)
    key = (Q.shape, hash(Q.tobytes()), tol)       # (as the torque cache keys its arrays)
    if key in DISTINCT_LAST:
        return DISTINCT_LAST.get(key)
    return DISTINCT_LAST.put(key, _distinct(Q, tol))


def _distinct(Q: np.ndarray, tol: float) -> int:
    # rows sorted lexicographically, then the changes counted: np.unique(axis=0) without its
    # import of numpy.ma (20 ms of the CLI's start); + 0.0 makes -0.0 equal to 0.0
    K = np.round(np.asarray(Q, float).reshape(len(Q), -1) / tol) + 0.0
    S = K[np.lexsort(K.T[::-1])]
    return 1 + int(np.count_nonzero(np.any(S[1:] != S[:-1], axis=1)))


#: Results that depend only on the robot model (structure, values, frames, limits, gravity) and
#: options, kept for the next calibrations of the same model: see :func:`robot_memo`.
ROBOT_RESULTS = Memo("robot results", 64, lru=True)
#: The most calibration rows whose closed-form frame estimate is kept (:func:`_frame_estimate`).
FRAME_MEMO_MAX_ROWS = 10_000


def robot_memo(kind: str, robot: RobotModel, options: tuple, compute):
    """``compute()``, or its value from an earlier call with the same ``kind``, model (its
    :attr:`~calib.model.robot.RobotModel.content_key`: structure, values, frames, limits and
    gravity) and ``options`` (the last 64 kept)."""
    key = (kind, robot.content_key, options)
    if key in ROBOT_RESULTS:
        return ROBOT_RESULTS.get(key)
    return ROBOT_RESULTS.put(key, compute())


def robot_reach(robot: RobotModel) -> float:
    """The farthest tool position from the meas frame's origin over 256 random configurations
    (seed 0), metres."""
    _, p = ChainKinematics(robot).frame_poses(robot.random_configurations(256, 0))
    return float(np.linalg.norm(p, axis=1).max())


def reach_of(robot: RobotModel) -> float:
    """The robot's reach (:func:`robot_reach`), kept for the next calibrations of the same model."""
    return robot_memo("reach", robot, (), lambda: robot_reach(robot))


def _check_plausible_positions(robot: RobotModel, m: Measurements) -> None:
    """Refuse positions no tracker could have measured of this robot: farther from the meas
    frame's origin than the robot's reach (the farthest tool position over random
    configurations, from the nominal meas frame) plus :data:`TRACKER_RANGE_M`."""
    reach = robot_memo("reach", robot, (), lambda: robot_reach(robot))
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
    and targets (at most 500 rows, evenly spaced) against its rank at 50 random configurations
    within the joint limits, every target measured at each (several reflectors count by
    configuration and target together: three points identify what the pose they define does).
    ``free`` are the parameters to identify; ``derived`` (the set was chosen from these
    data: base, auto) compares all parameters, since a set chosen from degenerate data is
    degenerate too. A non-finite Jacobian is refused naming its parameters."""
    cols = list(range(robot.n_params)) if derived else list(robot.indices(free))
    rows = target_rows(robot, m)
    pick = slice(None) if len(m.q) <= 500 else np.linspace(0, len(m.q) - 1, 500).astype(int)
    Q = m.q[pick]
    rows = None if rows is None else rows[pick]
    options = (measure, float(sigma_pos), float(sigma_rot), tuple(cols))

    def data_rank():
        Jd = kept_weighted_jacobian(robot, Q, measure, sigma_pos, sigma_rot, rows)[:, cols]
        finite = np.isfinite(Jd).all(axis=0)
        if not finite.all():
            names = [robot.names[cols[k]] for k in np.flatnonzero(~finite)]
            raise DataError(f"{m.source or '<measurements>'}: the identification Jacobian is not finite "
                            f"for {', '.join(names)}")
        return tuple(select_identifiable(Jd, range(len(cols)))[0])

    # both ranks are kept per model (and data): a calibration repeated on the same data, e.g.
    # with another method, does not redo them
    digest = content_digest(np.asarray(Q, float), None if rows is None else np.asarray(rows, np.int64))
    kept_d = robot_memo("data rank", robot, options + (digest,), data_rank)

    # the targets these rows measure (a target measured only in validation rows is not calibrated:
    # its frame is not asked of the calibration rows)
    present = None if rows is None else tuple(sorted(set(int(t) for t in rows)))

    def random_rank():
        Qr = robot.random_configurations(50, 0)
        K = 1 if present is None else len(present)
        every = None if present is None else np.tile(np.array(present), len(Qr))
        Jr = weighted_jacobian(robot, np.repeat(Qr, K, axis=0), measure, sigma_pos, sigma_rot, every)[:, cols]
        return tuple(select_identifiable(Jr, range(len(cols)))[0])

    kept_r = robot_memo("random rank", robot, options + (present,), random_rank)
    if len(kept_d) < len(kept_r):
        lost = [robot.names[cols[k]] for k in kept_r if k not in set(kept_d)]
        n_q = distinct_configurations(m.q)
        where = (f"{n_q} distinct configurations" if rows is None else
                 f"{n_q} distinct configurations, {distinct_measured_points(m.q, target_rows(robot, m))} "
                 f"distinct configuration-target pairs of {robot.n_targets} targets")
        random = "random poses" if rows is None else "random poses of every target"
        raise DataError(f"{m.source or '<measurements>'}: the {m.n_poses} calibration rows ({where}) "
                        f"identify {len(kept_d)} parameter combinations, {random} "
                        f"{len(kept_r)}: the rows cannot identify {', '.join(lost)} (measure poses that "
                        f"move every joint over its range"
                        + (", or name the parameters to identify with params / --params)" if derived else ")"))


def _rebase_frames(robot: RobotModel, m: Measurements, notes: list, always: bool = False,
                   kin: ChainKinematics | None = None) -> tuple[RobotModel, tuple[str, ...], np.ndarray | None]:
    """Move the reference frames to closed-form estimates when the data put them far away
    (or ``always``; kin: ``robot``'s kinematics at its values, to reuse). Returns the model, the
    frames moved and the rows the robust estimate left out (bool mask, or None when none)."""
    try:
        est = _frame_estimate(robot, m, kin)
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
        ang = rotation_angle(dT)
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


def _frame_estimate(robot: RobotModel, m: Measurements, kin: ChainKinematics | None):
    """:func:`estimate_frames_robust` of the rows of ``m``, kept by content (:func:`robot_memo`).
    A model whose joint terms are all zero has its geometry's kinematics and the same estimate:
    the choice of joint terms prepares the geometric model, calibrate then the chosen one on the
    same rows (the 1,402 iiwa rows: one estimate instead of two). Kept up to
    FRAME_MEMO_MAX_ROWS rows (the choice of joint terms judges at most 10,000: more rows are not
    prepared twice, and their residuals would stay in memory)."""
    rows = target_rows(robot, m)
    if m.n_poses > FRAME_MEMO_MAX_ROWS:
        return estimate_frames_robust(robot, m.q, m.position, m.rotation, rows, kin=kin)
    geo = robot
    if robot.has_joint_terms:
        terms = np.concatenate([robot.compliances(), robot.periodic_values()])
        if not np.any(terms != 0.0):
            geo = robot.geometry()
    return robot_memo("frames", geo, (content_digest(m.q, m.position, m.rotation, rows),),
                       lambda: estimate_frames_robust(robot, m.q, m.position, m.rotation, rows, kin=kin))


def with_gravity_for(robot: RobotModel, compliance: bool, payload=None,
                     gravity: Sequence[float] | None = None) -> tuple[RobotModel, list[str]]:
    """``robot`` with the gravity load its compliance model sees during the measurements, and a
    note on it (:func:`calib.model.compliance.with_gravity`), when compliance is identified or the
    model has compliances; ``robot`` unchanged otherwise. payload : a
    :class:`calib.model.compliance.Payload`; gravity : (3,) m/s^2 in the URDF root frame (None:
    the model's, else the default)."""
    if not (compliance or payload is not None or gravity is not None):
        return robot, []
    from calib.model.compliance import with_gravity

    if not (compliance or robot.has_compliance):
        raise ParameterError("a payload or gravity only matters for joint compliance: pass compliance=True")
    robot = with_gravity(robot, payload=payload if payload is not None else
                         (robot.gravity.payload if robot.has_compliance else None),
                         gravity=gravity if gravity is not None else
                         (robot.gravity.gravity if robot.has_compliance else None))
    return robot, [robot.gravity.note] if robot.gravity.note else []


# ---------------------------------------------------------------- touch data
#: Rows a feature needs at least (a point from 3 orientations, 3 points of a plane, locate the
#: feature and leave almost nothing to calibrate the robot).
MIN_TOUCH_ROWS = {"point": 4, "plane": 4, "sphere": 4}
#: Measured rows mixed with touch rows: at least this many, not on one line, to locate the
#: instrument's frame (the fit starts it at their rigid registration).
MEAS_FRAME_MIN_ROWS = 3


def check_touch_design(data: TouchData) -> None:
    """Raise DataError (one line, naming what to add) for touch designs that cannot calibrate
    anything useful: a feature with fewer rows than MIN_TOUCH_ROWS; measured rows
    (``data.measured``) fewer than MEAS_FRAME_MIN_ROWS or on one line (they cannot locate the
    instrument's frame). (Planes whose normals do not span space, and the parameter set, are
    judged by :func:`calib.calibration.parameters.touch_identifiability`.)"""
    if data.n_measured:
        m = data.measured
        s = np.linalg.svd(m.position - m.position.mean(axis=0), compute_uv=False) if m.n_poses > 1 else [0.0, 0.0]
        if m.n_poses < MEAS_FRAME_MIN_ROWS or s[1] <= 1e-6 * max(s[0], 1e-300):
            raise DataError(f"the {m.n_poses} measured rows {'lie on one line and ' if m.n_poses >= MEAS_FRAME_MIN_ROWS else ''}"
                            f"cannot locate the instrument's frame: give at least {MEAS_FRAME_MIN_ROWS} "
                            f"measured rows not on one line, or none")
    for k, f in enumerate(data.features):
        n = len(data.rows_of(k))
        if n < MIN_TOUCH_ROWS[f.kind]:
            what = {"point": "orientations", "plane": "points", "sphere": "points"}[f.kind]
            raise DataError(f"{f.kind} {f.id!r} is touched in {n} rows: touch it from at least "
                            f"{MIN_TOUCH_ROWS[f.kind]} {what} (more rows, or more features)")


def prepare_touch(robot: RobotModel, data: TouchData) -> tuple[Setup, list[str]]:
    """The prepare stage of touch data: the design checked (:func:`check_touch_design`), the
    measured rows' positions checked as a tracker's (:func:`_check_plausible_positions`), the
    meas frame started at the best-fit rigid motion of the nominal tool positions onto the
    measured ones (the instrument stands anywhere: a fit started at the nominal meas frame would
    not converge; the reference transform moves, u keeps its value, as the closed-form frames of
    :func:`prepare` do), the features started at the start model's tool points. Returns the
    :class:`Setup` (measure "touch") and its notes."""
    from calib.model.touch import initial_features

    if robot.targets:
        raise ParameterError("touch data calibrate a robot with one tool point; this model has several "
                             f"targets ({', '.join(robot.targets)})")
    if data.q.shape[1] != robot.n_joints:
        raise DataError(f"touch rows have {data.q.shape[1]} joint values, the robot {robot.n_joints} joints")
    check_touch_design(data)
    m, start, notes = data.measured, robot, []
    if m is not None:
        check_compatible(robot, m)
        _check_plausible_positions(robot, m)
        R, t, _ = best_fit_motion(ChainKinematics(robot).frame_poses(m.q)[1], m.position)
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = R, t
        start = replace(robot, T_meas_base_ref=X @ robot.T_meas_base_ref)
        dT = inverse(robot.T_meas_base_ref) @ start.T_meas_base_ref
        notes.append(f"measurement->base initialised by a rigid registration onto the measured rows: "
                     f"{np.linalg.norm(dT[:3, 3]) * 1e3:.1f} mm and {rotation_angle(dT):.3g} rad "
                     f"from the nominal transform (u are relative to it)")
    touch = replace(data, measured=None)
    kin = ChainKinematics(start)
    R, p = kin.frame_poses(touch.q)
    features = initial_features(touch, p, R[:, :, 2])
    rebased = ("measurement->base",) if m is not None else ()
    return Setup(robot, start, m, None, "touch", rebased, None, kin, touch, features), notes
