"""The HTML page of a report: the figures of a JSON report (:func:`calib.build_report`,
:func:`calib.report.build.build_accuracy_report`) laid out by a Jinja2 template
(``templates/report.html.j2``, HTML-escaped throughout), angles in degrees and uncertainties
expanded (k = 2). Jinja2 is imported here, on first use: the CLI's start-up does not pay for it.
"""
from __future__ import annotations

import base64
import math
from functools import partial
from pathlib import Path
from typing import Mapping

from calib.report.identity import approval, instrument
from calib.units import format_number

__all__ = ["html_page", "load_template", "COVERAGE_FACTOR", "IMAGE_CAPTIONS"]

#: Coverage factor of the expanded uncertainties in the page (about 95 % for a normal law).
COVERAGE_FACTOR = 2.0
#: Rows of the ISO 9283 per-pose table shown in the page (all are in the JSON).
ISO_SHOWN = 50
_DEG = 180.0 / math.pi
_TEMPLATE = Path(__file__).with_name("templates") / "report.html.j2"
#: Heading of each plot in the page.
IMAGE_CAPTIONS = {"position_errors.png": "Position error per row",
                  "orientation_errors.png": "Orientation error per row",
                  "error_histograms.png": "Error distributions",
                  "error_map.png": "Error over the workspace",
                  "drift.png": "Drift during the measurement"}
_ENV = None
_COMPILED = None


def _num(v, fmt: str = ".4g") -> str:
    """A number for the page: "" for None, "n/a" for NaN and infinities, never a signed zero."""
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return "n/a"
    return format_number(v, fmt)


def _environment():
    global _ENV
    if _ENV is None:
        import jinja2

        _ENV = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True,
                                  lstrip_blocks=True)
        _ENV.filters["num"] = _num
    return _ENV


def load_template():
    """The page's Jinja2 template, compiled once per process (importing Jinja2 and compiling it
    take about 50 ms: a command can do it while its plots are drawn elsewhere)."""
    global _COMPILED
    if _COMPILED is None:
        _COMPILED = _environment().from_string(_TEMPLATE.read_text(encoding="utf-8"))
    return _COMPILED


def _frame_rows(report: Mapping) -> list[dict]:
    """The frame transforms of a report that has them (``frame_transforms``: per frame its
    nominal, identified and std as x, y, z mm and roll, pitch, yaw deg) as table rows, the std
    expanded to U = k sigma."""
    out = []

    def six(d, scale=1.0, fmt=".4f", point=False):
        return [("fixed" if v is None else _num(v * scale, fmt)) for v in d["xyz_mm"]] + \
            [(("\u2014" if point else "fixed") if v is None else _num(v * scale, fmt)) for v in d["rpy_deg"]]
    for f in report.get("frame_transforms") or []:
        point = f.get("orientation_measured") is False      # a point: no orientation to show
        six_ = partial(six, point=point)
        if f.get("nominal") is not None:
            out.append({"frame": f["frame"], "what": "nominal", "values": six_(f["nominal"])})
        out.append({"frame": f["frame"], "what": "identified", "values": six_(f["identified"])})
        if f.get("std") is not None:
            out.append({"frame": f["frame"], "what": "U (k = 2)", "values": six_(f["std"], COVERAGE_FACTOR, ".3g")})
    return out


def _point_frames(report: Mapping) -> list[str]:
    """The frames of the frame table measured by position only (points: no orientation shown)."""
    return [f["frame"] for f in report.get("frame_transforms") or [] if f.get("orientation_measured") is False]


def _parameter_rows(report: Mapping) -> list[dict]:
    """The parameter table in display units with angles in degrees and U = k sigma (without the
    frames' u_ and v_ rows when the report gives the frames as transforms)."""
    out = []
    as_transforms = bool(report.get("frame_transforms"))
    for p in report.get("parameters") or []:
        if as_transforms and p["name"].startswith(("u_", "v_")):
            continue
        unit, f = (("deg", _DEG) if p["unit"] == "rad" else (p["unit"], 1.0))
        std = p.get("std")
        out.append({"name": p["name"], "unit": unit,
                    "nominal": _num(p["nominal"] * f, ".6f"), "identified": _num(p["identified"] * f, ".6f"),
                    "deviation": _num(p["deviation"] * f, ".6f"),
                    "u": ("fixed" if not p["free"] else _num(None if std is None else COVERAGE_FACTOR * std * f,
                                                             ".3g"))})
    return out


def _predicted(report: Mapping) -> list[tuple]:
    rows = []
    where = (report.get("predicted_rms") or {}).get("where")

    def deg(v):
        return None if v is None else v * _DEG
    for label, key, pos, rot in ((f"new rows, at the {where}", "predicted_holdout_rms", "position_mm", "rotation_rad"),
                                 ("new rows, at random configurations within the joint limits",
                                  "predicted_workspace_rms", "position_mm", "rotation_rad"),
                                 (f"true poses (Cramer-Rao), at the {where}", "predicted_rms", "position_mm",
                                  "rotation_rad"),
                                 ("true poses, at random configurations within the joint limits",
                                  "predicted_workspace_rms", "model_position_mm", "model_rotation_rad")):
        d = report.get(key)
        if d:
            rows.append((label, d.get(pos), deg(d.get(rot))))
    cv = report.get("cross_validation")
    if cv and cv.get("position_rms_mm") is not None:
        rows.append(("held out by cross-validation (measured rows)", cv.get("position_rms_mm"),
                     deg(cv.get("rotation_rms_rad"))))
    dc = report.get("data_consistency")
    if dc:
        rows.append(("held-out error of all calibration rows, flagged ones included",
                     dc["held_out_all_rows"]["position_mm"], deg(dc["held_out_all_rows"]["rotation_rad"])))
    return rows


def _targets(report: Mapping) -> list[dict]:
    out = []
    for t, d in (report.get("targets") or {}).items():
        b, a = d["before"], d["after"]
        if a.get("position_mm") is None:
            continue
        out.append({"label": f"target {t}", "n": a["n_poses"], "before": b["position_mm"]["rms"],
                    "after": a["position_mm"]["rms"], "after_max": a["position_mm"]["max"]})
    return out


def _written(key: str, value) -> str:
    """One value of the frames recorded in the written URDF (``FramesRecord.to_dict``) for a
    person: the measurement->base transform in mm and degrees, the targets' links as a list (the
    page showed Python's repr of the dicts, in metres and radians, with ``'link': None``)."""
    if key == "measurement" and isinstance(value, Mapping):
        xyz, rpy = value.get("xyz") or [], value.get("rpy") or []
        text = ("xyz " + ", ".join(format_number(v * 1e3, ".4f") for v in xyz) + " mm; rpy "
                + ", ".join(format_number(v * _DEG, ".6f") for v in rpy) + " deg (the measurement->base transform)")
        link = value.get("link")
        return text + (f"; written as the fixed link '{link}' above the root" if link else
                       "; recorded in calib:frames only (no --measurement-link)")
    if isinstance(value, Mapping):
        return ", ".join(f"{k}: {v}" for k, v in value.items())
    return value


def _utc_text(stamp: str | None) -> str:
    """An ISO 8601 UTC stamp of a report (``2026-11-25T10:00:07+00:00``) as a person reads it:
    ``2026-11-25 10:00:07 UTC``; anything else as it is."""
    if not stamp:
        return ""
    for tail in ("+00:00", "Z"):
        if stamp.endswith(tail) and len(stamp) > 11 and stamp[10] == "T":
            return stamp[:10] + " " + stamp[11:-len(tail)] + " UTC"
    return stamp


#: Where each input of a report comes from, for the identity table (role -> label).
_INPUT_LABELS = {"robot": "robot model", "measurements": "measurements", "tracker": "instrument's file",
                 "validation": "validation measurements"}


def _identity(cert: Mapping, meta: dict, prov: Mapping) -> list[tuple[str, str]]:
    """The identity table: certificate number (and where it comes from), customer, dates, robot,
    instrument (and its own calibration), the other fields as given, the input files. Consumes
    the fields of ``meta`` it shows."""
    inputs = prov.get("inputs", {})
    given = set(meta)
    out = []
    if cert.get("number"):
        how = "as given" if cert.get("number_from") == "meta" else \
            f"derived from the sha256 of the {', '.join(cert.get('number_inputs') or ['input'])} files: Provenance"
        out.append(("certificate number", f"{cert['number']} ({how})"))
    if "customer" in meta:
        out.append(("customer", meta.pop("customer")))
    out.append(("issued", _utc_text(cert.get("issued") or prov.get("date", ""))))
    when = cert.get("measurement_date")
    if when:
        out.append(("measurement date", when["label"]))
    if "robot_serial" in meta:
        out.append(("robot serial", meta.pop("robot_serial")))
    inst = cert.get("instrument") or instrument(meta)
    if inst.get("name") or inst.get("serial"):
        out.append(("instrument", ", ".join(([inst["name"]] if inst.get("name") else [])
                                            + ([f"serial {inst['serial']}"] if inst.get("serial") else []))))
    else:
        out.append(("instrument", "not given (--meta instrument=...,instrument_serial=...)"))
    cal = inst.get("calibration_date")
    out.append(("instrument calibrated", (cal + (f", certificate {inst['certificate']}" if inst.get("certificate")
                                                 else "")) if cal else
                "not given (--meta instrument_calibration_date=YYYY-MM-DD)"))
    if "operator" in meta:
        out.append(("measured by", meta.pop("operator")))
    for key in ("certificate_number", "measurement_date", "instrument", "instrument_serial",
                "instrument_calibration_date", "instrument_certificate", "approved_by"):
        meta.pop(key, None)
    out += [(k.replace("_", " "), v) for k, v in meta.items()]
    out += [(_INPUT_LABELS.get(role, role), v["path"]) for role, v in inputs.items() if role in _INPUT_LABELS]
    out.append(("calib version", prov.get("calib_version", "")))
    if not given & {"robot_serial", "instrument", "operator"}:
        out.insert(0, ("identity fields", "none given (--meta robot_serial=...,instrument=...,operator=...)"))
    return out


def html_page(report: Mapping, text: str, images: Mapping[str, bytes], title: str | None) -> str:
    """The page (see the module docstring) of a checked report, text and images."""
    cert = report["certificate"]
    evaluation = bool(report.get("evaluation"))
    title = title or ("Robot accuracy report" if evaluation else "Kinematic calibration report")
    meta = dict(report.get("meta") or {})
    prov = report.get("provenance", {})
    identity = _identity(cert, dict(meta), prov)
    accuracy = cert["accuracy"]
    has_rot = any(g.get("rotation_deg") for g in accuracy)
    headline = [g for g in accuracy if g["label"].startswith(("calibration rows", "validation rows", "all rows",
                                                              "rows,"))]
    outliers = [{"row": o["row"], "position_error_mm": o["position_error_mm"],
                 "rotation_deg": None if o.get("rotation_error_rad") is None else o["rotation_error_rad"] * _DEG,
                 "sigmas": o.get("sigmas")} for o in report.get("outliers") or []]
    frames = [("base frame (measurement frame)", report["frames"].get("base_frame")),
              ("tool frame", report["frames"].get("tool_frame")),
              ("joints", ", ".join(report["frames"].get("joints", [])))]
    frames += [(f"written URDF: {k}", _written(k, v)) for k, v in (report["frames"].get("written_urdf") or {}).items()]
    if report.get("estimated_frames"):
        frames.append(("frames estimated in closed form", ", ".join(report["estimated_frames"])))
    sel = report.get("model_selection")
    if sel:
        sel = dict(sel, candidates=[dict(c, rotation_rms_deg=None if c.get("rotation_rms_rad") is None
                                         else c["rotation_rms_rad"] * _DEG) for c in sel.get("candidates", [])])
    before = report.get("before") or {}
    provenance = [("calib version", prov.get("calib_version")), ("date (UTC)", prov.get("date")),
                  ("command line", " ".join(prov.get("command_line", [])))]
    provenance += [(f"input {role}", f"{v['path']} (sha256 {v['sha256']}, {v['bytes']} bytes"
                                     + (f", modified {v['modified']}" if v.get("modified") else "") + ")")
                   for role, v in prov.get("inputs", {}).items()]
    provenance += [(f"output {role}", v) for role, v in prov.get("outputs", {}).items()]
    res = report.get("residuals")
    if isinstance(res, Mapping) and res.get("layout") == "csv":
        provenance.append(("per-row residuals", f"{res['csv']} ({res['n_rows']} rows)"))
    lead = None
    if report.get("data_consistency"):
        lead = next((n for n in report.get("notes", []) if n.startswith("the data disagree")), None)
    context = {
        "title": title, "ok": report.get("success", True) if not evaluation else True,
        "status": report.get("status", "evaluated") if not evaluation else "evaluated",
        "message": report.get("message", "") if not evaluation else "accuracy of one model against measurements",
        "inconsistent": lead, "identity": identity, "tolerance": cert.get("tolerance"),
        "headline": headline, "accuracy": accuracy, "has_rot": has_rot,
        "before_label": cert.get("before_label"), "registered": report.get("before_registered") is not None,
        "unregistered_before": (before.get("position_mm") or {}).get("rms"),
        "outliers": outliers, "per_axis": cert["per_axis"],
        "axes": ["x", "y", "z"] + (["rx", "ry", "rz"] if has_rot else []),
        "iso": cert.get("iso9283"), "iso_shown": ISO_SHOWN,
        "iso_ids": any(p.get("pose_id") for p in (cert.get("iso9283") or {}).get("poses", [])), "drift": cert.get("drift"),
        "features": cert.get("features"), "quantity": cert.get("quantity"), "calibration": not evaluation,
        "multi_target": bool(report.get("targets")) or any(
            p.get("target") for p in (cert.get("iso9283") or {}).get("poses", [])),
        "predicted": ([tuple(r) for r in report["predicted_rows"]] if report.get("predicted_rows")
                      else _predicted(report) if not evaluation else []), "targets": _targets(report),
        "frames": frames, "parameters": _parameter_rows(report), "frame_rows": _frame_rows(report),
        "point_frames": _point_frames(report),
        "selection": sel,
        "images": [(name, IMAGE_CAPTIONS.get(name, name), base64.b64encode(data).decode("ascii"))
                   for name, data in images.items()],
        "text": text, "provenance": provenance,
        "number": cert.get("number"), "issued": _utc_text(cert.get("issued") or prov.get("date")),
        "measured": (cert.get("measurement_date") or {}).get("label"),
        "basis": cert.get("basis"), "identity_notes": cert.get("notes") or [],
        "signatures": cert.get("signatures") or approval(meta),
    }
    import jinja2

    template = load_template()
    try:
        return template.render(**context)
    except jinja2.UndefinedError as exc:      # a report without a key the page needs
        raise KeyError(str(exc)) from None
