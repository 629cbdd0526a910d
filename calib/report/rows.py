"""The per-row content of a report: each measured row's deviation before and after calibration,
its outlier flag and where it lies in the workspace, and the figures a certificate gives of them
(per-axis statistics, ISO 9283 pose accuracy and repeatability, a tolerance verdict).

"Before" is the nominal model as the text report's ``before, frame registered`` line measures it
when the frames were estimated (a tracker's pose, a reflector's offset are not errors of the
robot): the measurement frame registered by a best fit of the tool positions, with the tool or
target frames at their closed-form estimates when those were moved; the nominal model itself
otherwise. "After" is the calibrated model; its headline figures leave out the rows the fit
flagged as outliers (they are marked, not hidden).

ISO 9283 (Manipulating industrial robots - Performance criteria), clauses 7.2.1 and 7.2.3, with
the calibrated model's pose as the command pose: for a pose visited n times, with the attained
positions x_i (measured) and their barycentre x_bar, the pose accuracy AP_p = |x_bar - x_c|
(x_c the commanded position) and the repeatability RP_l = l_bar + 3 S_l, l_i = |x_i - x_bar|,
S_l = sqrt(sum (l_i - l_bar)^2 / (n - 1)); orientation: AP_a,b,c = mean angle - commanded angle
and RP_a,b,c = 3 S per axis, the angles taken as the components of the small rotation vector of
R_measured R_model^T about the meas frame's x, y, z axes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Mapping

import numpy as np

from calib.model.measurements import TEXT_COLUMNS, Measurements

if TYPE_CHECKING:     # Pinocchio is imported where the kinematics run: the plots' worker process
    from calib.model.robot import RobotModel     # (calib.cli.plot_worker) unpickles ReportRows without it

__all__ = ["PoseDeviations", "pose_deviations", "ReportRows", "report_rows", "axis_table", "iso9283", "error_stats",
           "tolerance_verdict", "repeated_groups", "drift_columns"]

_DEG = 180.0 / math.pi


@dataclass(frozen=True)
class PoseDeviations:
    """Per-pose deviations of a model's tool pose from measured ones, in the meas frame.

    position : (N, 3) float, metres: p_model - p_measured.
    rotation : (N, 3) float, radians: rotation vector of R_model R_measured^T, or None for
        position-only data.
    """

    position: np.ndarray
    rotation: np.ndarray | None

    @property
    def position_errors(self) -> np.ndarray:
        """(N,) metres: the length of each position deviation."""
        return np.linalg.norm(self.position, axis=1)

    @property
    def rotation_errors(self) -> np.ndarray | None:
        """(N,) radians: the rotation angle of each orientation deviation."""
        return None if self.rotation is None else np.linalg.norm(self.rotation, axis=1)


def pose_deviations(robot: RobotModel, measurements: Measurements) -> PoseDeviations:
    """Deviations of ``robot``'s tool poses from ``measurements`` (both in the meas frame; rows
    of several targets against the model's transform of their target)."""
    from calib.calibration.accuracy.errors import target_rows, with_measured_targets
    from calib.model.kinematics import ChainKinematics
    from calib.model.spatial import log3_batch

    robot = with_measured_targets(robot, measurements)
    R, p = ChainKinematics(robot).frame_poses(measurements.q, targets=target_rows(robot, measurements))
    rot = None
    if measurements.rotation is not None:
        rot = log3_batch(R @ np.transpose(measurements.rotation, (0, 2, 1)))
    return PoseDeviations(p - measurements.position, rot)


@dataclass(frozen=True, eq=False)
class ReportRows:
    """The rows of a report in the order of the files: the measurement file's rows in file order,
    then the validation file's.

    file : (N,) str, ``"measurements"`` or ``"validation"``; row : (N,) int, line numbers in that
    file; sets : (N,) str, ``"cal"`` / ``"val"`` (a validation file's rows are ``"val"``); target :
    (N,) str ids or None; q : (N, n) joint values (rad / m).
    before : deviations of the reference model (see the module docstring; None for a report of
    one model), after : of the calibrated (or evaluated) model, both in the meas frame, metres and
    radians. outlier : (N,) bool, the rows the fit flagged. validation : (N,) bool, the rows the
    calibration's validation statistics are of. point_base : (N, 3) metres, the measured point in
    the robot's base frame (by the model of ``after``). before_label : what "before" is.
    columns : the files' per-row columns (:attr:`Measurements.columns`: ``time_s``,
    ``temperature_c`` as (N,) float, NaN where a file has none; ``pose_id`` and ``name`` (N,)
    str, "" where a file has none). quantity : what ``position_errors`` measure, for the plots ("position
    error"; "touch residual" for touch rows, whose deviation is the residual along x).
    """

    file: np.ndarray
    row: np.ndarray
    sets: np.ndarray
    target: np.ndarray | None
    q: np.ndarray
    before: PoseDeviations | None
    after: PoseDeviations
    outlier: np.ndarray
    validation: np.ndarray
    point_base: np.ndarray
    before_label: str = "nominal model"
    columns: Mapping = field(default_factory=dict)
    quantity: str = "position error"

    @property
    def n_rows(self) -> int:
        return len(self.row)

    @property
    def has_rotation(self) -> bool:
        return self.after.rotation is not None

    @property
    def calibration(self) -> np.ndarray:
        """(N,) bool: the rows the model was identified from (outliers included)."""
        return ~self.validation & (self.file == "measurements") & (self.sets == "cal")

    @property
    def reach(self) -> np.ndarray:
        """(N,) metres: distance of the measured point from the origin of the base frame."""
        return np.linalg.norm(self.point_base, axis=1)

    def x_label(self) -> str:
        return "file row" if not (self.file == "validation").any() else \
            "file row (measurement file; validation file rows marked apart)"


def report_rows(model: RobotModel, measurements: Measurements, validation: Measurements | None = None, *,
                reference: RobotModel | None = None, reference_label: str = "nominal model",
                outlier_rows=(), validation_rows: str = "auto") -> ReportRows:
    """The :class:`ReportRows` of ``model`` (and ``reference``, the "before" model, or None)
    against ``measurements`` and ``validation`` (both in the meas frame). outlier_rows : line
    numbers of the measurement file's rows flagged as outliers. validation_rows : which rows the
    validation statistics are of: ``"auto"`` the validation file's when given, else the
    measurement file's ``val`` rows (as :func:`calib.calibrate` takes them)."""
    parts = [("measurements", measurements)] + ([("validation", validation)] if validation is not None
                                                 and validation.n_poses else [])
    files, rows, sets, targets, qs, after, before = [], [], [], [], [], [], []
    for role, m in parts:
        files.append(np.full(m.n_poses, role, dtype=object))
        rows.append(np.asarray(m.rows, int))
        sets.append(np.asarray(m.sets, dtype=object) if m.sets is not None
                    else np.full(m.n_poses, "cal" if role == "measurements" else "val", dtype=object))
        targets.append(None if m.target is None else np.asarray(m.target, dtype=object))
        qs.append(np.asarray(m.q))
        after.append(pose_deviations(model, m))
        if reference is not None:
            before.append(pose_deviations(reference, m))
    file = np.concatenate(files).astype(str)
    s = np.concatenate(sets).astype(str)
    has_val_file = len(parts) > 1
    if validation_rows == "auto":
        val = (file == "validation") if has_val_file else (s == "val")
    else:
        val = np.zeros(len(file), bool)
    row = np.concatenate(rows)
    outlier = (file == "measurements") & np.isin(row, np.asarray(list(outlier_rows), int))
    target = None
    if any(t is not None for t in targets):
        target = np.concatenate([t if t is not None else np.full(len(r), "", dtype=object)
                                 for t, r in zip(targets, rows)]).astype(str)
    dev_after = _concat(after)
    position = np.concatenate([m.position for _, m in parts])
    T = model.T_meas_base()
    point_base = (position - T[:3, 3]) @ T[:3, :3]
    columns = {}
    for name in dict.fromkeys(k for _, m in parts for k in (m.columns or {})):
        pid = name in TEXT_COLUMNS
        columns[name] = np.concatenate([
            np.asarray(m.columns[name], object if pid else float) if m.columns and name in m.columns
            else np.full(m.n_poses, "" if pid else np.nan, dtype=object if pid else float) for _, m in parts])
    return ReportRows(file, row, s, target, np.concatenate(qs), _concat(before) if before else None,
                      dev_after, outlier, val, point_base, reference_label, columns)


def _concat(devs) -> PoseDeviations:
    rot = None if any(d.rotation is None for d in devs) else np.concatenate([d.rotation for d in devs])
    return PoseDeviations(np.concatenate([d.position for d in devs]), rot)


# ====================================================================== figures
def error_stats(e: np.ndarray) -> dict | None:
    """mean, rms, max, min and the 95th percentile of errors ``e`` (None for no rows)."""
    if e is None or not len(e):
        return None
    return {"n": int(len(e)), "mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e ** 2))),
            "p95": float(np.percentile(e, 95)), "max": float(e.max()), "min": float(e.min())}


def axis_table(dev: PoseDeviations, mask: np.ndarray) -> dict:
    """Per axis of the meas frame, over the rows of ``mask``: mean, standard deviation and largest
    magnitude of the position deviation (x, y, z, mm) and of the rotation vector (rx, ry, rz,
    degrees). Returns ``{axis: {"mean", "std", "max_abs"}}``."""
    out = {}
    comps = [("x", dev.position, 1e3), ("y", dev.position, 1e3), ("z", dev.position, 1e3)]
    if dev.rotation is not None:
        comps += [("rx", dev.rotation, _DEG), ("ry", dev.rotation, _DEG), ("rz", dev.rotation, _DEG)]
    for k, (name, arr, scale) in enumerate(comps):
        v = arr[mask, k % 3] * scale
        if not len(v):
            continue
        out[name] = {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
                     "max_abs": float(np.abs(v).max())}
    return out


def repeated_groups(rows: ReportRows) -> np.ndarray:
    """(N,) int: the group of each row, rows of one file with the same target and the same
    ``pose_id`` (when the file has that column) or else equal joint values (to 1e-9 rad or m)
    sharing one; -1 for rows visited once."""
    N = rows.n_rows
    pose_id = rows.columns.get("pose_id")
    if pose_id is not None and (pose_id != "").all():
        keys = [np.unique(np.asarray(pose_id, str), return_inverse=True)[1]]
    else:
        keys = list(np.round(rows.q, 9).T)
    keys += [np.unique(rows.file, return_inverse=True)[1]]
    if rows.target is not None:
        keys.append(np.unique(rows.target, return_inverse=True)[1])
    order = np.lexsort(keys[::-1])
    stacked = np.column_stack([k[order] for k in keys])
    new = np.ones(N, bool)
    new[1:] = (np.diff(stacked, axis=0) != 0).any(axis=1)
    gid_sorted = np.cumsum(new) - 1
    gid = np.empty(N, int)
    gid[order] = gid_sorted
    counts = np.bincount(gid)
    return np.where(counts[gid] >= 2, gid, -1)


def iso9283(rows: ReportRows, dev: PoseDeviations, groups: np.ndarray, keep: np.ndarray) -> dict | None:
    """ISO 9283 pose accuracy and repeatability (module docstring) of each pose visited at least
    twice among the rows of ``keep``, from the deviations ``dev`` (model minus measured); None when
    no pose is. Returns ``{"poses": [{"pose_id", "first_row", "target", "visits", "ap_p_mm", "rp_l_mm",
    "ap_deg": [a, b, c], "rp_deg": [a, b, c]}...], "ap_p_max_mm", "rp_l_max_mm", ...}``; ``pose_id``
    is the file's id of the pose (its ``pose_id`` column; None without one), ``first_row`` the file
    row of its first visit."""
    g = np.where(keep, groups, -1)
    counts = np.bincount(g[g >= 0]) if (g >= 0).any() else np.zeros(0, int)
    first = {}
    for i, k in enumerate(g.tolist()):          # the poses in the order of their first visit
        if k >= 0 and counts[k] >= 2 and k not in first:
            first[k] = i
    if not first:
        return None
    poses = []
    members = {k: np.flatnonzero(g == k) for k in first} if len(first) <= 1000 else None
    order = np.argsort(g, kind="stable")
    starts = np.searchsorted(g[order], list(first))
    pose_id = rows.columns.get("pose_id")
    for j, k in enumerate(first):
        idx = members[k] if members is not None else order[starts[j]:starts[j] + counts[k]]
        d = -dev.position[idx] * 1e3                 # attained - commanded, mm
        bar = d.mean(axis=0)
        ap = float(np.linalg.norm(bar))
        l = np.linalg.norm(d - bar, axis=1)
        s_l = float(np.sqrt(np.sum((l - l.mean()) ** 2) / (len(l) - 1)))
        rec = {"pose_id": (str(pose_id[idx[0]]) or None) if pose_id is not None else None,
               "first_row": int(rows.row[idx[0]]), "file": str(rows.file[idx[0]]),
               "target": None if rows.target is None else str(rows.target[idx[0]]),
               "visits": int(len(idx)), "ap_p_mm": ap, "rp_l_mm": float(l.mean() + 3 * s_l),
               "ap_mm": bar.tolist()}
        if dev.rotation is not None:
            a = -dev.rotation[idx] * _DEG
            rec["ap_deg"] = a.mean(axis=0).tolist()
            rec["rp_deg"] = (3 * a.std(axis=0, ddof=1)).tolist()
        poses.append(rec)
    out = {"poses": poses, "n_poses": len(poses), "visits": int(sum(p["visits"] for p in poses)),
           "ap_p_max_mm": max(p["ap_p_mm"] for p in poses), "rp_l_max_mm": max(p["rp_l_mm"] for p in poses),
           "ap_p_mean_mm": float(np.mean([p["ap_p_mm"] for p in poses])),
           "rp_l_mean_mm": float(np.mean([p["rp_l_mm"] for p in poses]))}
    if dev.rotation is not None:
        out["rp_deg_max"] = np.max([p["rp_deg"] for p in poses], axis=0).tolist()
        out["ap_deg_max_abs"] = np.max(np.abs([p["ap_deg"] for p in poses]), axis=0).tolist()
    return out


def tolerance_verdict(tolerance_m: float, errors: np.ndarray, what: str) -> dict:
    """Pass (every error of ``errors``, metres, within ``tolerance_m``) or fail, with the count
    beyond and the largest error; ``what`` names the rows judged."""
    e = np.asarray(errors, float)
    over = int((e > tolerance_m).sum())
    return {"tolerance_mm": tolerance_m * 1e3, "rows": what, "n": int(len(e)),
            "max_mm": float(e.max()) * 1e3 if len(e) else None, "beyond": over,
            "pass": bool(len(e) and over == 0)}


def drift_columns(rows: ReportRows) -> dict:
    """The rows' time and temperature columns that hold at least three values and vary:
    name -> (N,) float (NaN where unknown)."""
    out = {}
    for name in ("time_s", "temperature_c"):
        v = rows.columns.get(name)
        if v is not None and np.isfinite(v).sum() >= 3 and np.nanmax(v) > np.nanmin(v):
            out[name] = np.asarray(v, float)
    return out
