"""The text and tables of a :class:`~calib.calibration.result.CalibrationResult` for a person
(:func:`format_result`: its ``format()``) and its frame transforms as transforms
(:func:`frames_table`: x, y, z mm; roll, pitch, yaw deg), read from the result only."""
from __future__ import annotations

import math

from calib.calibration.accuracy.errors import format_accuracy_table
from calib.units import display_unit, display_value, format_number

__all__ = ["format_result", "frames_table", "frames_text", "frame_of"]


def format_result(self) -> str:
    """The text of a :class:`~calib.calibration.result.CalibrationResult` for a person
    (``self``): status, noise, notes, outliers, the parameter table, the frames, accuracy before
    and after, the predictions."""
    if self.features is not None:
        return _format_touch(self)
    nz = self.noise
    est = self.estimator or {}
    if est.get("kind") == "eb-map":
        head = (f"Calibration: EB-MAP (regularised toward the nominal model; {len(self.free)} parameters "
                f"free of {len(self.parameters)}, {est['effective_parameters']:.1f} effective), "
                f"{self.status}: {self.message}")
    else:
        head = (f"Calibration: {self.method.upper()}, parameter set {self.param_set!r} "
                f"({len(self.free)} identified of {len(self.parameters)}), {self.status}: {self.message}")
    lines = [head, f"  {self.iterations} LM iterations in all (every fit of the calibration), {self.rounds} "
                   f"rounds, {self.wall_time * 1e3:.1f} ms"]
    if est.get("kind") == "eb-map":
        units = est.get("prior_scale_units", {})
        scales = ", ".join(f"{g} {v:.3g} {units.get(g, '')}".rstrip() for g, v in est["prior_scales"].items())
        pinned = f" (held at nominal: {', '.join(est['pinned'])})" if est.get("pinned") else ""
        lines.append(f"  prior scales from the evidence: {scales}{pinned}; log evidence "
                     f"{est['log_evidence']:.6g}")
    if nz is not None:
        rot = "" if nz.rotation is None else f", orientation {nz.rotation:.3g} rad"
        if nz.estimated and est.get("kind") == "eb-map":
            lines.append(f"  noise estimated with the prior scales (evidence, {nz.iterations} linearisations): "
                         f"position {nz.position * 1e3:.4g} mm{rot} per axis")
        elif nz.estimated:
            lines.append(f"  noise estimated from the residuals ({nz.iterations} re-weighted fits): "
                         f"position {nz.position * 1e3:.4g} mm{rot} per axis")
        else:
            lines.append(f"  noise given: position {nz.position * 1e3:g} mm{rot} per axis; residuals "
                         f"vs that noise: reduced chi^2 {nz.reduced_chi2:.3g} over {nz.dof:.0f} degrees "
                         f"of freedom (p = {nz.p_value:.3g}{', consistent' if nz.p_value > 0.01 else ', NOT consistent'})")
    lines += [f"  note: {n}" for n in self.notes]
    for o in self.outliers:
        rot = "" if math.isnan(o.rotation_error) else f", {o.rotation_error:.3g} rad"
        lines.append(f"  outlier: row {o.row}: {o.position_error * 1e3:.3f} mm{rot} ({o.sigmas:.0f} sigma)")
    if self.selection is not None:
        lines += ["", self.selection.format()]
    lines += _parameter_lines(self)
    rows = [("calibration rows, before", self.before)]
    if self.before_registered is not None:
        rows.append(("  before, frame registered", self.before_registered))
    rows.append(("calibration rows, after", self.after))
    if self.after_without_outliers is not None:
        rows.append(("  after, without outliers", self.after_without_outliers))
    if self.validation_after is not None:
        rows.append(("validation rows, before", self.validation_before))
        if self.validation_before_registered is not None:
            rows.append(("  before, frame registered", self.validation_before_registered))
        rows.append(("validation rows, after", self.validation_after))
    for t in self.targets:
        rows += [(f"target {t.target}, before", t.before), (f"target {t.target}, after", t.after)]
        if t.validation_after is not None:
            rows += [(f"target {t.target}, val. before", t.validation_before),
                     (f"target {t.target}, val. after", t.validation_after)]
    lines += ["", format_accuracy_table(rows)]
    if self.cross_validation is not None:
        cv = self.cross_validation
        rot = "" if cv.rotation_rms is None else f", orientation {cv.rotation_rms:.3g} rad"
        kind = "leave-one-out" if cv.folds == sum(n for n, _, _ in cv.per_fold) else f"{cv.folds}-fold"
        lines.append(f"cross-validated ({kind}) held-out RMS error: position "
                     f"{cv.position_rms * 1e3:.4g} mm{rot}")
    pr = self.predicted
    rot = "" if pr.get("rotation_rms") is None else f", orientation {pr['rotation_rms']:.3g} rad"
    if self.predicted_holdout is not None:
        ph = self.predicted_holdout
        rot_h = "" if pr.get("rotation_rms") is None else f", orientation {ph['rotation_rms']:.3g} rad"
        lines.append(f"predicted RMS error on new measured rows ({pr['where']}): position "
                     f"{ph['position_rms'] * 1e3:.4g} mm{rot_h}")
    pw = self.predicted_workspace
    if pw is not None:
        rot_w = "" if pw.get("rotation_rms") is None else f", orientation {pw['rotation_rms']:.3g} rad"
        lines.append(f"predicted RMS error on new measured rows ({pw['configurations']} {pw['where']}): "
                     f"position {pw['position_rms'] * 1e3:.4g} mm{rot_w}")
    lines.append(f"predicted RMS error of the calibrated model against the true poses (Cramer-Rao, "
                 f"{pr['where']}): position {pr['position_rms'] * 1e3:.4g} mm{rot}")
    return "\n".join(lines)

def _parameter_lines(self) -> list[str]:
    """The parameter table (the frames as transforms, after it)."""
    w = max([10] + [len(p.name) + 1 for p in self.parameters])
    lines = ["", f"{'parameter':<{w}}{'unit':>5}{'nominal':>14}{'identified':>14}{'deviation':>13}{'std':>11}"]
    if self.robot.has_joint_terms:
        lines.insert(-1, f"  note: {self.compliance_record()['note']}")
    for p in self.parameters:
        if frame_of(p.name) is not None:      # frames: as transforms, below
            continue
        unit = display_unit(p.unit)
        std = "fixed" if not p.free else f"{display_value(p.std, p.unit):.3g}"
        lines.append(f"{p.name:<{w}}{unit:>5}{format_number(display_value(p.nominal, p.unit), '>14.6f')}"
                     f"{format_number(display_value(p.identified, p.unit), '>14.6f')}"
                     f"{format_number(display_value(p.deviation, p.unit), '>13.6f')}{std:>11}")
    return lines + ["", frames_text(frames_table(self))]

def _format_touch(self) -> str:
    """:func:`format_result` of a calibration from touch data."""
    touch = self.group("touch")
    measured = self.group("position")
    n = sum(g.components for g in self.groups)
    lines = [f"touch calibration: {touch.rows} touch rows" + (f" and {measured.rows} measured rows" if measured
                                                               else "")
             + f", {n} residual components, {len(self.free)} robot parameters and "
             f"{len(self.features.names)} feature unknowns fitted; LM, parameter set {self.param_set!r}, "
             f"{self.status}: {self.message}",
             f"  {self.iterations} LM iterations in all (every fit of the calibration), {self.wall_time * 1e3:.1f} ms"]
    lines += [f"  {g.format()}" for g in self.groups]
    if self.nominal_scale:
        lines.append("  no known length: the scale is held at the nominal (nominal_scale); the model is "
                     "right up to scale")
    lines += [f"  note: {n}" for n in self.notes]
    lines += [f"  outlier: row {o.row}: {o.position_error * 1e3:.3f} mm ({o.sigmas:.0f} sigma)" for o in self.outliers]
    if self.cross_validation is not None:
        lines.append(f"  held out by {self.cross_validation.folds}-fold cross-validation (each group's RMS per "
                     f"component above)")
    lines += ["", "features:"] + self.features.format()
    if self.identifiability is not None:
        lines += ["", self.identifiability.format()]
    lines += _parameter_lines(self)
    lines += ["", format_accuracy_table([("rows, before", self.before), ("rows, after", self.after)]
                                        + ([("  after, without outliers", self.after_without_outliers)]
                                           if self.after_without_outliers is not None else []))]
    pr = self.predicted
    lines.append(f"predicted tool position error over the workspace ({pr['where']}"
                 + ("" if measured else ", relative to the nominal base frame")
                 + f"): {pr['position_rms'] * 1e3:.4f} mm RMS (noise only"
                 + ("; the scale held nominal adds the longest link's error over its length)"
                    if self.nominal_scale else ")"))
    if pr.get("meas_frame_rms") is not None:
        lines.append(f"predicted tool position error in the meas frame (identified by the {measured.rows} "
                     f"measured rows, no registration): {pr['meas_frame_rms'] * 1e3:.4f} mm RMS (noise only)")
    return "\n".join(lines)


#: The parameter groups that are frame transforms, and their kinds in Eq. (3) order.
_FRAME_GROUPS = ("u", "v")
_ZYX_KINDS = ("x", "y", "z", "alpha", "beta", "gamma")


def frame_of(name: str) -> tuple[str, str | None, str] | None:
    """(group, target or None, kind) of a u / v parameter name (``u_x``, ``v_gamma@A``), else None."""
    head, _, target = name.partition("@")
    group, _, kind = head.partition("_")
    if group in _FRAME_GROUPS and kind in _ZYX_KINDS:
        return group, (target or None), kind
    return None


def frames_text(rows: list[dict]) -> str:
    """The frame transforms as a table for a person: a row per value (nominal, identified, std)."""
    w = max([24] + [len(f["frame"]) + 2 for f in rows])
    out = [f"{'frame transform':<{w}}{'':<16}{'x/mm':>12}{'y/mm':>12}{'z/mm':>12}{'roll/deg':>12}"
           f"{'pitch/deg':>12}{'yaw/deg':>12}"]
    for f in rows:
        parts = ([("nominal", f["nominal"], ".4f", ".6f")] if f["nominal"] is not None else []) + \
            [("identified", f["identified"], ".4f", ".6f"), (f["std_label"], f["std"], ".3g", ".3g")]
        none = "-" if f.get("orientation_measured") is False else "fixed"
        for k, (label, d, fl, fa) in enumerate(parts):
            vals = [("fixed" if x is None else format_number(x, fl)) for x in d["xyz_mm"]] + \
                   [(none if x is None else format_number(x, fa)) for x in d["rpy_deg"]]
            out.append(f"{f['frame'] if k == 0 else '':<{w}}{label:<16}" + "".join(f"{v:>12}" for v in vals))
        if f.get("note"):
            out.append(f"{'':<{w}}({f['note']})")
    return "\n".join(out)


def frames_table(result) -> list[dict]:
    """The frame transforms of a result as transforms (x, y, z mm; roll, pitch, yaw deg): the
    measurement->base transform (when estimated), the robot base (MDH frame 0) in the URDF base
    frame, and flange->tool (or flange->target per target), with nominal, identified and std."""
    out = []
    mf = result.measurement_frame
    if mf is not None:
        d = mf.to_dict()
        out.append({"frame": f"measurement->{mf.base_frame}", "nominal": None,
                    "identified": {"xyz_mm": d["xyz_mm"], "rpy_deg": d["rpy_deg"]},
                    "std": {"xyz_mm": d["std_xyz_mm"], "rpy_deg": d["std_rotation_deg"]},
                    "std_label": "std (rot x,y,z)",
                    "note": "estimated from the data: the instrument's pose, not an error of the robot; "
                            "rotation std about the meas axes x, y, z"})
    # a tool or target measured by position alone is a point: its frame has no measured orientation
    point = result.before.rotation is None
    groups: dict = {}
    for p in result.parameters:
        f = frame_of(p.name)
        if f is not None:
            groups.setdefault(f[:2], {})[f[2]] = p
    for (group, target), rows in groups.items():
        if group == "u":
            label = ("base (MDH frame 0) in " + (mf.base_frame if mf is not None else "the meas frame"))
        else:
            label = f"flange->{target or 'tool'}"

        def pick(attr, rows=rows):
            v = [getattr(rows[k], attr) if k in rows else math.nan for k in _ZYX_KINDS]
            return v
        nom, ide, std = pick("nominal"), pick("identified"), pick("std")

        def as_transform(v, is_std=False):
            xyz = [v[i] * 1e3 for i in range(3)]
            rpy = [math.degrees(v[i]) for i in (5, 4, 3)]     # roll = gamma, pitch = beta, yaw = alpha
            if is_std:      # (a tool frame's std is propagated: it can move where a parameter is held)
                moves = [k in rows and math.isfinite(rows[k].std) for k in _ZYX_KINDS]
                xyz = [x if moves[i] else None for i, x in enumerate(xyz)]
                rpy = [x if moves[i] else None for i, x in zip((5, 4, 3), rpy)]
            if group == "v" and point:
                rpy = [None, None, None]
            return {"xyz_mm": xyz, "rpy_deg": rpy}
        estimated = (group == "u" and mf is not None) or (
            group == "v" and any(e.startswith("flange->") for e in result.estimated_frames))
        notes = (["the tool frame was estimated from the data: the measured point"] if group == "v" and estimated
                 else []) + (["measured by position only: a point, no orientation"] if group == "v" and point else [])
        entry = {"frame": label, "nominal": as_transform(nom), "identified": as_transform(ide),
                 "std": as_transform(std, True), "std_label": "std", "note": "; ".join(notes)}
        if group == "v" and point:
            entry["orientation_measured"] = False
        out.append(entry)
    return out
