"""``calib calibrate ROBOT.urdf MEAS.csv -o CALIBRATED.urdf``: identify the parameters, write the
calibrated URDF (and the report, plots, HTML and compliance sidecar asked for)."""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from calib.cli.inputs import add_bag, add_robot, bag_file, check_measurement_input, load, read_bag_args
from calib.cli.args import (HelpFormatter, add_compliance, add_file_format, add_frames, add_progress, add_report_options, add_verbose, check_measurement_link, compliance_options, count, parse_meta, positive, progress_enabled, read)
from calib.cli.output import Outputs, json_text, refuse_implausible, status_exit
from calib.cli.progress import working
from calib.errors import DataError, ParameterError

__all__ = ["add_parser", "run"]

log = logging.getLogger(__name__)

_CAL_DESC = """\
Identify a robot's TM-MDH parameters from measured tool poses and write the calibrated URDF.

Reads the nominal model from ROBOT.urdf and the measurements (CSV, see `calib formats`: joint values
and the tool pose in the base frame of the URDF, which plays the measurement frame). Rows with
set=val, and the rows of --validate, are held out for validation. Prints the parameter table
(nominal, identified, deviation, standard deviation; mm and rad) and the accuracy before and
after calibration (mean, RMS, max, min of the position error in mm and the orientation error in
rad, as the paper's Tables 10-11), then writes the calibrated URDF: a copy of ROBOT.urdf with the
joint origins that carry the kinematics recomputed, so that its forward kinematics equal the
calibrated model's.

Noise: without --sigma-pos-mm / --sigma-rot-rad the noise levels are estimated from the
residuals (variance-component estimation iterated with the fit) and printed; given ones are
honoured and a chi-square test says whether the residuals agree with them. The printed
"predicted RMS error on new measured rows" is what to expect on rows not used in the fit; the
cross-validated error (--cv K, when there are no validation rows) measures it.

--params:
  auto   nested candidate sets (joint offsets + frames; + lengths; + twists; the identifiable
         set, each its own maximal identifiable subset) compared by K-fold cross-validation, the
         lowest score chosen (default when the data hold under 10 residuals per identifiable
         parameter)
  base   the identifiable set at these poses (the default otherwise): redundant partners held
         at nominal
  paper  all but u_z, u_alpha, v_x, v_z, v_alpha, v_gamma (the paper's Section 4.2)
  all    every parameter; combinations the data do not determine stay where they start
  LIST   comma-separated parameter names, e.g. theta2,d2,a2,alpha2,beta2

Exit codes: 0 converged; 3 the fit did not converge or stopped in a local minimum (outputs
written for inspection, status on stderr); 2 bad input (nothing written)."""

_CAL_EPILOG = """\
examples:
  calib calibrate robots/brtirus0707a/brtirus0707a.urdf examples/brtirus0707a/measurements.csv \\
      -o calibrated.urdf --report report.json --plots plots
  calib calibrate robot.urdf meas.csv -o calibrated.urdf --method lm --params paper \\
      --sigma-pos-mm 0.05 --validate val.csv
  calib calibrate robot.urdf joints.csv --tracker export.csv --key Point \\
      --target-from '(?P<key>P\\d+)_(?P<target>SMR\\d+)' -o calibrated.urdf
      (a tracker export of 3 reflectors per pose, points P001_SMR1 ..., joined to the
      controller's joints.csv by its Point column P001 ...)
  calib calibrate robot.urdf log.csv --tracker timed.csv --join nearest-time --time time_s \\
      --max-gap 0.005 -o calibrated.urdf
      (a 100 Hz joint log and the tracker's timed measurements, by the nearest time)

Units: the measurement CSV carries its units in its column names (joint1_deg, x_mm, ...); the
noise sigmas weight position against orientation residuals (mm and rad per axis)."""


def _outlier_k(text: str) -> float | None:
    if text.strip().lower() == "off":
        return None
    return positive(text)



def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``calibrate`` to ``subparsers`` (from ``add_subparsers``); it runs :func:`run`."""
    from calib.choices import ESTIMATORS, LM_VARIANTS, LOSSES, METHODS

    p = subparsers.add_parser("calibrate", help="identify the parameters, write the calibrated URDF",
                       description=_CAL_DESC, epilog=_CAL_EPILOG, formatter_class=HelpFormatter)
    add_robot(p)
    p.add_argument("measurements", metavar="MEAS.csv", nargs="?", default=None,
                   help="measurement CSV (format: calib formats, docs/formats.md); or a ROS bag with --bag")
    p.add_argument("-o", "--output", required=True, metavar="CALIBRATED.urdf",
                   help="calibrated URDF to write (must differ from ROBOT.urdf)")
    p.add_argument("--method", choices=METHODS, default="search-lm",
                   help="search-lm: closed-form search of the angles on the rotation data, then LM "
                        "(converges from the largest errors); c-lm: the paper's cross-identification "
                        "scheme run with calib's LM (not the paper's Eq. 27-28; --lm-variant paper for "
                        "that); lm: calib's Levenberg-Marquardt alone (lm and c-lm exit 3 when they "
                        "stop in a local minimum)")
    p.add_argument("--lm-variant", choices=LM_VARIANTS, default="calib",
                   help="calib: calib's LM (default); paper: the LM of the paper's Eq. (27)-(28) as "
                        "printed (mu I, mu reset to 0.001 lambda^+-1, unweighted mm/rad residuals), "
                        "for --method lm or c-lm")
    p.add_argument("--estimator", choices=ESTIMATORS, default="auto",
                   help="map: regularised identification (EB-MAP: every structural parameter under a "
                        "prior centred on the URDF, its scale per group and the noise from the "
                        "evidence); ls: least squares on a parameter set (--params); auto (default): "
                        "map when the rows hold fewer than 10 residual components per identifiable "
                        "parameter and no --params, --loss or --compliance is given, else ls")
    p.add_argument("--params", default=None, metavar="auto|base|paper|all|LIST",
                   help="which parameters to identify by least squares (see above); default: base, "
                        "or with --estimator ls on few rows auto")
    p.add_argument("--sigma-pos-mm", type=positive, default=None, metavar="S",
                   help="position measurement noise per axis, mm (weights the residuals); default: "
                        "estimated from the residuals")
    p.add_argument("--sigma-rot-rad", type=positive, default=None, metavar="S",
                   help="orientation measurement noise per axis, rad (weights the residuals); "
                        "default: estimated from the residuals")
    p.add_argument("--cv", type=count, default=5, metavar="K",
                   help="K-fold cross-validated held-out error when there are no validation rows "
                        "(0: off)")
    p.add_argument("--loss", choices=LOSSES, default="linear",
                   help="linear: least squares (Gaussian noise); huber or soft_l1: robust to "
                        "outliers, applied to each pose's noise-weighted residual")
    p.add_argument("--outlier-k", type=_outlier_k, default=5.0, metavar="K|off",
                   help="after the fit, drop calibration rows whose residual exceeds K sigma and "
                        "fit again (listed in the report); off disables")
    p.add_argument("--accept-implausible", action="store_true",
                   help="write the outputs of a calibration whose checks find it implausible (errors no "
                        "robot and instrument give, residuals far beyond given noise levels, inconsistent "
                        "data), for inspection; without it such a calibration writes nothing (exit 3)")
    p.add_argument("--validate", metavar="VAL.csv", default=None,
                   help="more validation measurements (all rows held out), same format")
    p.add_argument("--report", metavar="REPORT.json", default=None,
                   help="write the full result as JSON (lengths in mm, angles in rad): status, "
                        "before, after, validation, parameters, certificate, per-row residuals, ...")
    p.add_argument("--plots", metavar="DIR", default=None,
                   help="write PNG plots into DIR (created if missing; its parent must exist): the "
                        "per-row errors before and after, their histograms, the error over the "
                        "workspace")
    p.add_argument("--html", metavar="REPORT.html", default=None,
                   help="write one self-contained HTML report, a calibration certificate (identity, "
                        "verdict, accuracy, per-axis and ISO 9283 tables, parameters with expanded "
                        "uncertainties, plots; no external links) for a person or a customer "
                        "(docs/certificate.md)")
    add_report_options(p)
    add_progress(p)
    p.add_argument("--probe-radius-mm", type=positive, default=None, metavar="R",
                   help="touch files (rows naming point, plane or sphere, docs/touch.md): the ball tip's "
                        "radius for plane rows")
    p.add_argument("--sigma-touch-mm", type=positive, default=None, metavar="S",
                   help="touch files: the touch noise per residual component, mm (default: estimated; "
                        "in a file without measured rows --sigma-pos-mm gives it too)")
    p.add_argument("--nominal-scale", action="store_true",
                   help="touch files with no known length (points and planes, no sphere, no measured "
                        "row): hold the robot's scale at the nominal instead of refusing the full model "
                        "(the accuracy then holds up to scale)")
    p.add_argument("--measurement-link", default=None, metavar="NAME",
                   help="when the calibration estimates the measurement frame (a tracker's), also write "
                        "it into CALIBRATED.urdf as a new root link NAME with a fixed joint "
                        "NAME_to_<root> whose child is the URDF's root link (the robot's base frame "
                        "stays where it was; docs/model.md, Frames and units)")
    add_file_format(p, tracker=True)
    add_bag(p)
    add_frames(p)
    g = add_compliance(p, "calibrate")
    g.add_argument("--periodic", action="store_true",
                   help="periodic joint errors: coefficients of sin q, cos q, sin 2q, cos 2q added to each "
                        "revolute joint's angle (rad), identified with the geometry (into the sidecar "
                        "CALIBRATED.compliance.json; evaluate and compensate --compliance read it)")
    g.add_argument("--terms", choices=("auto", "none"), default="auto",
                   help="auto (default): compliance (when the URDF has real link masses) and periodic errors "
                        "chosen by cross-validated held-out error on data with many rows per parameter "
                        "(20 residual components or more per parameter of the largest candidate; a note "
                        "gives the table); none: only --compliance / --periodic")
    add_verbose(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib calibrate`` with parsed arguments; returns the exit code."""
    from calib.cli.args import is_touch_input

    if is_touch_input(args):        # rows naming the point, plane or sphere touched (issue 24)
        from calib.cli.touch import run_touch

        return run_touch(args)
    if not (args.plots or args.html):
        return _calibrate(args, None)
    from calib.cli.plot_worker import PlotWorker

    # the plots' process imports matplotlib while this one reads and calibrates (stopped on every path)
    with PlotWorker() as plots:
        return _calibrate(args, plots)


def _outputs(args: argparse.Namespace):
    """The outputs of a calibration of measured rows, their options checked before any work:
    (the Outputs set, the URDF, the JSON report, the HTML page (each or None), the plots' paths,
    the report's identity fields)."""
    from calib.io.urdf.reader import robot_path

    _refuse_touch_options(args)
    outputs = Outputs([robot_path(args.robot), args.measurements, args.validate, args.tracker, args.bag])
    out_urdf = outputs.add(args.output)
    out_report = outputs.add(args.report) if args.report else None
    meta = parse_meta(args.meta)
    if args.report is None and args.html is None:
        for given, name in ((args.meta, "--meta"), (args.tolerance_mm, "--tolerance-mm")):
            if given is not None:
                raise ParameterError(f"{name} applies to the report: give --report REPORT.json or --html REPORT.html")
    if args.residuals != "auto" and args.report is None:
        raise ParameterError("--residuals applies to --report REPORT.json")
    out_html = outputs.add(args.html) if args.html else None
    plot_paths = {}
    if args.plots:
        from calib.report.build import PLOT_FILES

        plot_paths = outputs.add_folder(args.plots, PLOT_FILES, "--plots")
    return outputs, out_urdf, out_report, out_html, plot_paths, meta


def _calibrate(args: argparse.Namespace, plots) -> int:
    """:func:`run` of measured rows; ``plots``: the :class:`calib.cli.plot_worker.PlotWorker` that
    draws the plots of --plots and --html (None without them)."""
    import calib
    from calib.io.urdf.writer import check_writable

    outputs, out_urdf, out_report, out_html, plot_paths, meta = _outputs(args)
    robot, kinematics = _load_robot(args, outputs, out_urdf)
    payload, gravity = compliance_options(args)
    if (payload is not None or gravity is not None) and not args.compliance:
        raise ParameterError("--payload-kg and --gravity only matter with --compliance")
    from calib.io.compliance_file import sidecar_path

    # (reserved always: written when the model has joint terms, an earlier one removed otherwise)
    out_sidecar = outputs.add(sidecar_path(out_urdf))
    frames = check_writable(robot)     # what cannot be written is refused before the fit
    check_measurement_link(args.measurement_link, robot)
    log.info("the calibrated URDF will hold tool frame %r in base frame %r", frames.tool_frame,
             frames.base_frame)
    meas = read(args.measurements, robot, args, args.tracker) if args.bag is None else read_bag_args(args, robot)
    validation = read(args.validate, robot, args, joined=False) if args.validate else None
    out_residuals = None
    if out_report is not None:
        from calib.report.build import INLINE_RESIDUALS_MAX

        n_rows = meas.n_poses + (validation.n_poses if validation is not None else 0)
        if args.residuals == "csv" or args.residuals == "auto" and n_rows > INLINE_RESIDUALS_MAX:
            out_residuals = outputs.add(residuals_path(out_report))
    log.info("calibrating: method %s, parameter set %s, %d calibration rows", args.method,
             args.params or f"default (estimator {args.estimator})", meas.calibration().n_poses)
    try:
        with working(f"calibrating ({args.method})", logger=log, enabled=progress_enabled(args)) as line:
            result = calib.calibrate(robot, meas, method=args.method, params=args.params, progress=line.fraction,
                                     sigma_pos=None if args.sigma_pos_mm is None else args.sigma_pos_mm * 1e-3,
                                     sigma_rot=args.sigma_rot_rad, validation=validation, loss=args.loss,
                                     outlier_k=args.outlier_k, cv=args.cv, compliance=args.compliance,
                                     payload=payload, gravity=gravity, lm_variant=args.lm_variant,
                                     estimator=args.estimator, periodic=args.periodic, terms=args.terms)
    except DataError as exc:  # about the data as a whole (too few poses): name the file
        if str(exc).startswith(str(args.measurements or args.bag)):
            raise
        raise DataError(f"{args.measurements or args.bag}: {exc}") from None
    log.info("calibration: %s after %d iterations, %.3f s", result.status, result.iterations,
             result.wall_time)
    if result.status == "implausible" and not args.accept_implausible:
        return refuse_implausible(result.format(), result.message)   # nonsense is not written

    if args.measurement_link is not None and result.measurement_frame is None:
        raise ParameterError(f"--measurement-link {args.measurement_link}: the calibration did not estimate "
                             f"a measurement frame (the measurements are taken as given in the robot's base "
                             f"frame {robot.base_frame!r}); nothing written")
    urdf_text, frames = result.urdf_text(measurement_link=args.measurement_link)
    outputs.stage(out_urdf, urdf_text)
    out_kinematics, kinematics_line = kinematics(urdf_text)
    if out_sidecar is not None and result.robot.has_joint_terms:
        outputs.stage(out_sidecar, json_text(result.compliance_record()))
    stale = None
    if not result.robot.has_joint_terms and out_sidecar.exists():
        # an earlier calibration's joint terms beside the new geometry-only URDF would be read
        # with it (evaluate's note, compensate --compliance): it goes with the new outputs
        outputs.remove(out_sidecar)
        stale = out_sidecar
    out_sidecar = out_sidecar if result.robot.has_joint_terms else None
    text = result.format()
    images = {}
    if plot_paths or out_html is not None or out_report is not None:
        text += _report_stage(args, result, meas, validation, outputs, meta=meta, plot_paths=plot_paths,
                              out_report=out_report, out_html=out_html, out_residuals=out_residuals,
                              out_urdf=out_urdf, frames=frames, images=images, plots=plots)
    outputs.commit()

    written = [out_urdf] + [p for p in (out_kinematics, out_sidecar, out_report, out_residuals, out_html) if p] + \
              [p for p in plot_paths.values() if p in outputs.data]
    sys.stdout.write(text + "\n\nwrote " + ", ".join(str(p) for p in written) + "\n"
                     + f"{out_urdf}: calibrated kinematics of tool frame {frames.tool_frame!r} in "
                       f"base frame {frames.base_frame!r} (standing for {frames.nominal_tool_frame!r} "
                       f"and {frames.nominal_base_frame!r} of {args.robot}; evaluate and compensate "
                       f"use them by default)\n" + _targets_line(out_urdf, frames) + kinematics_line)
    if stale is not None:
        sys.stdout.write(f"removed {stale}: an earlier calibration's joint terms, which this geometry-only "
                         f"calibration does not have\n")
    return status_exit(result.status, result.message)



def _refuse_touch_options(args) -> None:
    for flag, value in (("--probe-radius-mm", args.probe_radius_mm), ("--sigma-touch-mm", args.sigma_touch_mm),
                        ("--nominal-scale", args.nominal_scale or None)):
        if value is not None:
            raise ParameterError(f"{flag} applies to touch files (rows naming point, plane or sphere)")
    check_measurement_input(args)


def kinematics_path(out_urdf: Path) -> Path:
    """CALIBRATED.kinematics.yaml beside CALIBRATED.urdf: the calibrated parameter file of a xacro
    that takes its kinematics from one."""
    return out_urdf.with_name(out_urdf.stem + ".kinematics.yaml")


def _load_robot(args, outputs, out_urdf):
    """The robot of ``args`` (:func:`calib.cli.inputs.load`) and a function that, given the calibrated
    URDF's text, stages the calibrated parameter file of a xacro that takes its kinematics from one
    (the UR case: ur_description's default_kinematics.yaml, :func:`kinematics_path`) and returns
    (its path, the line to print), or (None, "") for any other description. A chain that cannot be
    written in the file is refused here, before the fit."""
    from calib.cli.args import print_notes
    from calib.cli.inputs import robot_description
    from calib.io.urdf.xacro_file import XacroText

    description = robot_description(args, args.robot)
    robot = load(args, description)
    source = description.kinematics_file() if isinstance(description, XacroText) else None
    if source is None:
        return robot, lambda urdf_text: (None, "")
    from calib.errors import CalibError
    from calib.io.exports.export import export_calibration
    from calib.io.urdf.reader import UrdfText

    outputs.inputs.append(source)                 # (never overwritten)
    out = outputs.add(kinematics_path(out_urdf))
    try:
        export_calibration(description, "ur-yaml", base_frame=robot.base_frame, tool_frame=robot.tool_frame)
    except CalibError as exc:
        raise ParameterError(f"{args.robot} takes its kinematics from {source} (a UR kinematics file), and the "
                             f"calibration of {robot.tool_frame!r} in {robot.base_frame!r} cannot be written in one: "
                             f"{exc}") from None
    # (the argument that named it: xacro reads a relative path from the xacro's folder)
    arg = next((name for name, value in description.args
                if value and source in ((description.path.parent / value).resolve(), Path(value).resolve())), None)

    def stage(urdf_text: str):
        exported = export_calibration(UrdfText(path=description.path, text=urdf_text), "ur-yaml")
        outputs.stage(out, exported.text)
        print_notes(f"{out}: {note}" for note in exported.notes)
        where = out.resolve()           # (absolute: xacro reads a relative path from the xacro's folder)
        how = f"--xacro-arg {arg}:={where} (xacro {arg}:={where})" if arg else f"it in place of {source}"
        return out, (f"{out}: the calibrated kinematics, in the format of {source}, which {args.robot} reads; "
                     f"expand {args.robot} with {how} for the calibrated robot in ROS\n")
    return robot, stage


def _targets_line(out_urdf, frames) -> str:
    """The line saying where a calibration of several targets put them ("" without targets)."""
    if not frames.targets:
        return ""
    links = ", ".join(f"{link} ({t})" for t, link in frames.targets)
    tool = frames.tool_frame
    return (f"{out_urdf}: {tool!r} stays at the flange, the targets are fixed links under it at their identified "
            f"offsets: {links}; the flange's place along the last joint's axis, its turn about it and its offset "
            f"and tilt from it are the nominal ones (targets cannot tell them from their own offsets); compensate "
            f"aims {tool!r} or a tool on it (--tool-offset, --tool-frame)\n")


def residuals_path(report: Path) -> Path:
    """REPORT.residuals.csv beside REPORT.json."""
    return report.with_name(report.stem + ".residuals.csv")


def _report_stage(args, result, meas, validation, outputs, *, meta, plot_paths, out_report, out_html,
                  out_residuals, out_urdf, frames, images: dict, plots) -> str:
    """Stage the plots (drawn by the worker ``plots`` while the JSON report is built), JSON report
    (and its residuals CSV) and HTML page, with a progress line (fraction, time left); fills
    ``images``; returns the verdict line for the printed text ("" without --tolerance-mm)."""
    from calib.report.build import (build_report, render_html, report_json_text, report_rows_of,
                                          residuals_csv_chunks)
    from calib.cli.args import meta_inputs
    from calib.cli.progress import Progress, stage

    want_plots = bool(plot_paths) or out_html is not None
    steps = 1 + (5 if want_plots else 0) + (out_report is not None or out_html is not None) \
        + (out_residuals is not None) + (out_html is not None)
    with Progress(steps, "writing the report", enabled=progress_enabled(args)) as progress, \
            stage(log, "report"):
        rows = report_rows_of(result, meas, validation)
        if want_plots:
            plots.submit(rows, tolerance_m=None if args.tolerance_mm is None else args.tolerance_mm * 1e-3)
        progress.update()
        report = build_report(
            result, meas, validation, command_line=["calib", *args.argv],
            inputs={"robot": robot_path_of(args), "measurements": args.measurements or bag_file(args.bag), "tracker": args.tracker,
                    "validation": args.validate, **meta_inputs(args.meta)},
            outputs={"calibrated_urdf": out_urdf, "report": out_report, "html": out_html,
                     "residuals": out_residuals},
            frames={"written_urdf": frames.to_dict()}, meta=meta, tolerance_mm=args.tolerance_mm,
            residuals=out_residuals.name if out_residuals is not None else
            ("none" if args.residuals == "none" else "json"), rows=rows)
        progress.update()
        if out_report is not None:
            outputs.stage(out_report, report_json_text(report))
        if out_residuals is not None:
            outputs.stage(out_residuals, residuals_csv_chunks(rows))
            progress.update()
        verdict = ""
        tol = report["certificate"]["tolerance"]
        if tol is not None and tol["pass"] is None:     # fit residuals only: no verdict
            verdict = (f"\ntolerance {tol['tolerance_mm']:g} mm: no verdict (no verification rows: --validate "
                       f"VAL.csv, or rows with set=val); fit residuals: largest {tol['max_mm']:.4g} mm over {tol['n']} "
                       f"{tol['rows']}, {tol['beyond']} beyond")
        elif tol is not None:
            verdict = (f"\ntolerance {tol['tolerance_mm']:g} mm: {'PASS' if tol['pass'] else 'FAIL'} (largest "
                       f"position error {tol['max_mm']:.4g} mm over {tol['n']} {tol['rows']}; {tol['beyond']} beyond)")
        if want_plots:
            if out_html is not None:
                from calib.report.html import load_template

                load_template()          # (while the plots are drawn)
            done = progress.done
            images.update(plots.images(progress=lambda k, n: progress.set(done + round(5 * k / n))))
            progress.set(done + 5)
        if out_html is not None:
            outputs.stage(out_html, render_html(report, result.format() + verdict, images))
            progress.update()
    for name, path in plot_paths.items():
        if name in images:
            outputs.stage(path, images[name])
    return verdict


def robot_path_of(args):
    from calib.io.urdf.reader import robot_path

    return robot_path(args.robot)
