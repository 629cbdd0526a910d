"""Pose errors of a model against measured poses (:class:`AccuracyStats`, :func:`evaluate`), their
table, the accuracy on each target's rows (:class:`TargetAccuracy`), the rows' targets, and the
best-fit registration of the measurement frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from calib.calibration.frames import project_to_so3
from calib.calibration.options import check_compatible
from calib.model.measurements import check_measurements
from calib.model.robot import check_robot
from calib.checks import check_array
from calib.errors import DataError, ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.model.spatial import log3_batch

# ====================================================================== accuracy
@dataclass(frozen=True, eq=False)     # (array fields: compared by identity; nothing compares them)
class AccuracyStats:
    """Pose errors of a model against measurements (or the truth).

    position_errors : (N,) metres, |p_model - p_measured|; rotation_errors : (N,) radians, the
    angle of R_model R_measured^T (None for position-only data). Statistics in the same units.
    """

    position_errors: np.ndarray = field(repr=False)
    rotation_errors: np.ndarray | None = field(repr=False)

    @staticmethod
    def from_residuals(dp: np.ndarray, dr: np.ndarray | None) -> "AccuracyStats":
        """The errors of position residuals dp (N, 3) metres and rotation residuals dr (N, 3)
        radians, the rotation vectors of R_model R_measured^T (None for position-only data)."""
        dp = check_array(dp, "dp", (None, 3), unit="metres")
        dr = None if dr is None else check_array(dr, "dr", (len(dp), 3), unit="radians")
        # (the row norms as np.linalg.norm makes them, sqrt of the summed squares, without its wrapper)
        return AccuracyStats(np.sqrt(np.add.reduce(dp * dp, axis=1)),
                             None if dr is None else np.sqrt(np.add.reduce(dr * dr, axis=1)))

    @property
    def n_poses(self) -> int:
        return len(self.position_errors)

    def subset(self, mask: np.ndarray) -> "AccuracyStats":
        """The errors of the rows selected by ``mask`` ((N,) bool or indices)."""
        n = len(self.position_errors)
        sel = np.asarray(mask) if isinstance(mask, (list, tuple, np.ndarray)) else None
        if sel is None or sel.ndim != 1 or not (sel.dtype == bool and len(sel) == n or sel.size == 0 or
                                                np.issubdtype(sel.dtype, np.integer) and
                                                ((sel >= -n) & (sel < n)).all()):
            raise ParameterError(f"mask must be ({n},) booleans or row indices in [0, {n}), got {mask!r:.60}")
        mask = sel.astype(int) if sel.size == 0 else sel
        return AccuracyStats(self.position_errors[mask],
                             None if self.rotation_errors is None else self.rotation_errors[mask])

    @staticmethod
    def _stats(e: np.ndarray | None) -> dict[str, float] | None:
        if e is None or len(e) == 0:
            return None
        # (the reductions np.mean, np.max and np.min make, without their wrappers: the same sums;
        # in float64 whatever the array's type, as np.mean of float64)
        e = np.asarray(e, float)
        n = len(e)
        return {"mean": float(np.add.reduce(e)) / n, "rms": math.sqrt(float(np.add.reduce(e * e)) / n),
                "max": float(np.maximum.reduce(e)), "min": float(np.minimum.reduce(e))}

    @property
    def position(self) -> dict[str, float] | None:
        """mean, rms, max, min of the position error, metres."""
        return self._stats(self.position_errors)

    @property
    def rotation(self) -> dict[str, float] | None:
        """mean, rms, max, min of the orientation error, radians (None if position only)."""
        return self._stats(self.rotation_errors)

    def to_dict(self) -> dict:
        """JSON-ready: position in mm, rotation in rad."""
        pos = self.position
        return {"n_poses": self.n_poses,
                "position_mm": None if pos is None else {k: v * 1e3 for k, v in pos.items()},
                "rotation_rad": self.rotation}




@dataclass(frozen=True, eq=False)     # (AccuracyStats fields, themselves compared by identity; nothing compares them)
class TargetAccuracy:
    """Accuracy on the rows of one target of a multi-target calibration (see
    :class:`AccuracyStats`): before / after on the calibration rows, and on the validation rows
    (None without validation data)."""

    target: str
    before: AccuracyStats = field(repr=False)
    after: AccuracyStats = field(repr=False)
    validation_before: AccuracyStats | None = field(default=None, repr=False)
    validation_after: AccuracyStats | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"before": self.before.to_dict(), "after": self.after.to_dict(),
                "validation": None if self.validation_after is None else {
                    "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()}}

def pose_errors(robot: RobotModel, Q: np.ndarray, position: np.ndarray,
                rotation: np.ndarray | None, kin: ChainKinematics | None = None,
                targets: np.ndarray | None = None) -> AccuracyStats:
    """Errors of ``robot``'s tool poses at Q (N, n) against positions (N, 3) m and rotations
    (targets: (N,) each row's target index for a multi-target model)."""
    kin = kin or ChainKinematics(robot)
    if kin.values is not robot.values:
        kin.set_values(robot.values)
    R, p = kin.frame_poses(Q, targets=targets)
    dr = None if rotation is None else log3_batch(R @ np.transpose(rotation, (0, 2, 1)))
    return AccuracyStats.from_residuals(p - position, dr)


def evaluate(robot: RobotModel, measurements: Measurements) -> AccuracyStats:
    """Accuracy of ``robot`` against all rows of ``measurements`` (tool pose in the meas frame).

    Rows of several targets are compared with the model's transform of their target; a model
    with one tool frame serves every target with it (:meth:`RobotModel.with_targets`).
    """
    check_robot(robot)
    check_measurements(measurements)
    check_compatible(robot, measurements)
    robot = with_measured_targets(robot, measurements)
    return pose_errors(robot, measurements.q, measurements.position, measurements.rotation,
                       targets=target_rows(robot, measurements))


def with_measured_targets(robot: RobotModel, *measurements: Measurements | None) -> RobotModel:
    """A one-tool-frame ``robot`` with the targets of the measurements (two or more ids: one
    flange->target transform each, starting at the model's tool transform); unchanged for data
    of one target and for a model that has targets already (:func:`target_rows` then refuses
    an id it does not know)."""
    ids = tuple(dict.fromkeys(t for m in measurements if m is not None for t in m.target_ids))
    if len(ids) < 2 or robot.targets:
        return robot
    return robot.with_targets(ids)


def target_rows(robot: RobotModel, m: Measurements) -> np.ndarray | None:
    """(N,) int: each row's target index in ``robot.targets`` (None for a one-tool-frame model);
    an unknown id is a :class:`DataError` naming the file and row."""
    if not robot.targets:
        return None
    where = f"{m.source}: " if m.source is not None else ""
    if m.target is None:
        raise DataError(f"{where}the model has {robot.n_targets} targets ({', '.join(robot.targets)}): "
                        f"the measurements need a target column")
    for row, t in zip(m.rows, m.target):
        if t not in robot.targets:
            raise DataError(f"{where}row {row}, column target: {t!r} is not a target of the model "
                            f"({', '.join(robot.targets)})")
    return robot.target_rows(m.target)


def format_accuracy_table(rows: Sequence[tuple[str, AccuracyStats]]) -> str:
    """Mean, RMS, max, min of position (mm) and orientation (rad) errors, one line per row."""
    head = (f"{'':<28}{'poses':>6} | {'position/mm':^40} | {'orientation/rad':^44}\n"
            f"{'':<28}{'':>6} | {'mean':>9}{'rms':>10}{'max':>10}{'min':>10}"
            f"  | {'mean':>10}{'rms':>11}{'max':>11}{'min':>11}")
    lines = [head]
    for label, s in rows:
        p = s.position
        if p is None:       # (no rows: a target measured only in the other set)
            lines.append(f"{label:<28}{0:>6} | {'(no rows)':>40}")
            continue
        line = f"{label:<28}{s.n_poses:>6} | " + "".join(f"{p[k] * 1e3:>10.4f}" for k in ("mean", "rms", "max", "min"))
        r = s.rotation
        line += "  | " + ("".join(f"{r[k]:>11.3e}" for k in ("mean", "rms", "max", "min")) if r else f"{'(position only)':>44}")
        lines.append(line)
    return "\n".join(lines)


# ---------------------------------------------------------------- before, registered
def register_measurement_frame(robot: RobotModel, measurements: Measurements) -> RobotModel:
    """``robot`` with its measurement frame moved by the rigid transform that best fits its tool
    positions to the measured ones (least squares over the positions only; the convention of
    tracker software for "before calibration" errors)."""
    return _registered(robot, measurements, target_rows(robot, measurements))[0]


def _registered(robot: RobotModel, measurements: Measurements, targets):
    """(the registered ``robot`` of :func:`register_measurement_frame`, its tool rotations
    (N, 3, 3) and positions (N, 3) at the measured rows): the registration moves the poses the fit
    was made on, so their errors need no other pass over the rows."""
    R_nom, p_nom = ChainKinematics(robot).frame_poses(measurements.q, targets=targets)
    c_nom, c_meas = p_nom.mean(axis=0), measurements.position.mean(axis=0)
    # the rotation R minimising sum |a_i - R b_i|^2: the one closest to sum a_i b_i^T (Kabsch;
    # scipy's Rotation.align_vectors, whose import costs 0.4 s)
    T = np.eye(4)
    T[:3, :3] = project_to_so3((measurements.position - c_meas).T @ (p_nom - c_nom))
    T[:3, 3] = c_meas - T[:3, :3] @ c_nom
    return (replace(robot, T_meas_base_ref=T @ robot.T_meas_base_ref), T[:3, :3] @ R_nom,
            p_nom @ T[:3, :3].T + T[:3, 3])


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class BeforeAfter:
    """Accuracy of a calibration on its rows (see :class:`AccuracyStats`): ``before`` (the nominal
    model) and ``after`` (the calibrated one) on the calibration rows, ``validation_before`` /
    ``validation_after`` on the validation rows (None without any), the ``*_registered`` errors of
    the nominal model with its measurement frame registered by a best fit (None unless the frames
    were estimated), per ``targets`` of a multi-target model; cal_rows / val_rows: (N,) each row's
    target index (None for one tool frame). Made by :func:`accuracy_before`, completed by
    :func:`accuracy_after`."""

    before: AccuracyStats
    validation_before: AccuracyStats | None = None
    before_registered: AccuracyStats | None = None
    validation_before_registered: AccuracyStats | None = None
    cal_rows: np.ndarray | None = field(default=None, repr=False)
    val_rows: np.ndarray | None = field(default=None, repr=False)
    after: AccuracyStats | None = None
    validation_after: AccuracyStats | None = None
    #: the nominal model those ``*_registered`` errors are of (None unless the frames were estimated)
    registered: RobotModel | None = field(default=None, repr=False)
    targets: tuple[TargetAccuracy, ...] = ()


def accuracy_before(nominal: RobotModel, start: RobotModel, cal: Measurements, val: Measurements | None, *,
                    rebased: Sequence[str], kin: ChainKinematics | None = None) -> BeforeAfter:
    """The errors before calibration: of ``nominal`` (with the measured targets) on the
    calibration rows ``cal`` and validation rows ``val``, and, when the frames were estimated
    (``rebased``, see :class:`calib.calibration.prepare.Setup`), of the nominal geometry with the
    tool or targets where the closed-form estimate on ``start`` put them when it moved them (an
    SMR's unknown offset is not an error of the robot) and the measurement frame registered by a
    best fit. kin : a kinematics workspace of ``nominal``'s structure."""
    cal_rows = target_rows(nominal, cal)
    before = pose_errors(nominal, cal.q, cal.position, cal.rotation, kin, cal_rows)
    vb = val_rows = None
    if val is not None:
        val_rows = target_rows(nominal, val)
        vb = pose_errors(nominal, val.q, val.position, val.rotation, kin, val_rows)
    breg = vbreg = registered = None
    if rebased:
        ref = nominal if tuple(rebased) == ("measurement->base",) else replace(
            nominal, T_flange_tool_ref=start.T_flange_tool_ref, T_flange_target_refs=start.T_flange_target_refs)
        registered, R, p = _registered(ref, cal, cal_rows)
        dr = None if cal.rotation is None else log3_batch(R @ np.transpose(cal.rotation, (0, 2, 1)))
        breg = AccuracyStats.from_residuals(p - cal.position, dr)
        if val is not None:
            vbreg = pose_errors(registered, val.q, val.position, val.rotation, targets=val_rows)
    return BeforeAfter(before, vb, breg, vbreg, cal_rows, val_rows, registered=registered)


def accuracy_after(before: BeforeAfter, calibrated: RobotModel, after: AccuracyStats, val: Measurements | None,
                   targets: Sequence[str], kin: ChainKinematics | None = None) -> BeforeAfter:
    """``before`` completed with the errors of the ``calibrated`` model: ``after`` on the
    calibration rows (the fit's), on the validation rows ``val``, and per target (``targets``:
    the model's target ids)."""
    va = None
    if val is not None:
        va = pose_errors(calibrated, val.q, val.position, val.rotation, kin, before.val_rows)
    per_target = tuple(
        TargetAccuracy(t, before.before.subset(before.cal_rows == k), after.subset(before.cal_rows == k),
                       None if val is None else before.validation_before.subset(before.val_rows == k),
                       None if val is None else va.subset(before.val_rows == k))
        for k, t in enumerate(targets))
    return replace(before, after=after, validation_after=va, targets=per_target)


# ---------------------------------------------------------------- registered (touch data)
#: The registrations of tool positions: "rigid", "similarity" (and scale), "none" (as they are).
REGISTRATIONS = ("rigid", "similarity", "none")


def registered_residuals(p: np.ndarray, p_ref: np.ndarray, registration: str = "rigid") -> np.ndarray:
    """(N, 3) what is left of p - p_ref (both (N, 3) metres) after the best-fit rigid motion
    (``"similarity"``: and scale; ``"none"``: nothing) of p onto p_ref (Kabsch / Umeyama). Touch
    data without measured rows leave the base frame nominal (a rigid motion of the cell is not
    seen) and, without a known length, the scale: what a robot located by touching its work needs
    is its tool positions up to that motion."""
    from calib.model.spatial import best_fit_motion

    if registration not in REGISTRATIONS:
        raise ParameterError(f"registration must be one of {', '.join(REGISTRATIONS)}, got {registration!r}")
    if registration == "none":
        return p - p_ref
    R, t, scale = best_fit_motion(p, p_ref, registration)
    return scale * p @ R.T + t - p_ref


def registered_error(model: RobotModel, truth: RobotModel, Q: np.ndarray, registration: str = "rigid") -> float:
    """RMS distance (metres) between ``model``'s and ``truth``'s tool positions at Q (N, n) after
    one best-fit rigid (or similarity) registration of the former onto the latter."""
    p = ChainKinematics(model).frame_poses(Q)[1]
    p_ref = ChainKinematics(truth).frame_poses(Q)[1]
    return float(np.sqrt(np.mean(np.sum(registered_residuals(p, p_ref, registration) ** 2, axis=1))))
