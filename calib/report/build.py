"""The report of a calibration (or of one model's accuracy): its JSON, plots and HTML page.

:func:`report_rows_of` computes the per-row content once (:mod:`calib.report.rows`:
each row's deviation before and after, outliers, workspace position); :func:`build_report` makes
the JSON report (schema :data:`SCHEMA_VERSION`): the result's own dictionary plus provenance,
frames, identity fields (``meta``), the certificate figures (headline accuracy with the registered
"before" and the without-outliers "after", per-axis table, ISO 9283 AP / RP when rows repeat a
configuration, tolerance verdict), the covariance of the free parameters and the per-row
residuals as columns (inline, or in a CSV beside the JSON: :func:`residuals_csv_text`);
:func:`render_plots` draws the plots (:mod:`calib.report.plots`) and
:func:`render_html` one self-contained HTML page of a report (:mod:`calib.report.html`,
a Jinja2 template). :func:`build_accuracy_report` is the same report for ``calib evaluate``: one
model against measurements, no calibration.
"""
from __future__ import annotations

import datetime
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from calib.report.identity import certificate_identity, check_fields
from calib.report.plots import PLOT_FILES, plot_rows
from calib.report.rows import (PoseDeviations, ReportRows, axis_table, drift_columns, error_stats, iso9283,
                                           pose_deviations, repeated_groups, report_rows,
                                           tolerance_verdict)
from calib.calibration.result import CalibrationResult
from calib.checks import check_instance
from calib.errors import ParameterError
from calib.model.measurements import Measurements, check_measurements
from calib.model.robot import RobotModel, check_robot

__all__ = ["PoseDeviations", "SCHEMA_VERSION", "PLOT_FILES", "build_report", "build_accuracy_report",
           "file_provenance", "provenance_of", "pose_deviations", "render_html", "render_plots", "report_rows_of",
           "residuals_csv_text", "residuals_csv_chunks", "report_json_text", "INLINE_RESIDUALS_MAX",
           "RESIDUAL_COLUMNS", "check_meta"]

#: Above this many rows the per-row residuals go to a CSV beside the JSON report by default.
INLINE_RESIDUALS_MAX = 20_000
_DEG = 180.0 / math.pi


def report_rows_of(result: CalibrationResult, measurements: Measurements,
                   validation: Measurements | None = None) -> ReportRows:
    """The per-row content of a calibration's report (:class:`ReportRows`): "before" the nominal
    model registered as the text report's ``before, frame registered`` line (when the frames were
    estimated; the nominal model otherwise), "after" the calibrated model, the rows the fit
    flagged marked. ``measurements`` and ``validation`` are the arguments :func:`calib.calibrate`
    was given."""
    check_instance(result, "result", CalibrationResult, "from calib.calibrate")
    check_measurements(measurements)
    check_measurements(validation, "validation", allow_none=True)
    reference, label = result.nominal, "nominal model"
    if result.nominal_registered is not None:
        reference = result.nominal_registered
        label = "nominal model, frames registered"
    return report_rows(result.robot, measurements, validation, reference=reference, reference_label=label,
                       outlier_rows={int(o.row) for o in result.outliers})


def render_plots(result: CalibrationResult, measurements: Measurements,
                 validation: Measurements | None = None, *, rows: ReportRows | None = None,
                 tolerance_mm: float | None = None, columns: Mapping | None = None,
                 progress=None) -> dict[str, bytes]:
    """PNG images of the calibration's pose errors, by file name (:data:`PLOT_FILES`; see
    :mod:`calib.report.plots`): per file row before and after, histograms, the error
    over the workspace, and the drift against ``columns`` (name with unit -> (N,) values per
    row, e.g. ``time_s``) when given.

    ``result``, ``measurements``, ``validation``: what :func:`calib.calibrate` was given and
    returned; ``rows``: :func:`report_rows_of` of them when already computed. Nothing is written:
    the caller decides where the images go.
    """
    rows = rows if rows is not None else report_rows_of(result, measurements, validation)
    return plot_rows(rows, tolerance_m=None if tolerance_mm is None else tolerance_mm * 1e-3,
                     columns=columns, progress=progress)


# ====================================================================== JSON report
#: Version of the JSON report's layout; raised when a key changes meaning or disappears.
SCHEMA_VERSION = 3


def file_provenance(path: str | Path) -> dict:
    """``{"path", "sha256", "bytes", "modified"}`` of an input file (path as given, resolved to
    absolute; ``modified``: its modification time, ISO 8601 UTC to the second)."""
    path = Path(path)
    mtime = datetime.datetime.fromtimestamp(path.stat().st_mtime, datetime.timezone.utc)
    digest, size = hashlib.sha256(), 0
    with open(path, "rb") as fh:          # in blocks: a million-row file is 250 MB
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
            size += len(block)
    return {"path": str(path.resolve()), "sha256": digest.hexdigest(), "bytes": size,
            "modified": mtime.isoformat(timespec="seconds").replace("+00:00", "Z")}


def _calib_version() -> str:
    from calib import __version__

    return __version__


#: The per-row residual columns of a report, with their units (JSON and CSV alike).
RESIDUAL_COLUMNS = ("file", "row", "name", "set", "target", "outlier", "pose_id", "time_s", "temperature_c", "dx_mm", "dy_mm", "dz_mm", "position_error_mm",
                    "position_error_before_mm", "rx_rad", "ry_rad", "rz_rad", "rotation_error_rad",
                    "rotation_error_before_rad")


def _residual_columns(rows: ReportRows) -> dict[str, np.ndarray]:
    """The per-row residuals as columns (see :data:`RESIDUAL_COLUMNS`); position deviations
    p_model - p_measured in mm (rounded to 1 nm), rotation vectors of R_model R_measured^T in rad
    (to 1e-9 rad), in the meas frame; a column without data is left out."""
    cols: dict[str, np.ndarray] = {"file": rows.file, "row": rows.row}
    if "name" in rows.columns:
        cols["name"] = rows.columns["name"]
    cols["set"] = rows.sets
    if rows.target is not None:
        cols["target"] = rows.target
    cols["outlier"] = rows.outlier
    for name in ("pose_id", "time_s", "temperature_c"):
        if name in rows.columns:
            cols[name] = rows.columns[name] if name == "pose_id" else _rounded(rows.columns[name], 6)
    dp = rows.after.position * 1e3
    for k, axis in enumerate("xyz"):
        cols[f"d{axis}_mm"] = _rounded(dp[:, k], 6)
    cols["position_error_mm"] = _rounded(rows.after.position_errors * 1e3, 6)
    if rows.before is not None:
        cols["position_error_before_mm"] = _rounded(rows.before.position_errors * 1e3, 6)
    if rows.has_rotation:
        for k, axis in enumerate("xyz"):
            cols[f"r{axis}_rad"] = _rounded(rows.after.rotation[:, k], 9)
        cols["rotation_error_rad"] = _rounded(rows.after.rotation_errors, 9)
        if rows.before is not None and rows.before.rotation is not None:
            cols["rotation_error_before_rad"] = _rounded(rows.before.rotation_errors, 9)
    return cols


def _rounded(values: np.ndarray, decimals: int) -> np.ndarray:
    """``values`` rounded, with no negative zero (-0.0 + 0.0 is +0.0: a -1e-12 mm deviation is
    written 0, not -0)."""
    return np.round(values, decimals) + 0.0


def residuals_csv_text(rows: ReportRows) -> str:
    """The per-row residuals of a report as CSV text (one row per measured row, the columns of
    :data:`RESIDUAL_COLUMNS` that have data; units in the column names)."""
    return b"".join(residuals_csv_chunks(rows)).decode("utf-8")


#: Rows formatted at once by :func:`residuals_csv_chunks` (bounds the Python objects alive).
_CSV_CHUNK_ROWS = 20_000


def residuals_csv_chunks(rows: ReportRows) -> list[bytes]:
    """:func:`residuals_csv_text` as UTF-8 bytes in chunks of rows (to be written in order):
    only the file's bytes and one chunk's Python objects are held at once (a million rows
    formatted in one piece held 0.7 GB of them)."""
    cols = _residual_columns(rows)
    names = list(cols)
    fmt = ",".join("%d" if n in ("row", "outlier") else "%s" if cols[n].dtype.kind in "OUS" else "%.9g"
                   for n in names) + "\n"
    values = [cols[n].astype(int) if n == "outlier" else cols[n] for n in names]
    # text cells (file, set, target, pose_id) as cells no spreadsheet runs as a formula, quoted
    # where they hold a comma or a quote (calib.io.csv.cells); their distinct values once each
    from calib.io.csv.cells import csv_field

    for k, n in enumerate(names):
        if cols[n].dtype.kind in "OUS":
            col = cols[n].tolist()
            safe = {t: csv_field(str(t)) for t in set(col)}
            if any(safe[t] != t for t in safe):
                values[k] = np.array([safe[t] for t in col], dtype=object)
    out = [("# per-row residuals of a calib report: p_model - p_measured (mm) and the rotation vector of "
            "R_model R_measured^T (rad) in the meas frame\n" + ",".join(names) + "\n").encode("utf-8")]
    for s in range(0, rows.n_rows, _CSV_CHUNK_ROWS):
        part = zip(*[v[s:s + _CSV_CHUNK_ROWS].tolist() for v in values])
        out.append("".join(fmt % t for t in part).encode("utf-8"))
    return out


def _covariance_dict(result: CalibrationResult) -> dict:
    names = list(result.free)
    from calib.units import DISPLAY_UNITS

    edge = [DISPLAY_UNITS[result.robot.parameters[result.robot.index(n)].unit] for n in names]
    units = [u for u, _ in edge]
    scale = np.array([f for _, f in edge])
    cov = np.asarray(result.covariance, float) * np.outer(scale, scale)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    return {"parameters": names, "units": units,
            "std": std.tolist(),
            "covariance": cov.tolist(),
            "correlation": [[float(v) if math.isfinite(v) else None for v in row] for row in corr],
            "note": "covariance in the parameters' units (mm, rad, urad/(N m); products for mixed entries)"}


def _group_stats(dev: PoseDeviations | None, mask: np.ndarray) -> dict | None:
    if dev is None or not mask.any():
        return None
    rot = dev.rotation_errors
    return {"n": int(mask.sum()), "position_mm": error_stats(dev.position_errors[mask] * 1e3),
            "rotation_deg": None if rot is None else error_stats(rot[mask] * _DEG)}


def _certificate(rows: ReportRows, tolerance_mm: float | None, *, calibration: bool) -> dict:
    """The figures of the certificate (JSON-ready): headline accuracy groups, per-axis tables,
    ISO 9283, tolerance verdict (see :mod:`calib.report.rows`)."""
    kept = ~rows.outlier
    groups = []
    if calibration:
        cal = rows.calibration
        val = rows.validation
        groups += [("calibration rows, before", "before", cal),
                   ("calibration rows, after" + (", without outliers" if rows.outlier.any() else ""),
                    "after", cal & kept)]
        if rows.outlier.any():
            groups.append(("outlier rows, after (left out of the fit)", "after", rows.outlier))
        if val.any():
            groups += [("validation rows, before", "before", val), ("validation rows, after", "after", val)]
    else:
        groups.append(("all rows", "after", np.ones(rows.n_rows, bool)))
        for name, s in (("calibration rows (cal)", "cal"), ("validation rows (val)", "val")):
            if (rows.sets == s).any() and not (rows.sets == s).all():
                groups.append((name, "after", rows.sets == s))
    accuracy = []
    per_axis = []
    for label, which, mask in groups:
        dev = rows.before if which == "before" else rows.after
        st = _group_stats(dev, mask)
        if st is None:
            continue
        accuracy.append({"label": label, "model": which, **st})
        if not label.startswith("outlier"):
            per_axis.append({"label": label, "model": which, "axes": axis_table(dev, mask)})
    # the rows a verdict and the headline "after" are of: held-out rows when there are some; a
    # calibration without them has fit residuals only, which no verdict rests on
    if calibration and rows.validation.any():
        judged, what, basis = rows.validation, "validation rows (held out)", "held-out rows"
    elif calibration:
        judged, what = rows.calibration & kept, ("calibration rows without the outliers" if rows.outlier.any()
                                                 else "calibration rows")
        basis = "fit residuals"
    else:
        judged, what, basis = np.ones(rows.n_rows, bool), "all rows", "evaluated rows"
    groups_id = repeated_groups(rows)
    iso = iso9283(rows, rows.after, groups_id, kept)
    if iso is not None and rows.before is not None:
        iso_b = iso9283(rows, rows.before, groups_id, kept)
        iso["before"] = {k: iso_b[k] for k in ("ap_p_max_mm", "ap_p_mean_mm", "rp_l_max_mm", "rp_l_mean_mm")}
    drift = {}
    for name, v in drift_columns(rows).items():
        ok = kept & np.isfinite(v)
        e = rows.after.position_errors[ok] * 1e3
        slope = float(np.polyfit(v[ok], e, 1)[0])
        drift[name] = {"n": int(ok.sum()), "range": [float(v[ok].min()), float(v[ok].max())],
                       "slope_mm_per_unit": slope, "change_mm": slope * float(np.ptp(v[ok])),
                       "correlation": float(np.corrcoef(v[ok], e)[0, 1]) if np.ptp(e) > 0 else 0.0}
    out = {"before_label": rows.before_label if rows.before is not None else None,
           "headline_rows": what, "basis": basis, "accuracy": accuracy, "per_axis": per_axis, "iso9283": iso,
           "drift": drift or None,
           "outlier_rows": [int(r) for r in rows.row[rows.outlier]],
           "tolerance": None}
    if tolerance_mm is not None:
        out["tolerance"] = tolerance_verdict(tolerance_mm * 1e-3, rows.after.position_errors[judged], what)
        over = judged & (rows.after.position_errors > tolerance_mm * 1e-3)
        out["tolerance"]["rows_beyond"] = [int(r) for r in rows.row[over][:100]]
        out["tolerance"].update(_verdict_basis(out["tolerance"], basis))
    return out


#: Why a calibration without held-out rows gets no verdict (the report's words).
NO_VERDICT = ("no verification rows (--validate VAL.csv, or rows with set=val): the rows are fit residuals, "
              "the model's distance to the very rows it was fitted to, which understate its error on new "
              "rows and cannot carry a verdict")


def _verdict_basis(tolerance: Mapping, basis: str) -> dict:
    """The verdict of a tolerance comparison: ``"PASS"`` / ``"FAIL"`` on held-out or evaluated
    rows; on fit residuals none (``pass`` and ``verdict`` None, ``reason`` :data:`NO_VERDICT`):
    the comparison stays in the report as information."""
    if basis == "fit residuals":
        return {"basis": basis, "pass": None, "verdict": None, "reason": NO_VERDICT}
    return {"basis": basis, "verdict": "PASS" if tolerance["pass"] else "FAIL", "reason": None}


def _check_common(command_line, inputs, outputs, frames, meta, tolerance_mm, residuals) -> None:
    if not isinstance(command_line, (list, tuple)) or \
            not all(isinstance(a, (str, os.PathLike)) for a in command_line):
        raise ParameterError(f"command_line must be a list of arguments (strings), got {command_line!r:.60}")
    for name, paths in (("inputs", inputs), ("outputs", outputs)):
        if paths is not None and not (isinstance(paths, Mapping) and all(
                isinstance(role, str) and (p is None or isinstance(p, (str, os.PathLike))) for role, p in paths.items())):
            raise ParameterError(f"{name} must map each role (a string) to a file path, got {paths!r:.60}")
    if frames is not None and not (isinstance(frames, Mapping) and all(isinstance(k, str) for k in frames)):
        raise ParameterError(f"frames must be a mapping of names to values, got {frames!r:.60}")
    check_meta(meta)
    if tolerance_mm is not None and (isinstance(tolerance_mm, bool) or not isinstance(tolerance_mm, (int, float))
                                     or not math.isfinite(tolerance_mm) or tolerance_mm <= 0):
        raise ParameterError(f"tolerance_mm must be a positive number of millimetres, got {tolerance_mm!r:.60}")
    if not (isinstance(residuals, str) and residuals in ("json", "none", "auto")
            or isinstance(residuals, (str, os.PathLike)) and os.fspath(residuals).endswith(".csv")):
        raise ParameterError(f"residuals must be 'json', 'none', 'auto' or the path of a CSV file (.csv), "
                             f"got {residuals!r:.60}")


def check_meta(meta) -> dict:
    """``meta`` (identity fields of a report: name -> text or number, e.g. robot_serial,
    instrument, operator; the fields :mod:`calib.report.identity` reads checked as it
    reads them: dates ISO 8601) checked; returns it as a dict of strings."""
    if meta is None:
        return {}
    if not isinstance(meta, Mapping) or not all(
            isinstance(k, str) and k.strip() and isinstance(v, (str, int, float)) and not isinstance(v, bool)
            for k, v in meta.items()):
        raise ParameterError(f"meta must map field names to text or numbers (robot_serial=..., "
                             f"instrument=..., operator=...), got {meta!r:.80}")
    out = {k.strip(): str(v) for k, v in meta.items()}
    check_fields(out)
    return out


def provenance_of(command_line, inputs, outputs) -> dict:
    """Where a report comes from: calib's version, the command line, the date, each input file's
    digest and each output's path."""
    return {
        "calib_version": _calib_version(),
        "command_line": [os.fspath(a) for a in command_line],
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "inputs": {role: file_provenance(path) for role, path in (inputs or {}).items()
                   if path is not None},
        "outputs": {role: str(path) for role, path in (outputs or {}).items() if path is not None},
    }


def _residuals_entry(rows: ReportRows, residuals) -> dict | None:
    if residuals == "auto":
        residuals = "json"
    if residuals == "none":
        return None
    if residuals == "json":
        return {"layout": "columns", "n_rows": rows.n_rows,
                "columns": {k: v.tolist() for k, v in _residual_columns(rows).items()}}
    return {"layout": "csv", "n_rows": rows.n_rows, "csv": os.fspath(residuals),
            "columns": list(_residual_columns(rows))}


def build_report(result: CalibrationResult, measurements: Measurements,
                 validation: Measurements | None = None, *, command_line: Sequence[str] = (),
                 inputs: Mapping[str, str | Path] | None = None, frames: Mapping | None = None,
                 outputs: Mapping[str, str | Path] | None = None, meta: Mapping | None = None,
                 tolerance_mm: float | None = None, residuals: str | Path = "auto",
                 rows: ReportRows | None = None) -> dict:
    """The JSON report of a calibration: ``result.to_dict()`` plus

    * ``schema_version`` (:data:`SCHEMA_VERSION`);
    * ``provenance``: calib version, ``command_line`` (list of arguments), UTC date, and path,
      sha256 and size of every file in ``inputs`` (role -> path, e.g. ``{"robot": ...,
      "measurements": ...}``), and ``outputs`` (role -> path) as given;
    * ``meta``: the identity fields given (robot_serial, instrument, operator, ...: text);
    * ``frames``: base and tool frame and chain joints of the model, plus ``frames`` given by the
      caller (e.g. the frames recorded in the written URDF, under ``"written_urdf"``);
    * ``certificate``: the accuracy groups (calibration rows before, with the nominal model's
      frames registered when they were estimated, and after without the outliers; the outliers;
      validation rows), mm and degrees; the per-axis table (x, y, z mm; rx, ry, rz deg); ISO 9283
      AP / RP when rows repeat a configuration (None otherwise); the outlier rows; the verdict
      against ``tolerance_mm`` (positive, millimetres; None without): every position error of
      the validation rows (of the calibration rows without the outliers when there are none)
      within it;
    * ``residuals``: the per-row residuals as columns (:data:`RESIDUAL_COLUMNS`: file role,
      1-based file row, set, target, outlier flag, p_model - p_measured in mm in the meas frame,
      its length after and before, the rotation vector of R_model R_measured^T in rad and its
      angle); ``residuals="json"`` inline, ``"none"`` left out, a ``.csv`` path: only that path
      and the column names (the caller writes :func:`residuals_csv_text` there), ``"auto"``
      inline (the CLI sends more than :data:`INLINE_RESIDUALS_MAX` rows to a CSV);
    * ``covariance``: names, units, standard deviations, covariance and correlation of the free
      parameters (mm and rad).

    ``measurements`` and ``validation`` are the arguments :func:`calib.calibrate` was given;
    ``rows`` their :func:`report_rows_of` when already computed.
    """
    check_instance(result, "result", CalibrationResult, "from calib.calibrate")
    if result.features is not None:
        raise ParameterError("result is a calibration from touch data: its report is "
                             "calib.report.touch.touch_report (and touch_certificate)")
    check_measurements(measurements)
    check_measurements(validation, "validation", allow_none=True)
    _check_common(command_line, inputs, outputs, frames, meta, tolerance_mm, residuals)
    rows = check_instance(rows, "rows", ReportRows, "from report_rows_of", allow_none=True) \
        or report_rows_of(result, measurements, validation)
    report = {"schema_version": SCHEMA_VERSION, "provenance": provenance_of(command_line, inputs, outputs),
              "meta": check_meta(meta)}
    robot = result.robot
    report["frames"] = {"base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
                        "joints": list(robot.joint_names), **dict(frames or {})}
    report.update(result.to_dict())
    report["certificate"] = {**certificate_identity(report["provenance"], report["meta"], rows.columns),
                             **_certificate(rows, tolerance_mm, calibration=True)}
    report["covariance"] = _covariance_dict(result)
    report["residuals"] = _residuals_entry(rows, residuals)
    return report


def build_accuracy_report(robot: RobotModel, measurements: Measurements, *, command_line: Sequence[str] = (),
                          inputs: Mapping[str, str | Path] | None = None, meta: Mapping | None = None,
                          tolerance_mm: float | None = None, residuals: str | Path = "auto",
                          rows: ReportRows | None = None) -> dict:
    """The report of one model's accuracy against measurements (``calib evaluate --html``):
    ``schema_version``, ``provenance``, ``meta``, ``frames`` and ``certificate`` as in
    :func:`build_report` (the groups: all rows, and the cal and val rows apart when the file has
    both; the verdict over all rows), ``evaluation: true`` and ``residuals``. rows :
    :func:`report_rows` of ``robot`` and ``measurements`` when already computed."""
    check_robot(robot)
    check_measurements(measurements)
    _check_common(command_line, inputs, None, None, meta, tolerance_mm, residuals)
    rows = check_instance(rows, "rows", ReportRows, "from report_rows", allow_none=True) \
        or report_rows(robot, measurements, validation_rows="none")
    provenance, meta = provenance_of(command_line, inputs, None), check_meta(meta)
    report = {"schema_version": SCHEMA_VERSION, "evaluation": True,
              "provenance": provenance, "meta": meta,
              "frames": {"base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
                         "joints": list(robot.joint_names)},
              "certificate": {**certificate_identity(provenance, meta, rows.columns),
                              **_certificate(rows, tolerance_mm, calibration=False)},
              "residuals": _residuals_entry(rows, residuals)}
    return report


def report_json_text(report: Mapping) -> str:
    """The JSON text of a report: indented, with each residual column on one line (a 20,000-row
    report stays a few MB and readable); strict JSON (NaN and infinities as null)."""
    res = report.get("residuals")
    cols = res.get("columns") if isinstance(res, Mapping) and res.get("layout") == "columns" else None
    body = dict(report)
    if cols:
        body["residuals"] = {**res, "columns": {k: f"\0{k}\0" for k in cols}}
    text = json.dumps(_clean(body), indent=2, allow_nan=False)
    for k, v in (cols or {}).items():
        text = text.replace(json.dumps(f"\0{k}\0"), json.dumps(_clean(list(v)), separators=(",", ":")), 1)
    return text + "\n"


def _clean(o):
    """``o`` with non-finite floats as None, no negative zero (-0.0 + 0.0 is 0.0) and numpy
    scalars as Python ones."""
    if isinstance(o, float):
        return o + 0.0 if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        if o and all(type(v) is float for v in o[:3]) and all(math.isfinite(v) for v in o):
            return [v + 0.0 if type(v) is float else v for v in o]
        return [_clean(v) for v in o]
    if isinstance(o, np.generic):
        return _clean(o.item())
    return o


# ====================================================================== HTML report
def render_html(report: Mapping, text: str, images: Mapping[str, bytes] | None = None, *,
                title: str | None = None) -> str:
    """One self-contained HTML page (no external links; plots embedded as PNG data) of a report
    from :func:`build_report` or :func:`build_accuracy_report`, with ``text`` (what the terminal
    printed) and ``images`` (file name -> PNG bytes, e.g. from :func:`render_plots`): identity,
    verdict, accuracy (mm, degrees), per-axis table, ISO 9283, parameters with expanded
    uncertainties (k = 2), plots, provenance (:mod:`calib.report.html`)."""
    from calib.report.html import html_page

    if not isinstance(report, Mapping):
        raise ParameterError(f"report must be a report from calib.build_report, got {type(report).__name__}")
    for name, value in (("text", text), ("title", title)):
        if not isinstance(value, str) and not (name == "title" and value is None):
            raise ParameterError(f"{name} must be a string, got {type(value).__name__}")
    if images is not None and not (isinstance(images, Mapping) and all(
            isinstance(k, str) and isinstance(v, (bytes, bytearray)) for k, v in images.items())):
        raise ParameterError(f"images must map file names to PNG bytes, got {images!r:.60}")
    try:
        return html_page(report, text, images or {}, title)
    except (AttributeError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise ParameterError(f"report is not a report from calib.build_report ({type(exc).__name__}: "
                             f"{exc})") from None
