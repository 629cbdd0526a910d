"""The report of a calibration from touch data (a :class:`calib.CalibrationResult` whose
``features`` are set): its JSON (:func:`touch_report`), each row's constraint residual before and
after, per feature, with the same plots and page as a pose calibration (:func:`touch_rows`,
:func:`touch_certificate`), and the measured rows' deviations (:func:`measured_deviations`).

A row's residual is its RMS residual per component (a point row's ``|p - c| / sqrt(3)``, a plane
or sphere row's distance to the surface), metres. "Before": the nominal model with the features
fitted to its tool points (the start of the fit); "after": the calibrated model with the
identified features. The rows the fit dropped as outliers are kept here and marked.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from calib.calibration.result import CalibrationResult
from calib.checks import check_instance
from calib.errors import ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import TouchData, initial_features
from calib.report.rows import PoseDeviations, ReportRows, error_stats, tolerance_verdict

__all__ = ["touch_report", "touch_rows", "touch_certificate", "measured_deviations"]


def _check(result, data, nominal) -> None:
    check_instance(result, "result", CalibrationResult, "from calib.calibrate")
    check_instance(data, "data", TouchData, "calib.read_touch")
    check_robot(nominal, "nominal")
    if result.features is None:
        raise ParameterError("result is not a calibration from touch data (it has no features)")
    if len(result.features.features) != len(data.features):
        raise ParameterError(f"result has {len(result.features.features)} features, data {len(data.features)}: "
                             f"give the data the calibration was run on")


def row_residuals(model: RobotModel, data: TouchData, feature_values, plane_refs) -> np.ndarray:
    """(N,) metres: each touch row's RMS residual per component with ``model`` and the features'
    unknowns ``feature_values`` (3 K,), in the order of the rows."""
    from calib.solvers.residuals.touch import TouchRows

    block = TouchRows(data, plane_refs)
    R, p = ChainKinematics(model).frame_poses(data.q)
    r = block.evaluate(R, p, None, feature_values)[0]
    row = block.layout()[1]
    return np.sqrt(np.bincount(row, weights=r * r, minlength=data.n_rows) / np.bincount(row, minlength=data.n_rows))


def touch_rows(result: CalibrationResult, data: TouchData, nominal: RobotModel) -> ReportRows:
    """The :class:`ReportRows` of a touch calibration: every touch row of ``data`` (the rows the
    fit dropped included, marked as outliers), the residual before (``nominal``, features fitted
    to its tool points) and after (``result``), each stored as the x component of the deviation
    (metres; no rotation), and the tool point in the base frame."""
    _check(result, data, nominal)
    data = replace(data, measured=None)
    R, p = ChainKinematics(nominal).frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    before = row_residuals(nominal, data, start.values, start.plane_refs)
    after = row_residuals(result.robot, data, result.features.values, result.features.plane_refs)
    N = data.n_rows
    dev = lambda r: PoseDeviations(np.column_stack([r, np.zeros(N), np.zeros(N)]), None)   # noqa: E731
    _, p_cal = ChainKinematics(result.robot).frame_poses(data.q)
    T = result.robot.T_meas_base()
    rows = np.asarray(data.rows, int)
    outlier = np.isin(rows, [o.row for o in result.outliers])
    feature_ids = np.array([f"{data.features[k].kind} {data.features[k].id}" for k in data.feature])
    return ReportRows(np.full(N, "measurements"), rows, np.full(N, "cal"), feature_ids, np.asarray(data.q),
                      dev(before), dev(after), outlier, np.zeros(N, bool), (p_cal - T[:3, 3]) @ T[:3, :3],
                      "nominal model, features fitted to it", quantity="touch residual")


def measured_deviations(result: CalibrationResult, data: TouchData, nominal: RobotModel) -> dict | None:
    """The rows of ``data`` measured by an instrument (None without): their line numbers
    (``row``), outlier marks (``outlier``), and deviations ``before`` (the nominal model, its
    measurement frame registered to them by a best fit of the positions) and ``after`` (the
    calibrated model in the identified measurement frame), :class:`PoseDeviations` each."""
    from calib.calibration.accuracy.errors import register_measurement_frame
    from calib.report.rows import pose_deviations

    _check(result, data, nominal)
    m = data.measured
    if m is None or not m.n_poses:
        return None
    rows = np.asarray(m.rows, int)
    return {"row": rows, "outlier": np.isin(rows, [o.row for o in result.outliers]),
            "before": pose_deviations(register_measurement_frame(nominal, m), m),
            "after": pose_deviations(result.robot, m)}


def touch_report(result: CalibrationResult, command_line: Sequence[str]) -> dict:
    """The JSON report of a calibration from touch data (mm, rad; a parameter's value and std in
    SI units as in :class:`calib.CalibrationResult`): its status, rows, the touch group's
    residuals and noise, cross-validation, the robot parameters fitted, the features, the held
    nominal parameters, the outliers, each residual group, the predicted tool errors, and the
    whole result's own dict under ``result``."""
    check_instance(result, "result", CalibrationResult, "from calib.calibrate")
    if result.features is None:
        raise ParameterError("result is not a calibration from touch data (it has no features)")
    touch, measured = result.group("touch"), result.group("position")
    cv, std = result.cross_validation, result.std
    extra = result.touch_dict()
    ident = result.identifiability
    return {
        "kind": "touch", "status": result.status, "message": result.message, "command_line": list(command_line),
        "rows": touch.rows, "residual_components": sum(g.components for g in result.groups),
        "residual_rms_mm": {"before": touch.rms_before * 1e3, "after": touch.rms_after * 1e3},
        "noise_mm": {"used": touch.sigma * 1e3, "given": touch.given, "estimated": touch.estimated * 1e3},
        "cross_validation": None if cv is None else {"folds": cv.folds, "held_out_rms_mm": touch.cv_rms * 1e3},
        "parameters": [{"name": n, "value": float(result.robot.value(n)), "std": float(s)}
                       for n, s in zip(result.free, std)],
        "features": extra["features"], "plane_normals": extra["plane_normals"],
        "held_nominal": [] if ident is None else [r.describe() for r in ident.unidentifiable],
        "outliers": [{"row": o.row, "residual_mm": o.position_error * 1e3, "sigmas": o.sigmas}
                     for o in result.outliers],
        "scale_free": bool(ident is not None and ident.scale_free), "nominal_scale": result.nominal_scale,
        "measured_rows": 0 if measured is None else measured.rows, "notes": list(result.notes),
        "groups": extra["groups"], "predicted_tool_error_mm": extra["predicted_tool_error_mm"],
        "predicted_tool_error_registration": extra["registration"],
        "predicted_tool_error_meas_frame_mm": extra["predicted_tool_error_meas_frame_mm"],
        "nominal_expected_error_mm": extra["nominal_expected_error_mm"],
        "measurement_frame": None if result.measurement_frame is None else result.measurement_frame.to_dict(),
        "result": result.to_dict(),
    }


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
