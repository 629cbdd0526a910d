"""``calib evaluate ROBOT.urdf MEAS.csv``: accuracy of a model against measurements."""
from __future__ import annotations

import argparse
import sys

from calib.cli.inputs import (add_bag, add_robot, bag_file, check_measurement_input, load, read_bag_args, robot_description)
from calib.cli.args import (COMMON_EPILOG, HelpFormatter, add_compliance, add_file_format, add_frames, add_progress, add_report_options, add_verbose, parse_meta, read, with_compliance_file)
from calib.cli.output import EXIT_OK, PROG, json_text
from calib.errors import ParameterError

__all__ = ["add_parser", "run"]

_EVAL_DESC = """\
Accuracy of a robot model against measurements: mean, RMS, max and min of the tool position
error (mm) and orientation error (rad, the angle of R_model R_measured^T), over all rows and,
when the file has a set column, over the cal and val rows apart. Give it the nominal URDF to see
the error before calibration, the calibrated one to see it after: a calibrated URDF records its
base and tool frames (and the nominal frames they stand for), so the same options as for
`calibrate` (or none) measure the same frames and reproduce calibrate's numbers.

Joint compliance: a calibration made with --compliance keeps its compliances in
CALIBRATED.compliance.json beside the URDF (the URDF holds the geometry only). --compliance FILE
(that sidecar, or calibrate's --report JSON) applies them, with the payload and gravity of the
calibration unless --payload-kg / --gravity say otherwise, as `compensate --compliance` does; a
note on stderr says so. The gravity torques come from the inertias of ROBOT.urdf, or of
--nominal NOMINAL.urdf, the URDF calibrate started from: with it the numbers are calibrate's to
rounding. Without --compliance the accuracy is of the geometry alone (a note says so when a
sidecar lies beside ROBOT.urdf)."""

_EVAL_EPILOG = """\
examples:
  calib evaluate robots/brtirus0707a/brtirus0707a.urdf examples/brtirus0707a/measurements.csv
  calib evaluate calibrated.urdf examples/brtirus0707a/measurements.csv --json
  calib evaluate cal.urdf meas.csv --compliance cal.compliance.json --nominal ur10
  calib evaluate cal.urdf check.csv --html check.html --plots check_plots --tolerance-mm 0.5 \\
      --meta robot_serial=R123,instrument=AT960,operator=J.Doe
""" + COMMON_EPILOG



def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``evaluate`` to ``subparsers`` (from ``add_subparsers``); it runs :func:`run`."""
    p = subparsers.add_parser("evaluate", help="accuracy of a model against measurements",
                       description=_EVAL_DESC, epilog=_EVAL_EPILOG, formatter_class=HelpFormatter)
    add_robot(p)
    p.add_argument("measurements", metavar="MEAS.csv", nargs="?", default=None,
                   help="measurement CSV (format: calib formats, docs/formats.md); or a ROS bag with --bag")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: n_poses, position_mm and rotation_rad statistics "
                        "(mean, rms, max, min) for all, cal and val rows")
    p.add_argument("--html", metavar="REPORT.html", default=None,
                   help="write one self-contained HTML accuracy report (identity, verdict, accuracy, "
                        "per-axis and ISO 9283 tables, plots) of this model against these measurements")
    p.add_argument("--plots", metavar="DIR", default=None,
                   help="write PNG plots of the per-row errors, their histogram and the error over the "
                        "workspace into DIR (created if missing; its parent must exist)")
    add_report_options(p, residuals=False)
    add_progress(p)
    add_file_format(p, tracker=True)
    add_bag(p)
    add_frames(p)
    g = add_compliance(p, "evaluate")
    g.add_argument("--nominal", metavar="NOMINAL.urdf", default=None,
                   help="with --compliance: the nominal URDF of the calibration, whose inertias give "
                        "the gravity torques as in calibrate (reproduces its numbers exactly); "
                        "default: ROBOT.urdf's (its calibrated geometry moves the torques by ~1e-3 "
                        "of themselves, sub-micrometre at the tool); required for a calibration of "
                        "several targets")
    add_verbose(p)
    p.set_defaults(func=run)
    return p


def _evaluate_compliance(robot, args):
    """``robot`` with the compliances of --compliance (torques from --nominal's URDF if given,
    else from ROBOT.urdf's), and the stderr note that says so; without --compliance, a note when
    a compliance sidecar lies beside ROBOT.urdf (its accuracy is then geometry-only)."""
    from calib.io.compliance_file import sidecar_path

    nominal = None
    if args.nominal is not None:
        if args.compliance is None:
            raise ParameterError("--nominal only matters with --compliance (it gives the gravity torques)")
        from calib.compensation.compensate import nominal_frames

        base, tool = nominal_frames(robot, base_frame=args.base_frame, tool_frame=args.tool_frame)
        from calib.io.urdf.reader import load_robot

        nominal = load_robot(robot_description(args, args.nominal), base_frame=base, tool_frame=tool)
    elif args.compliance is not None and robot.targets:
        raise ParameterError(f"--compliance: {args.robot} holds {robot.n_targets} targets and its tool "
                             f"frame is target {robot.targets[0]}'s, not the tool the payload was given "
                             f"in: give --nominal NOMINAL.urdf (the URDF calibrate started from) for "
                             f"the gravity torques")
    robot = with_compliance_file(robot, args, torques_from=nominal,
                                 hint=" (the report or the compliance sidecar of the calibration)")
    if args.compliance is not None and robot.has_periodic:
        largest = max(abs(v) for v in robot.periodic_values()) * 1e6
        sys.stderr.write(f"{PROG}: note: periodic joint errors of {args.compliance} applied "
                         f"({len(robot.periodic_names)} coefficients, the largest {largest:.4g} urad)\n")
    if args.compliance is not None and robot.has_compliance:
        from calib.units import DISPLAY_UNITS

        gm = robot.gravity
        units = [DISPLAY_UNITS[robot.parameters[robot.index(n)].unit] for n in robot.compliance_names]
        one_unit = len({u for u, _ in units}) == 1       # else (prismatic joints) a unit each
        values = [f"{n} {robot.value(n) * f:.4g}" + ("" if one_unit else f" {u}")
                  for n, (u, f) in zip(robot.compliance_names, units)]
        unit = f" {units[0][0]}" if one_unit else ""
        load = (f"payload {gm.payload.mass:g} kg" if gm.payload is not None and gm.payload.mass > 0
                else "no payload")
        source = args.nominal if nominal is not None else args.robot
        sys.stderr.write(f"{PROG}: note: joint compliance of {args.compliance} applied "
                         f"({', '.join(values)}{unit}; {load}, gravity "
                         f"({', '.join(f'{g:g}' for g in gm.gravity)}) m/s^2; torques from the "
                         f"inertias of {source})\n")
    elif robot.urdf_path is not None and sidecar_path(robot.urdf_path).is_file():
        sys.stderr.write(f"{PROG}: note: {sidecar_path(robot.urdf_path)} holds joint compliances; "
                         f"this accuracy is of the geometry alone (--compliance "
                         f"{sidecar_path(robot.urdf_path)} applies them)\n")
    return robot



def _in_measurement_frame(robot, args):
    """``robot`` with its tool poses in the measurement frame its calibrated URDF records
    (``<calib:measurement>``: a calibration that estimated a tracker's frame), when no
    --base-frame is given, with a note on stderr; ``robot`` itself otherwise."""
    doc = None if robot.source is None else robot.source.document
    rec = None if doc is None else doc.frames
    if args.base_frame is not None or rec is None or rec.measurement_transform is None \
            or robot.base_frame != rec.base_frame:
        return robot
    from dataclasses import replace

    sys.stderr.write(f"{PROG}: note: poses compared in the measurement frame {args.robot} records (the "
                     f"tracker's, estimated by the calibration); --base-frame {rec.base_frame} compares "
                     f"them in the robot's base frame\n")
    return replace(robot, T_meas_base_ref=rec.measurement_transform @ robot.T_meas_base_ref)


def run(args: argparse.Namespace) -> int:
    """Run ``calib evaluate`` with parsed arguments; returns the exit code."""
    if not (args.plots or args.html):
        return _evaluate(args, None)
    from calib.cli.plot_worker import PlotWorker

    # the plots' process imports matplotlib while this one reads and evaluates (stopped on every path)
    with PlotWorker() as plots:
        return _evaluate(args, plots)


def _evaluate(args: argparse.Namespace, plots) -> int:
    """:func:`run`; ``plots``: the :class:`calib.cli.plot_worker.PlotWorker` that draws the plots
    of --plots and --html (None without them)."""
    import numpy as np

    import calib
    from calib.calibration.accuracy.errors import format_accuracy_table
    from calib.cli.output import Outputs
    from calib.io.urdf.reader import robot_path

    check_measurement_input(args)
    source = args.measurements or args.bag
    outputs = Outputs([robot_path(args.robot), args.measurements, args.tracker, args.compliance, args.nominal, args.bag])
    out_html = outputs.add(args.html) if args.html else None
    plot_paths = {}
    if args.plots:
        from calib.report.plots import PLOT_FILES

        plot_paths = outputs.add_folder(args.plots, PLOT_FILES, "--plots")
    meta = parse_meta(args.meta)
    if out_html is None and (args.meta is not None or args.tolerance_mm is not None):
        raise ParameterError("--meta and --tolerance-mm apply to the report: give --html REPORT.html")
    robot = _evaluate_compliance(_in_measurement_frame(load(args), args), args)
    from calib.cli.args import is_touch_input

    if args.key is None and is_touch_input(args):     # (a joint file's key column may be named point)
        raise ParameterError(f"{args.measurements}: a touch file (rows naming a point, plane or sphere): evaluate "
                             f"compares measured poses; calib calibrate ROBOT.urdf {args.measurements} reports "
                             f"its touch residuals")
    meas = read(args.measurements, robot, args, args.tracker) if args.bag is None else read_bag_args(args, robot)
    rows = [("all rows", calib.evaluate(robot, meas))]
    if meas.sets is not None:
        for label, part in (("calibration rows (cal)", meas.calibration()),
                            ("validation rows (val)", meas.validation())):
            if part.n_poses:
                rows.append((label, calib.evaluate(robot, part)))
    per_target = []     # several targets: each target's rows too
    if len(meas.target_ids) > 1:
        per_target = [(t, calib.evaluate(robot, meas.subset(np.array(meas.target) == t))) for t in meas.target_ids]
    if out_html is not None or plot_paths:
        _write_report(args, robot, meas, outputs, out_html, plot_paths, meta, plots)
    if args.json:
        keys = {"all rows": "all", "calibration rows (cal)": "cal", "validation rows (val)": "val"}
        out = {"robot": str(args.robot), "measurements": str(source),
               "base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
               "joints": list(robot.joint_names),
               "compliance": None if args.compliance is None else str(args.compliance)}
        out.update({keys[label]: s.to_dict() for label, s in rows})
        if per_target:
            out["targets"] = {t: s.to_dict() for t, s in per_target}
        sys.stdout.write(json_text(out))
        return EXIT_OK
    sys.stdout.write(f"Accuracy of {args.robot} (tool frame {robot.tool_frame!r} in base frame "
                     f"{robot.base_frame!r}) against {source}:\n\n"
                     + format_accuracy_table(rows + [(f"target {t}", st) for t, st in per_target]) + "\n"
                     + getattr(args, "_verdict", "")
                     + ("".join(f"wrote {p}\n" for p in getattr(args, "_written", []))))
    return EXIT_OK


def _write_report(args, robot, meas, outputs, out_html, plot_paths, meta, plots) -> None:
    """Plots (drawn by the worker ``plots`` while the report is built) and the HTML accuracy
    report, staged and committed with a progress line; the verdict line and the written paths
    are kept on ``args`` for the printed text."""
    from calib.report.build import build_accuracy_report, render_html
    from calib.report.html import load_template
    from calib.report.rows import report_rows
    from calib.cli.progress import Progress
    from calib.io.urdf.reader import robot_path

    from calib.cli.args import meta_inputs, progress_enabled

    with Progress(7, "writing the report", enabled=progress_enabled(args)) as progress:
        rows = report_rows(robot, meas, validation_rows="none")
        plots.submit(rows, tolerance_m=None if args.tolerance_mm is None else args.tolerance_mm * 1e-3)
        progress.update()
        report = build_accuracy_report(robot, meas, command_line=["calib", *args.argv],
                                       inputs={"robot": robot_path(args.robot), "measurements": args.measurements or bag_file(args.bag),
                                               "tracker": args.tracker, **meta_inputs(args.meta)},
                                       meta=meta, tolerance_mm=args.tolerance_mm, residuals="none", rows=rows)
        tol = report["certificate"]["tolerance"]
        args._verdict = "" if tol is None else (
            f"tolerance {tol['tolerance_mm']:g} mm: {'PASS' if tol['pass'] else 'FAIL'} (largest position error "
            f"{tol['max_mm']:.4g} mm over {tol['n']} rows; {tol['beyond']} beyond)\n")
        if out_html is not None:
            load_template()              # (while the plots are drawn)
        images = plots.images(progress=lambda k, n: progress.set(1 + round(5 * k / n)))
        if out_html is not None:
            text = (f"Accuracy of {args.robot} (tool frame {robot.tool_frame!r} in base frame {robot.base_frame!r}) "
                    f"against {args.measurements or args.bag}")
            outputs.stage(out_html, render_html(report, text, images))
        for name, path in plot_paths.items():
            if name in images:
                outputs.stage(path, images[name])
        progress.set(7)
    outputs.commit()
    args._written = [p for p in outputs.paths if p in outputs.data]
