"""The report of a touch calibration (:func:`calib.calibrate_touch`): each row's constraint
residual before and after, per feature, with the same plots and page as a pose calibration.

A row's residual is its RMS residual per component (:meth:`TouchProblem.row_residuals`: a point
row's ``|p - c| / sqrt(3)``, a plane or sphere row's distance to the surface), metres. "Before":
the nominal model with the features fitted to its tool points (the start of the fit, as the
printed "residual RMS ... before"); "after": the calibrated model with the identified features.
The rows the fit dropped as outliers are kept here and marked.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from calib.report.rows import PoseDeviations, ReportRows, error_stats, tolerance_verdict
from calib.calibration.touch import TouchResult
from calib.checks import check_instance
from calib.errors import ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import TouchData, initial_features

__all__ = ["touch_rows", "touch_certificate", "measured_deviations"]


def _row_residuals(model: RobotModel, data: TouchData, feature_values, plane_refs) -> np.ndarray:
    from calib.solvers.touch_problem import TouchProblem

    prob = TouchProblem(ChainKinematics(model), data, model.values, np.zeros(0, int), plane_refs, 1.0)
    return prob.row_residuals(prob.x0(feature_values))


def touch_rows(result: TouchResult, data: TouchData, nominal: RobotModel) -> ReportRows:
    """The :class:`ReportRows` of a touch calibration: every row of ``data`` (the rows the fit
    dropped included, marked as outliers), the residual before (``nominal``, features fitted to
    its tool points) and after (``result``), each stored as the x component of the deviation
    (metres; no rotation), and the tool point in the base frame."""
    check_instance(result, "result", TouchResult, "from calib.calibrate_touch")
    check_instance(data, "data", TouchData, "calib.read_touch")
    check_robot(nominal, "nominal")
    if len(result.feature_names) != 3 * len(data.features):
        raise ParameterError(f"result has {len(result.feature_names) // 3} features, data {len(data.features)}: "
                             f"give the data the calibration was run on")
    kin = ChainKinematics(nominal)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    before = _row_residuals(nominal, data, start.values, start.plane_refs)
    after = _row_residuals(result.robot, data, result.feature_values, result.plane_refs)
    N = data.n_rows
    dev = lambda r: PoseDeviations(np.column_stack([r, np.zeros(N), np.zeros(N)]), None)
    _, p_cal = ChainKinematics(result.robot).frame_poses(data.q)
    T = result.robot.T_meas_base()
    rows = np.asarray(data.rows, int)
    outlier = np.isin(rows, [row for row, _ in result.outliers])
    feature_ids = np.array([f"{data.features[k].kind} {data.features[k].id}" for k in data.feature])
    return ReportRows(np.full(N, "measurements"), rows, np.full(N, "cal"), feature_ids, np.asarray(data.q),
                      dev(before), dev(after), outlier, np.zeros(N, bool), (p_cal - T[:3, 3]) @ T[:3, :3],
                      "nominal model, features fitted to it", quantity="touch residual")


def measured_deviations(result: TouchResult, data: TouchData, nominal: RobotModel) -> dict | None:
    """The rows of ``data`` measured by an instrument (None without): their line numbers
    (``row``), outlier marks (``outlier``), and deviations ``before`` (the nominal model, its
    measurement frame registered to them by a best fit of the positions) and ``after`` (the
    calibrated model in the identified measurement frame), :class:`PoseDeviations` each."""
    from calib.calibration.accuracy import register_measurement_frame
    from calib.report.rows import pose_deviations

    check_instance(result, "result", TouchResult, "from calib.calibrate_touch")
    check_instance(data, "data", TouchData, "calib.read_touch")
    check_robot(nominal, "nominal")
    m = data.measured
    if m is None or not m.n_poses:
        return None
    rows = np.asarray(m.rows, int)
    return {"row": rows, "outlier": np.isin(rows, [row for row, _ in result.outliers]),
            "before": pose_deviations(register_measurement_frame(nominal, m), m),
            "after": pose_deviations(result.robot, m)}


def touch_certificate(rows: ReportRows, features: Sequence, tolerance_mm: float | None = None,
                      measured: dict | None = None) -> dict:
    """The figures of a touch report (JSON-ready, mm): accuracy groups (all rows before, the
    kept rows after, the outliers after), the per-feature table (rows, RMS before and after, max
    after), the outlier rows and the tolerance verdict over the kept rows. ``measured``
    (:func:`measured_deviations`): the rows measured by an instrument get their own accuracy
    groups (position error, and orientation when measured) and count in the outlier rows and
    the verdict (their position errors beside the touch residuals)."""
    kept = ~rows.outlier
    eb, ea = rows.before.position_errors * 1e3, rows.after.position_errors * 1e3
    groups = [("rows, before", "before", np.ones(rows.n_rows, bool)),
              ("rows, after" + (", without outliers" if rows.outlier.any() else ""), "after", kept)]
    if rows.outlier.any():
        groups.append(("outlier rows, after (left out of the fit)", "after", rows.outlier))
    touch_word = "touch rows" if measured is not None else "rows"
    accuracy = [{"label": label.replace("rows", touch_word, 1) if label.startswith("rows") else label,
                 "model": which, "n": int(m.sum()),
                 "position_mm": error_stats((eb if which == "before" else ea)[m]), "rotation_deg": None}
                for label, which, m in groups if m.any()]
    m_row = np.zeros(0, int)
    m_out = np.zeros(0, bool)
    m_after = np.zeros(0)
    if measured is not None:
        m_row, m_out = measured["row"], measured["outlier"]
        m_kept = ~m_out
        for label, which, sel in (("measured rows, before (measurement frame registered)", "before",
                                   np.ones(len(m_row), bool)),
                                  ("measured rows, after" + (", without outliers" if m_out.any() else ""),
                                   "after", m_kept),
                                  ("measured outlier rows, after (left out of the fit)", "after", m_out)):
            if sel.any():
                dev = measured[which]
                rot = dev.rotation_errors
                accuracy.append({"label": label, "model": which, "n": int(sel.sum()),
                                 "position_mm": error_stats(dev.position_errors[sel] * 1e3),
                                 "rotation_deg": None if rot is None else error_stats(np.degrees(rot[sel]))})
        m_after = measured["after"].position_errors
    table = []
    for f in features:
        m = rows.target == f"{f.kind} {f.id}"
        k = m & kept
        table.append({"kind": f.kind, "id": f.id, "rows": int(m.sum()), "outliers": int((m & rows.outlier).sum()),
                      "rms_before_mm": float(np.sqrt(np.mean(eb[m] ** 2))) if m.any() else None,
                      "rms_after_mm": float(np.sqrt(np.mean(ea[k] ** 2))) if k.any() else None,
                      "max_after_mm": float(ea[k].max()) if k.any() else None})
    out = {"before_label": rows.before_label, "headline_rows": "rows", "accuracy": accuracy,
           "per_axis": [], "iso9283": None, "drift": None, "features": table,
           "outlier_rows": sorted(int(r) for r in np.concatenate([rows.row[rows.outlier], m_row[m_out]])),
           "tolerance": None,
           "quantity": "touch residual (RMS per component: |p - c| / sqrt(3) for a point, the distance "
                       "to the surface for a plane or sphere)"}
    if tolerance_mm is not None:
        if isinstance(tolerance_mm, bool) or not isinstance(tolerance_mm, (int, float)) or \
                not math.isfinite(tolerance_mm) or tolerance_mm <= 0:
            raise ParameterError(f"tolerance_mm must be a positive number of millimetres, got {tolerance_mm!r:.60}")
        what = ("touch and measured rows" if measured is not None else "rows") + (
            " without the outliers" if rows.outlier.any() or m_out.any() else "")
        errors = np.concatenate([rows.after.position_errors[kept], m_after[~m_out]])
        out["tolerance"] = tolerance_verdict(tolerance_mm * 1e-3, errors, what)
        over = np.concatenate([rows.row[kept & (rows.after.position_errors > tolerance_mm * 1e-3)],
                               m_row[~m_out & (m_after > tolerance_mm * 1e-3)]])
        out["tolerance"]["rows_beyond"] = sorted(int(r) for r in over)[:100]
    return out
