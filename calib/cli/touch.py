"""Touch files in the CLI (issue 24): ``calib calibrate ROBOT.urdf TOUCH.csv -o OUT.urdf`` on a
file whose rows name the point, plane or sphere the tool touched (:mod:`calib.io.csv.touch`),
and ``calib simulate ... --constraint point:N,plane:N,sphere:RADIUS_MM``.

:func:`run_touch` is what ``calibrate`` runs for such a file (it routes there when the header
has a ``point``, ``plane`` or ``sphere`` column, :func:`calib.cli.args.is_touch_input`).
"""
from __future__ import annotations

import argparse
import logging
import sys

from calib.cli.args import read_options
from calib.cli.inputs import load
from calib.cli.output import Outputs, command_line, json_text, refuse_implausible, status_exit
from calib.errors import CalibError, ParameterError

log = logging.getLogger(__name__)

#: calibrate's options that touch files do not take, with their defaults (a value other than the
#: default is refused: the touch fit is least squares by LM, geometry only).
_NOT_FOR_TOUCH = (("tracker", None), ("validate", None), ("compliance", False), ("method", "search-lm"), ("estimator", "auto"), ("loss", "linear"),
                  ("lm_variant", "calib"), ("periodic", False), ("payload_kg", None), ("payload_com_mm", None),
                  ("gravity", None), ("key", None), ("target_column", None), ("target_from", None),
                  ("join", "key"), ("time", None), ("time_unit", None), ("max_gap", None),
                  ("residuals", "auto"))


def run_touch(args: argparse.Namespace) -> int:
    """``calib calibrate`` on a touch file: :func:`calib.calibrate` of its rows (the identifiable
    parameters and the features), the calibrated URDF (u nominal; with measured rows rooted at the
    robot's base, the measurement->base transform recorded apart as for measurement files), the
    printed result (and --report JSON, :func:`calib.report.touch.touch_report`)."""
    import calib
    from calib.io.csv.touch import read_touch
    from calib.io.urdf.reader import robot_path
    from calib.io.urdf.writer import check_writable

    for name, default in _NOT_FOR_TOUCH:
        if getattr(args, name, default) not in (default, None):
            raise ParameterError(f"--{name.replace('_', '-')} does not apply to touch files "
                                 f"(rows naming point, plane or sphere)")
    params = args.params or "auto"
    if params not in ("auto", "tool"):
        raise ParameterError(f"--params for touch files: one of auto, tool, got {params!r}")
    outputs = Outputs([robot_path(args.robot), args.measurements])
    out_urdf = outputs.add(args.output)
    out_report = outputs.add(args.report) if args.report else None
    out_html = outputs.add(args.html) if getattr(args, "html", None) else None
    plot_paths = {}
    if getattr(args, "plots", None):
        from pathlib import Path

        from calib.report.plots import PLOT_FILES

        plot_paths = {name: outputs.add(Path(args.plots) / name, make_folder=True) for name in PLOT_FILES}
    from calib.cli.args import check_measurement_link, parse_meta

    meta = parse_meta(getattr(args, "meta", None))
    if out_report is None and out_html is None and (getattr(args, "meta", None) is not None
                                                     or getattr(args, "tolerance_mm", None) is not None):
        raise ParameterError("--meta and --tolerance-mm apply to the report: give --report REPORT.json or "
                             "--html REPORT.html")
    robot = load(args)
    check_writable(robot)
    check_measurement_link(getattr(args, "measurement_link", None), robot)
    probe = (getattr(args, "probe_radius_mm", None) or 0.0) * 1e-3
    data = read_touch(args.measurements, robot, probe_radius=probe, options=read_options(args, joined=False))
    link = getattr(args, "measurement_link", None)
    if link is not None and not data.n_measured:
        raise ParameterError(f"--measurement-link {link}: {args.measurements} has no rows measured by an "
                             f"instrument, so the calibration estimates no measurement frame (the features "
                             f"are in the robot's base frame {robot.base_frame!r}); nothing written")
    try:
        result = calib.calibrate(robot, data, params=params, cv=getattr(args, "cv", 5),
                                 outlier_k=getattr(args, "outlier_k", 5.0),
                                 nominal_scale=bool(getattr(args, "nominal_scale", False)), **_noise_arguments(args, data))
    except CalibError as exc:       # about the data as a whole (a degenerate design): name the file
        if str(exc).startswith(str(args.measurements)):
            raise
        raise type(exc)(f"{args.measurements}: {exc}") from None
    if result.status == "implausible" and not getattr(args, "accept_implausible", False):
        return refuse_implausible(result.format(), result.message)   # nonsense is not written
    urdf_text, frames = result.urdf_text(measurement_link=link)
    outputs.stage(out_urdf, urdf_text)
    text = result.format()
    from calib.report.touch import touch_report

    report = touch_report(result, ["calib", *getattr(args, "argv", [])])
    if out_report is not None or out_html is not None or plot_paths:
        text += _touch_report_stage(args, result, data, robot, report, text, meta, outputs, out_html,
                                    plot_paths, frames)
    if out_report is not None:
        outputs.stage(out_report, json_text(report))
    outputs.commit()
    shown = [p for p in [out_report, out_html] + list(plot_paths.values()) if p is not None and p in outputs.data]
    sys.stdout.write(text + f"\n\nwrote {out_urdf}" + "".join(f", {p}" for p in shown)
                     + f"\n{out_urdf}: calibrated kinematics of tool frame {frames.tool_frame!r} in base "
                       f"frame {frames.base_frame!r}\n")
    return status_exit(result.status, result.message)


def _touch_report_stage(args, result, data, robot, report: dict, text: str, meta, outputs, out_html, plot_paths,
                        frames) -> str:
    """The touch report's certificate (into ``report``, the JSON), plots and HTML page staged in
    ``outputs``; returns the verdict line for the printed text ("" without --tolerance-mm)."""
    from calib.report.build import provenance_of, render_html
    from calib.report.identity import certificate_identity
    from calib.report.plots import plot_rows
    from calib.report.touch import measured_deviations, touch_certificate, touch_rows
    from calib.cli.args import meta_inputs, progress_enabled
    from calib.cli.progress import Progress
    from calib.io.urdf.reader import robot_path

    tol_mm = getattr(args, "tolerance_mm", None)
    with Progress(3, "writing the report", enabled=progress_enabled(args)) as progress:
        rows = touch_rows(result, data, robot)
        provenance = provenance_of(["calib", *getattr(args, "argv", [])],
                                 {"robot": robot_path(args.robot), "measurements": args.measurements,
                                  **meta_inputs(getattr(args, "meta", None))},
                                 {"calibrated_urdf": args.output, "html": out_html})
        report["certificate"] = {**certificate_identity(provenance, meta, rows.columns),
                                 **touch_certificate(rows, data.features, tol_mm,
                                                     measured_deviations(result, data, robot))}
        report["meta"] = meta
        report["provenance"] = provenance
        progress.update()
        images = plot_rows(rows, tolerance_m=None if tol_mm is None else tol_mm * 1e-3) if (
            plot_paths or out_html is not None) else {}
        progress.update()
        tol = report["certificate"]["tolerance"]
        verdict = "" if tol is None else (
            f"\ntolerance {tol['tolerance_mm']:g} mm: {'PASS' if tol['pass'] else 'FAIL'} (largest "
            f"{'touch residual or measured position error' if data.n_measured else 'touch residual'} "
            f"{tol['max_mm']:.4g} mm over {tol['n']} {tol['rows']}; {tol['beyond']} beyond)")
        if out_html is not None:
            params = [{"name": p.name, "unit": d["unit"], "nominal": d["nominal"], "identified": d["identified"],
                       "deviation": d["deviation"], "std": d["std"], "free": True}
                      for p, d in zip(result.parameters, result.to_dict()["parameters"]) if p.free]
            page = {"status": result.status, "success": result.success, "message": result.message,
                    "meta": meta, "certificate": report["certificate"], "parameters": params,
                    "provenance": provenance,
                    "frames": {"base_frame": frames.base_frame, "tool_frame": frames.tool_frame,
                               "joints": list(robot.joint_names), "written_urdf": frames.to_dict()},
                    "outliers": [{"row": o.row, "position_error_mm": o.position_error * 1e3, "rotation_error_rad": None,
                                  "sigmas": o.sigmas} for o in result.outliers],
                    "predicted_rows": [r for r in (
                        None if report["cross_validation"] is None else (
                            f"touch residual held out by {report['cross_validation']['folds']}-fold cross-validation "
                            f"(RMS per component)", report["cross_validation"]["held_out_rms_mm"], None),
                        (f"tool position at {result.predicted['configurations']} random configurations, after a "
                         f"best-fit registration (noise only)", report["predicted_tool_error_mm"], None)) if r is not None]}
            outputs.stage(out_html, render_html(page, text + verdict, images, title="Touch calibration report"))
        for name, path in plot_paths.items():
            if name in images:
                outputs.stage(path, images[name])
        progress.update()
    return verdict


def _noise_arguments(args, data) -> dict:
    """calibrate's noise levels of touch data from the flags: --sigma-touch-mm (or, in a file
    without measured rows, --sigma-pos-mm) the touch rows', --sigma-pos-mm / --sigma-rot-rad the
    measured rows'; a flag for a group the file does not have is refused."""
    touch = getattr(args, "sigma_touch_mm", None)
    pos, rot = args.sigma_pos_mm, getattr(args, "sigma_rot_rad", None)
    if not data.n_measured:
        if touch is not None and pos is not None:
            raise ParameterError("--sigma-touch-mm and --sigma-pos-mm both give the touch noise of a file without "
                                 "measured rows: give one")
        touch, pos = (touch if touch is not None else pos), None
    if rot is not None and (data.measured is None or data.measured.rotation is None):
        raise ParameterError("--sigma-rot-rad weights measured orientations; this touch file has none")
    mm = (lambda v: None if v is None else v * 1e-3)      # noqa: E731
    return {"sigma_touch": mm(touch), "sigma_pos": mm(pos), "sigma_rot": rot}


# ---------------------------------------------------------------- simulate
def parse_constraints(text: str):
    """``point:N,plane:N,sphere:RADIUS_MM,measured:N`` -> (features (N point ids P1.., N planes
    A.. (faces of one cube, perpendicular in threes), a sphere S1.. of each radius), the number of
    rows measured by an instrument)."""
    from calib.model.touch import MAX_SPHERE_RADIUS_M, Feature
    from calib.model.touch_simulate import MAX_FEATURES, MAX_ROWS

    features = []
    counts = {"point": 0, "plane": 0, "sphere": 0, "measured": 0}
    for part in str(text).split(","):
        kind, sep, value = part.strip().partition(":")
        kind = kind.strip().lower()
        try:
            number = float(value)
        except ValueError:
            number = float("nan")
        if not sep or kind not in counts or not number > 0 or (kind != "sphere" and number != int(number)):
            raise ParameterError(f"--constraint: {part.strip()!r} is not point:N, plane:N, sphere:RADIUS_MM "
                                 f"or measured:N (N a positive count, RADIUS_MM a positive radius in mm)")
        if kind == "measured":
            counts["measured"] += int(number) if number <= MAX_ROWS else MAX_ROWS + 1
            if counts["measured"] > MAX_ROWS:
                raise ParameterError(f"--constraint {text!r}: more than {MAX_ROWS:,} measured rows")
            continue
        if len(features) + (1 if kind == "sphere" else number) > MAX_FEATURES:
            raise ParameterError(f"--constraint {text!r}: {len(features) + (1 if kind == 'sphere' else number):,.0f} "
                                 f"features, at most {MAX_FEATURES} (each is reached by inverse kinematics from "
                                 f"many starts, about a second per feature of 100 rows; a touch calibration "
                                 f"fits 3 unknowns per feature)")
        if kind == "sphere" and number * 1e-3 > MAX_SPHERE_RADIUS_M:
            raise ParameterError(f"--constraint: sphere:{value.strip()} mm is larger than any sphere a robot touches "
                                 f"(at most {MAX_SPHERE_RADIUS_M * 1e3:g} mm)")
        if kind == "sphere":
            counts["sphere"] += 1
            features.append(Feature("sphere", f"S{counts['sphere']}", radius=number * 1e-3))
            continue
        for _ in range(int(number)):
            counts[kind] += 1
            k = counts[kind]
            fid = f"P{k}" if kind == "point" else (chr(ord("A") + k - 1) if k <= 26 else f"F{k}")
            features.append(Feature(kind, fid))
    if not features:
        raise ParameterError(f"--constraint {text!r}: name a point, plane or sphere touched (measured:N "
                             f"rows only mix with touch rows)")
    return features, counts["measured"]


def simulate_touch_file(args, robot, true_robot, rng, outputs, out_csv, described: str, out_truth=None) -> str:
    """``calib simulate --constraint``: stage the touch file of ``true_robot`` (``args.poses`` rows
    per feature) in ``outputs``; returns the lines to print."""
    from dataclasses import replace

    from calib.io.csv.touch import write_touch
    from calib.model.simulate import simulate_measurements
    from calib.model.touch_simulate import simulate_touch

    features, n_measured = parse_constraints(args.constraint)
    from calib.model.touch_simulate import MAX_ROWS

    if args.poses * len(features) > MAX_ROWS:
        raise ParameterError(f"--poses {args.poses} rows for each of {len(features)} features: "
                             f"{args.poses * len(features):,} touch rows, at most {MAX_ROWS:,} per simulation")
    sim = simulate_touch(true_robot, features, [args.poses] * len(features),
                         sigma=args.sigma_pos_mm * 1e-3, rng=rng)
    data = sim.data
    measured_text = ""
    if n_measured:
        meas = simulate_measurements(true_robot, robot.random_configurations(n_measured, rng),
                                     sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad,
                                     position_only=args.position_only, rng=rng)
        data = replace(data, measured=meas)
        measured_text = (f" and {n_measured} rows measured by an instrument ("
                         + ("positions" if args.position_only else f"poses, orientation noise {args.sigma_rot_rad:g} rad")
                         + f", noise {args.sigma_pos_mm:g} mm per axis)")
    comment = (f"Simulated by: {command_line(args)}\nTrue model: {args.robot} with deviations from "
               f"{described}; touch noise {args.sigma_pos_mm:g} mm per axis; {args.poses} rows per feature"
               + measured_text + (f"; features and measured rows in a frame where the base frame is at "
                                  f"{args.meas_frame} (mm, deg)" if getattr(args, "meas_frame", None) else ""))
    outputs.stage_from_file(out_csv, lambda p: write_touch(p, data, robot, comment=comment))
    lines = [f"Simulated {sim.data.n_rows} touch rows{measured_text} of {args.robot} -> {out_csv}",
             f"  {len(features)} features ({', '.join(f'{f.kind} {f.id}' for f in features)}), {args.poses} rows "
             f"each, reached by the true model within the joint limits; seed {args.seed}; touch noise "
             f"{args.sigma_pos_mm:g} mm per axis", f"  true model: deviations from {described}"
             + (f", written to {out_truth}" if out_truth else "")]
    F = sim.truth.reshape(-1, 3)
    for k, f in enumerate(features):
        if f.kind == "plane":
            n = sim.normals[k]
            lines.append(f"  plane {f.id}: normal ({n[0]:.6f}, {n[1]:.6f}, {n[2]:.6f}), offset {F[k, 2] * 1e3:.4f} mm")
        else:
            lines.append(f"  {f.kind} {f.id}: {'centre' if f.kind == 'sphere' else 'at'} "
                         f"({', '.join(f'{x * 1e3:.4f}' for x in F[k])}) mm")
    return "\n".join(lines)


__all__ = ["run_touch", "parse_constraints", "simulate_touch_file"]
