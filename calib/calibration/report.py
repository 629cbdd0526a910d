"""Plots of a calibration: per-pose tool pose errors before and after, and their histograms.

:func:`render_plots` draws, with matplotlib's Agg canvas (no display needed; pyplot and the
global backend are left alone):

- ``position_errors.png`` (as Figure 7 of the paper): per pose, the position error |p_model -
  p_measured| and its x, y, z components in the meas frame, millimetres; one panel for the
  nominal model (before) and one for the calibrated model (after). Calibration rows come first,
  then validation rows, separated by a dashed line.
- ``orientation_errors.png`` (as Figure 8): per pose, the angle of ``R_model R_measured^T`` and
  the components of its rotation vector about the meas frame's x, y, z axes, radians (not drawn
  for position-only data).
- ``error_histograms.png``: histograms of the position (mm) and orientation (rad) errors, before
  and after, calibration and validation rows apart.

The rows are split as :func:`calib.calibrate` splits them: the ``cal`` rows of the measurements
(all rows without a set column) for identification; their ``val`` rows and the extra validation
measurements for validation.

:func:`build_report` makes the JSON report of a calibration (schema :data:`SCHEMA_VERSION`):
the result's own dictionary plus provenance, frames, per-row residuals and the covariance of the
free parameters; :func:`render_html` one self-contained HTML page of it with the plots.
"""
from __future__ import annotations

import base64
import datetime
import hashlib
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from calib.calibration.result import CalibrationResult
from calib.checks import check_instance
from calib.errors import ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements, check_measurements
from calib.model.robot import RobotModel
from calib.model.spatial import log3_batch

__all__ = ["PoseDeviations", "SCHEMA_VERSION", "build_report", "file_provenance",
           "pose_deviations", "render_html", "render_plots"]

#: File names of the plots, in the order :func:`render_plots` returns them.
PLOT_FILES = ("position_errors.png", "orientation_errors.png", "error_histograms.png")


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
    from calib.calibration.accuracy import target_rows, with_measured_targets

    robot = with_measured_targets(robot, measurements)
    R, p = ChainKinematics(robot).frame_poses(measurements.q, targets=target_rows(robot, measurements))
    rot = None
    if measurements.rotation is not None:
        rot = log3_batch(R @ np.transpose(measurements.rotation, (0, 2, 1)))
    return PoseDeviations(p - measurements.position, rot)


def _split(measurements: Measurements, validation: Measurements | None):
    """(calibration rows, validation rows or None), as calibrate() splits them."""
    cal = measurements.calibration()
    parts = [m for m in (measurements.validation(), validation) if m is not None and m.n_poses]
    return cal, parts


def _deviations(robot: RobotModel, cal: Measurements, val_parts) -> tuple[PoseDeviations, PoseDeviations | None]:
    dc = pose_deviations(robot, cal)
    if not val_parts:
        return dc, None
    dv = [pose_deviations(robot, m) for m in val_parts]
    rot = None if any(d.rotation is None for d in dv) else np.concatenate([d.rotation for d in dv])
    return dc, PoseDeviations(np.concatenate([d.position for d in dv]), rot)


def _figure_bytes(fig) -> bytes:
    """The figure as PNG, drawn by the Agg canvas (pyplot and the global backend are not used)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def render_plots(result: CalibrationResult, measurements: Measurements,
                 validation: Measurements | None = None) -> dict[str, bytes]:
    """PNG images of the calibration's pose errors, by file name (see the module docstring).

    Parameters
    ----------
    result : what :func:`calib.calibrate` returned for these measurements.
    measurements, validation : the arguments given to :func:`calib.calibrate`.

    Returns ``{file name: PNG bytes}``; ``orientation_errors.png`` is left out for position-only
    data. Nothing is written: the caller decides where the images go.
    """
    from matplotlib.figure import Figure

    cal, val_parts = _split(measurements, validation)
    before = _deviations(result.nominal, cal, val_parts)
    after = _deviations(result.robot, cal, val_parts)
    n_cal = cal.n_poses
    has_rot = before[0].rotation is not None and (before[1] is None or before[1].rotation is not None)

    def stack(pair, attr):
        parts = [getattr(d, attr) for d in pair if d is not None]
        return np.concatenate(parts)

    images: dict[str, bytes] = {}
    colors = ("tab:red", "tab:green", "tab:blue")

    def per_pose(kind: str, scale: float, unit: str, title: str) -> bytes:
        fig = Figure(figsize=(10, 7), layout="constrained")
        axes = fig.subplots(2, 1)
        for ax, (label, dev) in zip(axes, (("before calibration (nominal model)", before),
                                           ("after calibration", after))):
            comp = stack(dev, kind) * scale
            norm = np.linalg.norm(comp, axis=1)
            idx = np.arange(1, len(norm) + 1)
            ax.plot(idx, norm, color="black", lw=1.2, marker=".", ms=3, label="error (norm)")
            for c, axis_name, color in zip(comp.T, "xyz", colors):
                ax.plot(idx, c, color=color, lw=0.7, alpha=0.8,
                        label=f"{'about ' if kind == 'rotation' else ''}{axis_name}")
            ax.axhline(0.0, color="grey", lw=0.5)
            if len(norm) > n_cal:
                ax.axvline(n_cal + 0.5, color="grey", ls="--", lw=1.0)
                ax.text(n_cal + 0.5, 1.0, "  validation rows", transform=ax.get_xaxis_transform(),
                        va="top", ha="left", fontsize=8, color="grey")
                ax.text(n_cal + 0.5, 1.0, "calibration rows  ", transform=ax.get_xaxis_transform(),
                        va="top", ha="right", fontsize=8, color="grey")
            ax.set_title(f"{title}, {label}: mean {norm.mean():.4g} {unit}, max {norm.max():.4g} {unit} "
                         f"over all {len(norm)} rows",
                         fontsize=10)
            ax.set_xlabel("pose")
            ax.set_ylabel(f"{title.split(' ')[0]} error / {unit}")
            ax.set_xlim(0.5, len(norm) + 0.5)
            ax.legend(fontsize=8, ncol=4, loc="lower right")
            ax.grid(alpha=0.3)
        fig.suptitle(f"Tool {title} in the meas frame per pose ({result.method.upper()}, "
                     f"parameter set {result.param_set!r})")
        return _figure_bytes(fig)

    images["position_errors.png"] = per_pose("position", 1e3, "mm", "position deviation")
    if has_rot:
        images["orientation_errors.png"] = per_pose("rotation", 1.0, "rad", "orientation deviation")

    fig = Figure(figsize=(10, 7 if has_rot else 3.8), layout="constrained")
    rows = 2 if has_rot else 1
    axes = np.atleast_2d(fig.subplots(rows, 2))
    quantities = [("position_errors", 1e3, "position error / mm")]
    if has_rot:
        quantities.append(("rotation_errors", 1.0, "orientation error / rad"))
    for r, (attr, scale, xlabel) in enumerate(quantities):
        for c, (label, dev) in enumerate((("before calibration", before), ("after calibration", after))):
            ax = axes[r, c]
            data = [(name, getattr(d, attr) * scale) for name, d in (("calibration rows", dev[0]),
                                                                     ("validation rows", dev[1]))
                    if d is not None]
            hi = max(float(e.max()) for _, e in data)
            bins = np.linspace(0.0, hi * 1.0001 if hi > 0 else 1.0, 31)
            for (name, e), color in zip(data, ("tab:blue", "tab:orange")):
                ax.hist(e, bins=bins, alpha=0.6, color=color, label=f"{name} ({len(e)})")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("poses")
            ax.set_title(label, fontsize=10)
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
    fig.suptitle("Distribution of the tool pose errors")
    images["error_histograms.png"] = _figure_bytes(fig)
    return images


# ====================================================================== JSON report
#: Version of the JSON report's layout; raised when a key changes meaning or disappears.
SCHEMA_VERSION = 1


def file_provenance(path: str | Path) -> dict:
    """``{"path", "sha256", "bytes"}`` of an input file (path as given, resolved to absolute)."""
    path = Path(path)
    data = path.read_bytes()
    return {"path": str(path.resolve()), "sha256": hashlib.sha256(data).hexdigest(),
            "bytes": len(data)}


def _calib_version() -> str:
    from calib import __version__

    return __version__


def _residual_rows(result: CalibrationResult, parts: Sequence[tuple[str, str, Measurements]],
                   outlier_rows: set) -> list[dict]:
    out = []
    for file_role, set_name, m in parts:
        if m is None or not m.n_poses:
            continue
        after, before = pose_deviations(result.robot, m), pose_deviations(result.nominal, m)
        sets = m.sets if m.sets is not None else [set_name] * m.n_poses
        for k in range(m.n_poses):
            rec = {"file": file_role, "row": int(m.rows[k]), "set": str(sets[k]),
                   "position_mm": [float(v) * 1e3 for v in after.position[k]],
                   "position_error_mm": float(np.linalg.norm(after.position[k])) * 1e3,
                   "position_error_before_mm": float(np.linalg.norm(before.position[k])) * 1e3}
            if after.rotation is not None:
                rec.update({"rotation_rad": [float(v) for v in after.rotation[k]],
                            "rotation_error_rad": float(np.linalg.norm(after.rotation[k])),
                            "rotation_error_before_rad": float(np.linalg.norm(before.rotation[k]))})
            if m.target is not None:
                rec["target"] = m.target[k]
            if file_role == "measurements":
                rec["outlier"] = int(m.rows[k]) in outlier_rows
            out.append(rec)
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


def build_report(result: CalibrationResult, measurements: Measurements,
                 validation: Measurements | None = None, *, command_line: Sequence[str] = (),
                 inputs: Mapping[str, str | Path] | None = None, frames: Mapping | None = None,
                 outputs: Mapping[str, str | Path] | None = None) -> dict:
    """The JSON report of a calibration: ``result.to_dict()`` plus

    * ``schema_version`` (:data:`SCHEMA_VERSION`);
    * ``provenance``: calib version, ``command_line`` (list of arguments), UTC date, and path,
      sha256 and size of every file in ``inputs`` (role -> path, e.g. ``{"robot": ...,
      "measurements": ...}``), and ``outputs`` (role -> path) as given;
    * ``frames``: base and tool frame and chain joints of the model, plus ``frames`` given by the
      caller (e.g. the frames recorded in the written URDF, under ``"written_urdf"``);
    * ``residuals``: one entry per row of ``measurements`` and ``validation`` (file role, 1-based
      file row, set, target (when the data has a target column), residual p_model - p_measured in mm in the meas frame, its length before and
      after, rotation vector of R_model R_measured^T in rad and its angle, outlier flag);
    * ``covariance``: names, units, standard deviations, covariance and correlation of the free
      parameters (mm and rad).

    ``measurements`` and ``validation`` are the arguments :func:`calib.calibrate` was given.
    """
    check_instance(result, "result", CalibrationResult, "from calib.calibrate")
    check_measurements(measurements)
    check_measurements(validation, "validation", allow_none=True)
    if not isinstance(command_line, (list, tuple)) or \
            not all(isinstance(a, (str, os.PathLike)) for a in command_line):
        raise ParameterError(f"command_line must be a list of arguments (strings), got {command_line!r:.60}")
    for name, paths in (("inputs", inputs), ("outputs", outputs)):
        if paths is not None and not (isinstance(paths, Mapping) and all(
                isinstance(role, str) and (p is None or isinstance(p, (str, os.PathLike))) for role, p in paths.items())):
            raise ParameterError(f"{name} must map each role (a string) to a file path, got {paths!r:.60}")
    if frames is not None and not (isinstance(frames, Mapping) and all(isinstance(k, str) for k in frames)):
        raise ParameterError(f"frames must be a mapping of names to values, got {frames!r:.60}")
    report = {"schema_version": SCHEMA_VERSION}
    report["provenance"] = {
        "calib_version": _calib_version(),
        "command_line": [os.fspath(a) for a in command_line],
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "inputs": {role: file_provenance(path) for role, path in (inputs or {}).items()
                   if path is not None},
        "outputs": {role: str(path) for role, path in (outputs or {}).items() if path is not None},
    }
    robot = result.robot
    report["frames"] = {"base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
                        "joints": list(robot.joint_names), **dict(frames or {})}
    report.update(result.to_dict())
    outlier_rows = {int(o.row) for o in getattr(result, "outliers", ())}
    parts = [("measurements", "cal", measurements), ("validation", "val", validation)]
    report["residuals"] = _residual_rows(result, parts, outlier_rows)
    report["covariance"] = _covariance_dict(result)
    return report


# ====================================================================== HTML report
_CSS = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;
text-align:right}th{background:#eee}td.l,th.l{text-align:left}pre{background:#f6f6f6;padding:1em;
overflow-x:auto}img{max-width:100%}.bad{color:#b00}"""


def _escape(s: str) -> str:
    """html.escape (imported on first use: the html package costs 10 ms of the CLI's start)."""
    import html

    return html.escape(s)


def _table(header: Sequence[str], rows: Sequence[Sequence], left: int = 1) -> str:
    def cell(tag, k, v):
        cls = ' class="l"' if k < left else ""
        return f"<{tag}{cls}>{_escape(str(v))}</{tag}>"
    head = "".join(cell("th", k, h) for k, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", k, v) for k, v in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _frame_transforms_html(rows) -> str:
    """The frame transforms (measurement->base, base, flange->tool) as transforms: x, y, z / mm
    and roll, pitch, yaw / deg, nominal, identified and 1-sigma std."""
    if not rows:
        return ""

    def six(d, fmt):
        return [_num(v, fmt) if v is not None else "fixed" for v in (*d["xyz_mm"], *d["rpy_deg"])]
    body = []
    for f in rows:
        if f.get("nominal") is not None:
            body.append([f["frame"], "nominal", *six(f["nominal"], ".4f")])
        body.append([f["frame"], "identified", *six(f["identified"], ".4f")])
        body.append([f["frame"], f.get("std_label", "std") + " (1 sigma)", *six(f["std"], ".3g")])
    return ("<h2>Frame transforms</h2>" + _table(
        ["frame", "", "x / mm", "y / mm", "z / mm", "roll / deg", "pitch / deg", "yaw / deg"], body, left=2))


def _num(v, fmt=".4g") -> str:
    return "" if v is None else format(v, fmt)


def render_html(report: Mapping, text: str, images: Mapping[str, bytes] | None = None, *,
                title: str = "Kinematic calibration report") -> str:
    """One self-contained HTML page (no external links; plots embedded as PNG data) of a report
    from :func:`build_report`, with ``text`` (what the terminal printed) and ``images`` (file
    name -> PNG bytes, e.g. from :func:`render_plots`)."""
    if not isinstance(report, Mapping):
        raise ParameterError(f"report must be a report from calib.build_report, got {type(report).__name__}")
    for name, value in (("text", text), ("title", title)):
        if not isinstance(value, str):
            raise ParameterError(f"{name} must be a string, got {type(value).__name__}")
    if images is not None and not (isinstance(images, Mapping) and all(
            isinstance(k, str) and isinstance(v, (bytes, bytearray)) for k, v in images.items())):
        raise ParameterError(f"images must map file names to PNG bytes, got {images!r:.60}")
    try:
        return _html(report, text, images, title)
    except (AttributeError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise ParameterError(f"report is not a report from calib.build_report ({type(exc).__name__}: "
                             f"{exc})") from None


def _html(report: Mapping, text: str, images: Mapping[str, bytes] | None, title: str) -> str:
    """:func:`render_html` of checked arguments."""
    e = _escape
    prov, frames = report.get("provenance", {}), report.get("frames", {})
    parts = [f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{e(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{e(title)}</h1>"]
    ok = report.get("success")
    parts.append(f"<p>Status: <b class=\"{'' if ok else 'bad'}\">{e(str(report.get('status')))}</b>"
                 f" &mdash; {e(str(report.get('message', '')))}</p>")
    dc = report.get("data_consistency")
    if dc:
        lead = next((n for n in report.get("notes", []) if n.startswith("the data disagree")), None)
        if lead:
            parts.append(f"<p class=\"bad\"><b>Inconsistent data:</b> {e(lead)}</p>")
    parts.append("<h2>Robot and frames</h2>" + _table(
        ["item", "value"],
        [["base frame (measurement frame)", frames.get("base_frame")],
         ["tool frame", frames.get("tool_frame")],
         ["joints", ", ".join(frames.get("joints", []))]]
        + [[f"written URDF: {k}", v] for k, v in (frames.get("written_urdf") or {}).items()], left=2))
    acc_rows = []
    per_target = [(f"target {t}, {when}", ("targets", t, when)) for t in (report.get("targets") or {})
                  for when in ("before", "after")]
    for label, key in [("calibration rows, before", ("before",)), ("calibration rows, after", ("after",)),
                       ("validation rows, before", ("validation", "before")),
                       ("validation rows, after", ("validation", "after"))] + per_target:
        d = report
        for k in key:
            d = d.get(k) if isinstance(d, Mapping) else None
        if not d:
            continue
        pos, rot = d.get("position_mm") or {}, d.get("rotation_rad") or {}
        acc_rows.append([label, d.get("n_poses")] + [_num(pos.get(k)) for k in ("mean", "rms", "max")]
                        + [_num(rot.get(k)) if rot else "" for k in ("mean", "rms", "max")])
    parts.append("<h2>Accuracy</h2>" + _table(
        ["rows", "poses", "position mean / mm", "RMS / mm", "max / mm", "orientation mean / rad",
         "RMS / rad", "max / rad"], acc_rows))
    pred_rows = []
    for label, key, pos, rot in (("new rows, at the " + str((report.get("predicted_rms") or {}).get("where")),
                                  "predicted_holdout_rms", "position_mm", "rotation_rad"),
                                 ("new rows, at random configurations within the joint limits",
                                  "predicted_workspace_rms", "position_mm", "rotation_rad"),
                                 ("true poses (Cramer-Rao), at the " + str((report.get("predicted_rms") or {}).get("where")),
                                  "predicted_rms", "position_mm", "rotation_rad"),
                                 ("true poses, at random configurations within the joint limits",
                                  "predicted_workspace_rms", "model_position_mm", "model_rotation_rad")):
        d = report.get(key)
        if d:
            pred_rows.append([label, _num(d.get(pos)), _num(d.get(rot))])
    if dc:
        pred_rows.append(["held-out error of all calibration rows, flagged ones included",
                          _num(dc["held_out_all_rows"]["position_mm"]), _num(dc["held_out_all_rows"]["rotation_rad"])])
    if pred_rows:
        parts.append("<h2>Predicted RMS error</h2>" + _table(["against", "position / mm", "orientation / rad"],
                                                           pred_rows))
    parts.append("<h2>Parameters</h2>" + _table(
        ["parameter", "unit", "nominal", "identified", "deviation", "std"],
        [[p["name"], p["unit"], _num(p["nominal"], ".6f"), _num(p["identified"], ".6f"),
          _num(p["deviation"], ".6f"), _num(p["std"], ".3g") if p["free"] else "fixed"]
         for p in report.get("parameters", []) if not p["name"].startswith(("u_", "v_"))], left=2))
    parts.append(_frame_transforms_html(report.get("frame_transforms") or []))
    sel = report.get("model_selection")
    if sel:
        parts.append(f"<h2>Model selection</h2><p>Candidate parameter sets compared by cross-validation "
                     f"(rule: {e(str(sel.get('rule')))}); chosen: <b>{e(str(sel.get('chosen')))}</b>, lowest "
                     f"score: {e(str(sel.get('best')))}.</p>" + _table(
                         ["candidate", "free parameters", "score", "score s.e.", "position RMS / mm",
                          "rotation RMS / rad"],
                         [[c["label"], c["n_free"], _num(c["score"]), _num(c["score_se"], ".3g"),
                           _num(c["position_rms_mm"]), _num(c["rotation_rms_rad"])]
                          for c in sel.get("candidates", [])]))
    for name, data in (images or {}).items():
        b64 = base64.b64encode(data).decode("ascii")
        parts.append(f"<h2>{e(name)}</h2><img alt=\"{e(name)}\" src=\"data:image/png;base64,{b64}\">")
    parts.append(f"<h2>Terminal output</h2><pre>{e(text)}</pre>")
    inputs = prov.get("inputs", {})
    parts.append("<h2>Provenance</h2>" + _table(
        ["item", "value"],
        [["calib version", prov.get("calib_version")], ["date (UTC)", prov.get("date")],
         ["command line", " ".join(prov.get("command_line", []))]]
        + [[f"input {role}", f"{v['path']} (sha256 {v['sha256']}, {v['bytes']} bytes)"]
           for role, v in inputs.items()], left=2))
    parts.append("</body></html>\n")
    return "\n".join(parts)
