"""The prepare stage (:class:`Setup`): calibration and validation rows, what is measured, duplicate and
implausible rows, the data-rank check, and the closed-form estimate of the measurement and tool
frames; plus what depends only on the robot model, kept for the next calibrations (reach).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import field, replace
from typing import Sequence

import numpy as np

from calib.dataclass_code import dataclass
from calib.calibration.accuracy import target_rows, with_measured_targets
from calib.calibration.frames import estimate_frames_robust
from calib.calibration.options import (
    DISTINCT_Q_TOL,
    FRAME_REBASE_M,
    FRAME_REBASE_RAD,
    TRACKER_RANGE_M,
    _check_compatible,
)
from calib.errors import DataError, ParameterError
from calib.model.identifiability import (
    content_digest,
    kept_weighted_jacobian,
    SIGMA_POS_M,
    SIGMA_ROT_RAD,
    select_identifiable,
    weighted_jacobian,
)
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.model.spatial import inverse, rotation_angle, zyx_transform


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
    needed).
    """

    nominal: RobotModel
    start: RobotModel
    cal: Measurements = field(repr=False)
    val: Measurements | None = field(repr=False)
    measure: str
    rebased: tuple[str, ...]
    suspect: np.ndarray | None = field(default=None, repr=False)
    kin: ChainKinematics | None = field(default=None, repr=False, compare=False)

    @property
    def components_per_pose(self) -> int:
        return 6 if self.measure == "pose" else 3


def prepare(robot: RobotModel, measurements: Measurements, validation: Measurements | None = None,
            init_frames: bool | str = "auto") -> tuple[Setup, list[str]]:
    """The prepare stage: rows, what is measured, closed-form frames (see the module docstring).
    Returns the :class:`Setup` and notes for the user. Data of several targets give the nominal
    model one flange->target transform per target (:func:`with_measured_targets`)."""
    _check_compatible(robot, measurements)
    robot = with_measured_targets(robot, measurements, validation)
    notes: list[str] = []
    cal = measurements.calibration()
    val = measurements.validation()
    if validation is not None:
        _check_compatible(robot, validation)
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


_DISTINCT_LAST: list = [None, 0]


def distinct_configurations(Q: np.ndarray, tol: float = DISTINCT_Q_TOL) -> int:
    """The number of distinct rows of Q (N, n) (rad / m), rows equal to ``tol`` counted once
    (the last answer kept by content: each candidate model of one calibration asks it)."""
    if len(Q) == 0:
        return 0
    Q = np.ascontiguousarray(Q, float)
    key = (Q.shape, hash(Q.tobytes()), tol)       # (as the torque cache keys its arrays)
    if _DISTINCT_LAST[0] == key:
        return _DISTINCT_LAST[1]
    _DISTINCT_LAST[:] = [key, _distinct(Q, tol)]
    return _DISTINCT_LAST[1]


def _distinct(Q: np.ndarray, tol: float) -> int:
    # rows sorted lexicographically, then the changes counted: np.unique(axis=0) without its
    # import of numpy.ma (20 ms of the CLI's start); + 0.0 makes -0.0 equal to 0.0
    K = np.round(np.asarray(Q, float).reshape(len(Q), -1) / tol) + 0.0
    S = K[np.lexsort(K.T[::-1])]
    return 1 + int(np.count_nonzero(np.any(S[1:] != S[:-1], axis=1)))


#: Results that depend only on the robot model (structure, values, frames, limits, gravity) and
#: options, kept for the next calibrations of the same model: see :func:`_robot_memo`.
_ROBOT_MEMO: OrderedDict = OrderedDict()
#: The most calibration rows whose closed-form frame estimate is kept (:func:`_frame_estimate`).
FRAME_MEMO_MAX_ROWS = 10_000


def _robot_key(robot: RobotModel) -> tuple:
    """What the results of :func:`_robot_memo` depend on: the model's structure, values, frames,
    limits and gravity (a digest); kept on the (immutable) model, so that asking again costs
    nothing (:meth:`RobotModel.with_values` makes a model without it)."""
    key = robot.__dict__.get("_memo_key")
    if key is None:
        from calib.model.identifiability import _cache_key

        limits = np.stack([robot.lower, robot.upper])
        key = _cache_key(robot, limits, "pose", 1.0, 1.0, 1.0, None, None)
        robot.__dict__["_memo_key"] = key
    return key


def _robot_memo(kind: str, robot: RobotModel, options: tuple, compute):
    """``compute()``, or its value from an earlier call with the same ``kind``, model and
    ``options`` (the last 64 kept)."""
    key = (kind, _robot_key(robot), options)
    if key in _ROBOT_MEMO:
        _ROBOT_MEMO.move_to_end(key)
        return _ROBOT_MEMO[key]
    value = _ROBOT_MEMO[key] = compute()
    while len(_ROBOT_MEMO) > 64:
        _ROBOT_MEMO.popitem(last=False)
    return value


def _reach(robot: RobotModel) -> float:
    """The farthest tool position from the meas frame's origin over 256 random configurations
    (seed 0), metres."""
    _, p = ChainKinematics(robot).frame_poses(robot.random_configurations(256, 0))
    return float(np.linalg.norm(p, axis=1).max())


def _check_plausible_positions(robot: RobotModel, m: Measurements) -> None:
    """Refuse positions no tracker could have measured of this robot: farther from the meas
    frame's origin than the robot's reach (the farthest tool position over random
    configurations, from the nominal meas frame) plus :data:`TRACKER_RANGE_M`."""
    reach = _robot_memo("reach", robot, (), lambda: _reach(robot))
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
    kept_d = _robot_memo("data rank", robot, options + (digest,), data_rank)

    # the targets these rows measure (a target measured only in validation rows is not calibrated:
    # its frame is not asked of the calibration rows)
    present = None if rows is None else tuple(sorted(set(int(t) for t in rows)))

    def random_rank():
        Qr = robot.random_configurations(50, 0)
        K = 1 if present is None else len(present)
        every = None if present is None else np.tile(np.array(present), len(Qr))
        Jr = weighted_jacobian(robot, np.repeat(Qr, K, axis=0), measure, sigma_pos, sigma_rot, every)[:, cols]
        return tuple(select_identifiable(Jr, range(len(cols)))[0])

    kept_r = _robot_memo("random rank", robot, options + (present,), random_rank)
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
    """:func:`estimate_frames_robust` of the rows of ``m``, kept by content (:func:`_robot_memo`).
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
    return _robot_memo("frames", geo, (content_digest(m.q, m.position, m.rotation, rows),),
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
