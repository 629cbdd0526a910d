"""The ``calib`` command: a thin layer over the Python API, one subcommand per job.

    calib identifiability ROBOT.urdf            which parameters the data can identify
    calib simulate ROBOT.urdf -o meas.csv       synthetic measurements of a perturbed robot
    calib calibrate ROBOT.urdf MEAS.csv -o calibrated.urdf
    calib evaluate ROBOT.urdf MEAS.csv          accuracy of a model against measurements
    calib select-poses ROBOT.urdf -n N -o poses.csv       configurations worth measuring
    calib compensate CALIBRATED.urdf NOMINAL.urdf TARGETS.csv -o corrected.csv

Exit codes: 0 success; 2 bad input or usage (one line ``calib: error: ...`` on stderr, no
output file created or changed); 3 ``calibrate`` ran but the fit did not converge, or
``compensate`` could not reach every target (outputs are written so that they can be
inspected, the status is printed on stderr); 130 / 143 interrupted by SIGINT / SIGTERM (one
line, no output changed); 1 is left to Python for unexpected internal errors (a bug: the
traceback says where).

Outputs are produced in memory first and written only when everything succeeded, as a set
(:class:`calib.io.fileio.OutputSet`: temporary files in the target folders, renamed together);
an output path that names an input is refused.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import shlex
import signal
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from calib.cli.args import (ArgumentParser, HelpFormatter, add_compliance, add_file_format, add_frames,
                            add_targets, compliance_options, count, nonnegative, positive, positive_int,
                            print_notes, read_options, with_compliance_file, with_targets)
from calib.cli.practice import add_compensate_parser, add_select_poses_parser
from calib import (CalibError, DataError, PAPER_DEVIATIONS, ParameterError, analyze_identifiability,
                   apply_deviations, calibrate, evaluate, load_robot, random_deviations, read_measurements,
                   simulate_measurements, write_measurements)
from calib.calibration.core import _EDGE_UNITS, METHODS, format_accuracy_table
from calib.io.fileio import OutputSet, check_not_input, output_target
from calib.cli.progress import working
from calib.solvers.problem import LOSSES

__all__ = ["main", "main_entry"]

log = logging.getLogger("calib.cli.main")

PROG = "calib"
EXIT_OK = 0
EXIT_INPUT = 2
EXIT_NOT_CONVERGED = 3


# ====================================================================== outputs
class Outputs:
    """Output files staged in memory and written together at the end.

    :meth:`add` checks a path at once (not an input, not another output, its folder exists, not
    a folder itself), so that a bad path fails before any work is done; :meth:`commit` writes
    every staged file atomically.
    """

    def __init__(self, inputs: Sequence[str | Path | None]):
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.paths: list[Path] = []
        self.data: dict[Path, bytes] = {}
        self.folders: list[Path] = []

    def add(self, path: str | Path, *, make_folder: bool = False) -> Path:
        """Reserve ``path`` as an output; with ``make_folder`` its folder may not exist yet (it
        is created by :meth:`commit`)."""
        path = Path(path)
        check_not_input(path, self.inputs)
        check_not_input(path, self.paths)
        output_target(path)          # a device, FIFO or socket is refused before any work
        if path.is_dir():
            raise CalibError(f"{path}: is a folder, expected a file name for the output")
        folder = path.parent
        if not folder.is_dir():
            if make_folder and not folder.exists() and folder.parent.is_dir():
                if folder not in self.folders:
                    self.folders.append(folder)
            elif folder.exists():
                raise CalibError(f"{path}: {folder} is not a folder")
            else:
                raise CalibError(f"{path}: folder {folder} does not exist")
        self.paths.append(path)
        return path

    def stage(self, path: Path, data: bytes | str) -> None:
        if path not in self.paths:
            raise ValueError(f"{path} was not reserved with Outputs.add")
        self.data[path] = data.encode("utf-8") if isinstance(data, str) else data

    def stage_from_file(self, path: Path, write: Callable[[Path], None]) -> None:
        """Stage what ``write(temporary_path)`` writes (for API writers that take a path)."""
        with tempfile.TemporaryDirectory(prefix="calib-") as tmp:
            target = Path(tmp) / path.name
            write(target)
            self.stage(path, target.read_bytes())

    def commit(self) -> None:
        """Write every staged file as a set (:class:`calib.io.fileio.OutputSet`): all or none."""
        out = OutputSet()
        for folder in self.folders:
            out.make_folder(folder)
        for path in self.paths:
            if path in self.data:
                out.stage(path, self.data[path])
        for path in out.commit():
            log.info("wrote %s", path)


def _json_text(obj) -> str:
    """Strict JSON (NaN and infinities become null), indented, newline-terminated."""
    def clean(o):
        if isinstance(o, float):
            return o if math.isfinite(o) else None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, np.generic):
            return clean(o.item())
        return o
    return json.dumps(clean(obj), indent=2, allow_nan=False) + "\n"


# ====================================================================== common pieces
def _load(args):
    robot = load_robot(args.robot, base_frame=args.base_frame, tool_frame=args.tool_frame)
    log.info("robot %s: %d joints (%s), base frame %r, tool frame %r, %d parameters",
             args.robot, robot.n_joints, ", ".join(robot.joint_names), robot.base_frame,
             robot.tool_frame, robot.n_params)
    log.debug("nominal model:\n%s", robot.describe())
    return robot


def _read(path, robot, args, tracker=None, *, joined=True):
    with working(f"reading {path}", logger=log):
        m = read_measurements(path, robot, tracker=tracker, options=read_options(args, joined=joined))
    log.info("read %r", m)
    print_notes(m.notes, PROG)
    return m


def _outlier_k(text: str) -> float | None:
    if text.strip().lower() == "off":
        return None
    return positive(text)


# ====================================================================== identifiability
def cmd_identifiability(args) -> int:
    robot = with_targets(_load(args), args)
    payload, gravity = compliance_options(args)
    if args.compliance:
        from calib.model.compliance import with_gravity

        robot = with_gravity(robot, payload=payload, gravity=gravity)
    elif payload is not None or gravity is not None:
        raise ParameterError("--payload-kg and --gravity only matter with --compliance")
    report = analyze_identifiability(robot, measure=args.measure, n_poses=args.poses, seed=args.seed)
    if args.json:
        out = {"robot": str(args.robot), "urdf": str(robot.urdf_path),
               "base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
               "joints": list(robot.joint_names), "seed": args.seed}
        out.update(report.to_dict())
        sys.stdout.write(_json_text(out))
        return EXIT_OK
    tied = {r.parameter: r for r in report.unidentifiable}
    w = max([10] + [len(n) + 1 for n in robot.names])
    lines = [f"Robot {args.robot}: {robot.n_joints} joints, base frame {robot.base_frame!r}, "
             f"tool frame {robot.tool_frame!r}; {report.n_poses // robot.n_targets} random configurations "
             f"within the joint limits (seed {args.seed})"
             + (f", each measuring targets {', '.join(robot.targets)}" if robot.targets else ""), "",
             f"{'parameter':<{w}}{'unit':>5}  {'of':<14}{'identifiable':<13}tied to"]
    for p in robot.parameters:
        of = (robot.joints[p.joint - 1].name if p.group in ("joint", "compliance") else "meas->base"
              if p.group == "u" else f"flange->{p.target or 'tool'}")
        r = tied.get(p.name)
        if r is None:
            status, partners = "yes", ""
        elif r.partners:
            status, partners = "no", " ".join(f"{c:+.4g}*{n}" for n, c in r.partners)
        else:
            status, partners = "no", f"({r.reason})"
        lines.append(f"{p.name:<{w}}{_EDGE_UNITS[p.unit][0]:>5}  {of:<14}{status:<13}"
                     f"{partners}".rstrip())
    lines += ["", report.format(), ""]
    sys.stdout.write("\n".join(lines))
    return EXIT_OK


# ====================================================================== simulate
def _deviations(spec: str, robot, rng) -> tuple[dict[str, float], str]:
    """(deviations in SI units, description) from --deviations."""
    if spec == "paper":
        missing = [n for n in PAPER_DEVIATIONS if n not in robot.names]
        if missing and robot.targets:
            raise ParameterError("--deviations paper: the paper's deviations are for one tool frame "
                                 "(v_x ...), with --target each target has its own (v_x@<id> ...); "
                                 "use --deviations random:SCALE_MM or FILE.json")
        if missing:
            raise ParameterError(f"--deviations paper: the paper's deviations (Tables 4-5, for the "
                                 f"BRTIRUS0707A) name parameters this robot does not have: "
                                 f"{', '.join(missing)}; use --deviations random:SCALE_MM or "
                                 f"FILE.json")
        return dict(PAPER_DEVIATIONS), "the paper's Tables 4-5"
    if spec.startswith("random:"):
        text = spec[len("random:"):]
        try:
            scale_mm = float(text)
        except ValueError:
            scale_mm = math.nan
        if not (math.isfinite(scale_mm) and scale_mm >= 0):
            raise CalibError(f"--deviations {spec}: expected random:SCALE_MM with SCALE_MM a number "
                             f">= 0 (millimetres), e.g. random:0.5")
        return (random_deviations(robot, scale_mm * 1e-3, rng),
                f"random:{scale_mm:g} (Gaussian, standard deviation {scale_mm:g} mm and "
                f"{scale_mm * 2e-3:g} rad)")
    path = Path(spec)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise CalibError(f"{path}: file not found (--deviations takes paper, random:SCALE_MM or a "
                         f"JSON file)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibError(f"{path}: cannot be read: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}, column "
                         f"{exc.colno}") from None
    if not isinstance(data, dict):
        raise CalibError(f"{path}: expected a JSON object of parameter deviations in SI units, "
                         f"e.g. {{\"d2\": 0.0001, \"theta3\": -0.002}}")
    out = {}
    for key, value in data.items():
        if key not in robot.names:
            raise CalibError(f"{path}: key {key!r} is not a parameter of this robot; parameters: "
                             f"{', '.join(robot.names)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise CalibError(f"{path}: key {key!r}: {json.dumps(value)} is not a finite number "
                             f"(deviations are in metres and radians)")
        out[key] = float(value)
    return out, str(path)


def cmd_simulate(args) -> int:
    dev_file = None if args.deviations == "paper" or args.deviations.startswith("random:") \
        else args.deviations
    outputs = Outputs([args.robot, dev_file])
    out_csv = outputs.add(args.output)
    out_truth = outputs.add(args.truth_urdf) if args.truth_urdf else None

    robot = with_targets(_load(args), args)     # --target: flange->target offsets (before c<i>)
    payload, gravity = compliance_options(args)
    if payload is not None or gravity is not None or dev_file is not None:
        # compliance parameters c<i> (zero unless the deviations name them; calib.model.compliance)
        from calib.model.compliance import with_gravity

        robot = with_gravity(robot, payload=payload, gravity=gravity)
    rng = np.random.default_rng(args.seed)
    deviations, described = _deviations(args.deviations, robot, rng)
    true_robot = apply_deviations(robot, deviations)
    n_cal, n_val = args.poses, args.val_poses
    Q = robot.random_configurations(n_cal + n_val, rng)
    sets = np.array(["cal"] * n_cal + ["val"] * n_val) if n_val else None
    ids = None
    if robot.targets:       # each configuration measured at every target, in --target order
        k = robot.n_targets
        Q, ids = np.repeat(Q, k, axis=0), list(robot.targets) * (n_cal + n_val)
        sets = None if sets is None else np.repeat(sets, k)
    meas = simulate_measurements(true_robot, Q, sigma_pos=args.sigma_pos_mm * 1e-3,
                                 sigma_rot=args.sigma_rot_rad, position_only=args.position_only,
                                 rng=rng, sets=sets, unmodelled=args.unmodelled_rad, targets=ids)
    kind = "positions only" if args.position_only else "positions and orientations"
    noise = [f"sigma_pos {args.sigma_pos_mm:g} mm"] + \
        ([] if args.position_only else [f"sigma_rot {args.sigma_rot_rad:g} rad"])
    noise_text = ("no noise" if args.sigma_pos_mm == 0 and (args.position_only or args.sigma_rot_rad == 0)
                  else "noise " + ", ".join(noise) + " per axis")
    if args.unmodelled_rad > 0:
        noise_text += f"; unmodelled joint error up to {args.unmodelled_rad:g} rad"
    if robot.has_compliance and payload is not None:
        noise_text += (f"; payload {payload.mass:g} kg at ({', '.join(f'{x * 1e3:g}' for x in payload.com_tool)}) "
                       f"mm in the tool frame")
    per_pose = ""
    if robot.targets:
        per_pose = (f", each measured at targets {', '.join(robot.targets)} (one row per target, "
                    f"{meas.n_poses} rows)")
    command = " ".join(shlex.quote(a) for a in ["calib", *args.argv])
    comment = (f"Simulated by: {command}\n"
               f"True model: {args.robot} with deviations from {described}; {noise_text}; "
               f"{n_cal} calibration + {n_val} validation poses{per_pose}")
    outputs.stage_from_file(out_csv, lambda p: write_measurements(p, meas, comment=comment))
    if out_truth is not None:
        from calib.io.urdf_writer import write_calibrated_urdf

        # several targets: the nominal is the URDF's own tool (the targets' offsets are not in it)
        outputs.stage_from_file(out_truth, lambda p: write_calibrated_urdf(
            true_robot.geometry(), p, nominal=None if robot.targets else robot.geometry()))
    outputs.commit()

    w = max([10] + [len(n) + 1 for n in deviations])
    counts = (f"{n_cal} calibration (set=cal) + {n_val} validation (set=val) poses" if n_val
              else f"{n_cal} poses")
    lines = [f"Simulated {counts} of {args.robot} ({kind}){per_pose} -> {out_csv}",
             f"  configurations uniform within the joint limits, seed {args.seed}; {noise_text}",
             f"  true model: deviations from {described}" +
             (f", written to {out_truth}" if out_truth else ""), "",
             f"{'parameter':<{w}}{'unit':>5}{'deviation':>14}"]
    for p in robot.parameters:
        if p.name in deviations:
            unit, scale = _EDGE_UNITS[p.unit]
            lines.append(f"{p.name:<{w}}{unit:>5}{deviations[p.name] * scale:>14.6g}")
    sys.stdout.write("\n".join(lines) + "\n")
    return EXIT_OK


# ====================================================================== calibrate
def cmd_calibrate(args) -> int:
    from calib.calibration.report import build_report
    from calib.io.urdf_reader import robot_path
    from calib.io.urdf_writer import check_writable, write_calibrated_urdf

    outputs = Outputs([robot_path(args.robot), args.measurements, args.validate, args.tracker])
    out_urdf = outputs.add(args.output)
    out_report = outputs.add(args.report) if args.report else None
    out_html = outputs.add(args.html) if args.html else None
    plot_paths = {}
    if args.plots:
        from calib.calibration.report import PLOT_FILES

        for name in PLOT_FILES:
            plot_paths[name] = outputs.add(Path(args.plots) / name, make_folder=True)

    robot = _load(args)
    payload, gravity = compliance_options(args)
    if (payload is not None or gravity is not None) and not args.compliance:
        raise ParameterError("--payload-kg and --gravity only matter with --compliance")
    out_sidecar = None
    if args.compliance:
        from calib.io.compliance_file import sidecar_path

        out_sidecar = outputs.add(sidecar_path(out_urdf))
    frames = check_writable(robot)     # what cannot be written is refused before the fit
    log.info("the calibrated URDF will hold tool frame %r in base frame %r", frames.tool_frame,
             frames.base_frame)
    meas = _read(args.measurements, robot, args, args.tracker)
    validation = _read(args.validate, robot, args, joined=False) if args.validate else None
    log.info("calibrating: method %s, parameter set %s, %d calibration rows", args.method,
             args.params or "default (auto or base)", meas.calibration().n_poses)
    try:
        with working(f"calibrating ({args.method})", logger=log):
            result = calibrate(robot, meas, method=args.method, params=args.params,
                               sigma_pos=None if args.sigma_pos_mm is None else args.sigma_pos_mm * 1e-3,
                               sigma_rot=args.sigma_rot_rad, validation=validation, loss=args.loss,
                               outlier_k=args.outlier_k, cv=args.cv, compliance=args.compliance,
                               payload=payload, gravity=gravity, lm_variant=args.lm_variant)
    except DataError as exc:  # about the data as a whole (too few poses): name the file
        if str(exc).startswith(str(args.measurements)):
            raise
        raise DataError(f"{args.measurements}: {exc}") from None
    log.info("calibration: %s after %d iterations, %.3f s", result.status, result.iterations,
             result.wall_time)

    written_frames = []
    outputs.stage_from_file(out_urdf, lambda p: written_frames.append(
        write_calibrated_urdf(result.robot.geometry(), p, nominal=result.nominal.geometry(),
                              estimated=result.estimated_frames)))
    frames = written_frames[0]
    if out_sidecar is not None:
        outputs.stage(out_sidecar, _json_text(result.compliance_record()))
    text = result.format()
    images = {}
    if plot_paths or out_html is not None:
        from calib.calibration.report import render_plots

        with working("drawing the plots", logger=log):
            images = render_plots(result, meas, validation)
    if out_report is not None or out_html is not None:
        report = build_report(
            result, meas, validation, command_line=["calib", *args.argv],
            inputs={"robot": robot_path(args.robot), "measurements": args.measurements,
                    "validation": args.validate},
            outputs={"calibrated_urdf": out_urdf, "report": out_report, "html": out_html},
            frames={"written_urdf": frames.to_dict()})
        if out_report is not None:
            outputs.stage(out_report, _json_text(report))
        if out_html is not None:
            from calib.calibration.report import render_html

            outputs.stage(out_html, render_html(report, text, images))
    for name, path in plot_paths.items():
        if name in images:
            outputs.stage(path, images[name])
    outputs.commit()

    written = [out_urdf] + [p for p in (out_sidecar, out_report, out_html) if p is not None] + \
              [p for p in plot_paths.values() if p in outputs.data]
    sys.stdout.write(text + "\n\nwrote " + ", ".join(str(p) for p in written) + "\n"
                     + f"{out_urdf}: calibrated kinematics of tool frame {frames.tool_frame!r} in "
                       f"base frame {frames.base_frame!r} (standing for {frames.nominal_tool_frame!r} "
                       f"and {frames.nominal_base_frame!r} of {args.robot}; evaluate and compensate "
                       f"use them by default)\n")
    if not result.success:
        sys.stderr.write(f"{PROG}: warning: the calibration did NOT converge (status "
                         f"{result.status}: {result.message}); the outputs were written for "
                         f"inspection, do not use them as a calibrated model\n")
        return EXIT_NOT_CONVERGED
    return EXIT_OK


# ====================================================================== evaluate
def _evaluate_compliance(robot, args):
    """``robot`` with the compliances of --compliance (torques from --nominal's URDF if given,
    else from ROBOT.urdf's), and the stderr note that says so; without --compliance, a note when
    a compliance sidecar lies beside ROBOT.urdf (its accuracy is then geometry-only)."""
    from calib.io.compliance_file import sidecar_path

    nominal = None
    if args.nominal is not None:
        if args.compliance is None:
            raise ParameterError("--nominal only matters with --compliance (it gives the gravity torques)")
        from calib.calibration.compensation import nominal_frames

        base, tool = nominal_frames(robot, base_frame=args.base_frame, tool_frame=args.tool_frame)
        nominal = load_robot(args.nominal, base_frame=base, tool_frame=tool)
    elif args.compliance is not None and robot.targets:
        raise ParameterError(f"--compliance: {args.robot} holds {robot.n_targets} targets and its tool "
                             f"frame is target {robot.targets[0]}'s, not the tool the payload was given "
                             f"in: give --nominal NOMINAL.urdf (the URDF calibrate started from) for "
                             f"the gravity torques")
    robot = with_compliance_file(robot, args, torques_from=nominal,
                                 hint=" (the report or the compliance sidecar of the calibration)")
    if args.compliance is not None:
        from calib.model.compliance import DISPLAY_UNITS

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


def cmd_evaluate(args) -> int:
    robot = _evaluate_compliance(_load(args), args)
    meas = _read(args.measurements, robot, args, args.tracker)
    rows = [("all rows", evaluate(robot, meas))]
    if meas.sets is not None:
        for label, part in (("calibration rows (cal)", meas.calibration()),
                            ("validation rows (val)", meas.validation())):
            if part.n_poses:
                rows.append((label, evaluate(robot, part)))
    per_target = []     # several targets: each target's rows too
    if len(meas.target_ids) > 1:
        per_target = [(t, evaluate(robot, meas.subset(np.array(meas.target) == t))) for t in meas.target_ids]
    if args.json:
        keys = {"all rows": "all", "calibration rows (cal)": "cal", "validation rows (val)": "val"}
        out = {"robot": str(args.robot), "measurements": str(args.measurements),
               "base_frame": robot.base_frame, "tool_frame": robot.tool_frame,
               "joints": list(robot.joint_names),
               "compliance": None if args.compliance is None else str(args.compliance)}
        out.update({keys[label]: s.to_dict() for label, s in rows})
        if per_target:
            out["targets"] = {t: s.to_dict() for t, s in per_target}
        sys.stdout.write(_json_text(out))
        return EXIT_OK
    sys.stdout.write(f"Accuracy of {args.robot} (tool frame {robot.tool_frame!r} in base frame "
                     f"{robot.base_frame!r}) against {args.measurements}:\n\n"
                     + format_accuracy_table(rows + [(f"target {t}", st) for t, st in per_target]) + "\n")
    return EXIT_OK


# ====================================================================== parser
_COMMON_EPILOG = """
Units: the measurement CSV carries its units in its column names (joint1_deg, x_mm, ...); printed
positions are in mm, orientations in rad. Exit codes: 0 success, 2 bad input (one-line message on
stderr, no file written)."""

_IDENT_DESC = """\
Which TM-MDH parameters of a robot pose (or position) measurements can identify.

Linearises the error model at random configurations uniform within the joint limits, weights
the rows by the measurement noise (0.02 mm, 0.002 rad), and keeps parameters in the order of
the paper's Eq. (23) as long as they add rank. Prints each parameter with whether it is
identifiable and, if not, the identifiable parameters it is tied to (a change of the tied
parameter acts like the listed multiples of its partners: mm per mm, mm per rad, ...), the rank,
and the observability indices O1, O3, O4 and the condition number."""

_IDENT_EPILOG = """\
examples:
  calib identifiability robots/brtirus0707a/brtirus0707a.urdf
  calib identifiability robots/brtirus0707a/brtirus0707a.urdf --measure position --json
""" + _COMMON_EPILOG

_SIM_DESC = """\
Synthetic measurements of a perturbed ("true") robot, as in Section 4 of the paper.

Draws --poses + --val-poses configurations uniformly within the joint limits, perturbs the
nominal model by --deviations, and writes the tool poses of the true model (in the base frame
of the URDF, the meas frame) with Gaussian noise: sigma-pos-mm per axis on positions,
sigma-rot-rad per axis (a rotation vector in the meas frame) on orientations. The last
--val-poses rows are marked set=val (held out for validation; they are noisy like the others).

Several targets (--target ID=X,Y,Z, once per target, two or more; mm in the tool frame): as a
tracker user measures reflectors on the tool, each configuration is measured at every target,
one row per target in --target order, with its id in a target column (3 targets and --poses 100:
300 rows). Each target has its own flange->target parameters v_x@<id> ... (--deviations random
perturbs them; a JSON file names them); --position-only, the noise, --unmodelled-rad and the
compliance deviations apply to every row. `calib calibrate` reads the file as it is.

--deviations:
  paper            the deviations of the paper's Tables 4-5 (for the bundled BRTIRUS0707A)
  random:SCALE_MM  Gaussian deviations of every parameter: lengths with standard deviation
                   SCALE_MM mm, angles SCALE_MM/500 rad (moves a point 0.5 m away by as much)
  FILE.json        a JSON object of deviations in SI units (metres, radians), parameter names
                   as printed by `calib identifiability`, e.g. {"d2": 0.0001, "theta3": -0.002}"""

_SIM_EPILOG = """\
examples:
  calib simulate robots/brtirus0707a/brtirus0707a.urdf -o meas.csv --poses 100 --val-poses 200 \\
      --deviations paper --seed 1 --truth-urdf true.urdf
  calib simulate robot.urdf -o meas.csv --deviations random:0.5 --position-only
  calib simulate robots/brtirus0707a/brtirus0707a.urdf -o meas.csv --deviations random:0.3 \
      --position-only --target A=100,0,50 --target B=-50,80,50 --target C=0,-70,100
""" + _COMMON_EPILOG

_CAL_DESC = """\
Identify a robot's TM-MDH parameters from measured tool poses and write the calibrated URDF.

Reads the nominal model from ROBOT.urdf and the measurements (CSV, see README.md: joint values
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
         set) compared by K-fold cross-validation, the smallest within one standard error of the
         best chosen (default when the data hold under 10 residuals per identifiable parameter)
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

Units: the measurement CSV carries its units in its column names (joint1_deg, x_mm, ...); the
noise sigmas weight position against orientation residuals (mm and rad per axis)."""

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
""" + _COMMON_EPILOG


def _add_robot(p: argparse.ArgumentParser) -> None:
    p.add_argument("robot", metavar="ROBOT.urdf",
                   help="URDF of the robot (the nominal model), or a robot name example-robot-data "
                        "knows (ur5, panda, ...); a calibrated URDF written by calib brings its own "
                        "base and tool frames")


def _add_verbose(p: argparse.ArgumentParser, top: bool) -> None:
    p.add_argument("-v", "--verbose", action="count", default=0 if top else argparse.SUPPRESS,
                   help="log progress on stderr (-vv: also the nominal model)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``calib`` command."""
    from calib import __version__ as ver
    parser = ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Kinematic calibration of serial robots: TM-MDH error model, C-LM "
                    "identification (Lao et al. 2023), on Pinocchio.",
        epilog="Run `calib COMMAND --help` for each command. Exit codes: 0 success, 2 bad input "
               "(no file written), 3 calibration did not converge or a compensation target was "
               "not reached.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {ver}")
    _add_verbose(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("identifiability", help="which parameters the measurements can identify",
                       description=_IDENT_DESC, epilog=_IDENT_EPILOG, formatter_class=HelpFormatter)
    _add_robot(p)
    p.add_argument("--measure", choices=("pose", "position"), default="pose",
                   help="what is measured: position and orientation, or position only")
    p.add_argument("--poses", type=positive_int, default=100, metavar="N",
                   help="number of random configurations")
    p.add_argument("--seed", type=count, default=0, metavar="S",
                   help="random seed of the configurations")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (n_params, rank, identifiable, unidentifiable with "
                        "tied partners, condition_number, observability, ...)")
    add_frames(p)
    add_compliance(p, "calibrate")
    add_targets(p)
    _add_verbose(p, top=False)
    p.set_defaults(func=cmd_identifiability)

    p = sub.add_parser("simulate", help="synthetic measurements of a perturbed robot",
                       description=_SIM_DESC, epilog=_SIM_EPILOG, formatter_class=HelpFormatter)
    _add_robot(p)
    p.add_argument("-o", "--output", required=True, metavar="MEAS.csv",
                   help="measurement CSV to write (degrees and millimetres, quaternion qw..qz)")
    p.add_argument("--poses", type=positive_int, default=100, metavar="N",
                   help="number of calibration poses (set=cal)")
    p.add_argument("--val-poses", type=count, default=0, metavar="M",
                   help="number of validation poses (set=val), after the calibration ones")
    p.add_argument("--seed", type=count, default=0, metavar="S",
                   help="random seed (configurations, random deviations, noise)")
    p.add_argument("--deviations", default="paper", metavar="paper|random:SCALE_MM|FILE.json",
                   help="parameter deviations of the true robot (see above)")
    p.add_argument("--sigma-pos-mm", type=nonnegative, default=0.02, metavar="S",
                   help="position noise per axis, mm (0: noise-free)")
    p.add_argument("--sigma-rot-rad", type=nonnegative, default=0.002, metavar="S",
                   help="orientation noise per axis, rad (0: noise-free)")
    p.add_argument("--unmodelled-rad", type=nonnegative, default=0.0, metavar="A",
                   help="add an error the model cannot describe: every revolute joint really turns "
                        "by q + a sin(q + phi), a in [A/2, A] rad, random phase (default 0)")
    p.add_argument("--position-only", action="store_true",
                   help="write positions only (no orientation columns)")
    p.add_argument("--truth-urdf", metavar="TRUE.urdf", default=None,
                   help="also write the true model as a URDF (a copy of ROBOT.urdf with its joint "
                        "origins changed)")
    add_frames(p)
    add_compliance(p, "simulate")
    add_targets(p)
    _add_verbose(p, top=False)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("calibrate", help="identify the parameters, write the calibrated URDF",
                       description=_CAL_DESC, epilog=_CAL_EPILOG, formatter_class=HelpFormatter)
    _add_robot(p)
    p.add_argument("measurements", metavar="MEAS.csv", help="measurement CSV (format: README.md)")
    p.add_argument("-o", "--output", required=True, metavar="CALIBRATED.urdf",
                   help="calibrated URDF to write (must differ from ROBOT.urdf)")
    p.add_argument("--method", choices=METHODS, default="search-lm",
                   help="search-lm: closed-form search of the angles on the rotation data, then LM "
                        "(converges from the largest errors); c-lm: the paper's cross-identification "
                        "scheme run with calib's LM (not the paper's Eq. 27-28; --lm-variant paper for "
                        "that); lm: calib's Levenberg-Marquardt alone (lm and c-lm exit 3 when they "
                        "stop in a local minimum)")
    p.add_argument("--lm-variant", choices=("calib", "paper"), default="calib",
                   help="calib: calib's LM (default); paper: the LM of the paper's Eq. (27)-(28) as "
                        "printed (mu I, mu reset to 0.001 lambda^+-1, unweighted mm/rad residuals), "
                        "for --method lm or c-lm")
    p.add_argument("--params", default=None, metavar="auto|base|paper|all|LIST",
                   help="which parameters to identify (see above); default: auto when the rows "
                        "hold few residuals per identifiable parameter, else base")
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
    p.add_argument("--validate", metavar="VAL.csv", default=None,
                   help="more validation measurements (all rows held out), same format")
    p.add_argument("--report", metavar="REPORT.json", default=None,
                   help="write the full result as JSON (lengths in mm, angles in rad): status, "
                        "before, after, validation, parameters, ...")
    p.add_argument("--plots", metavar="DIR", default=None,
                   help="write PNG plots of the per-pose errors before and after and their "
                        "histograms into DIR (created if missing; its parent must exist)")
    p.add_argument("--html", metavar="REPORT.html", default=None,
                   help="write one self-contained HTML report (tables, the printed report and "
                        "the plots embedded; no external links) for a person or a customer")
    add_file_format(p, tracker=True)
    add_frames(p)
    add_compliance(p, "calibrate")
    _add_verbose(p, top=False)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("evaluate", help="accuracy of a model against measurements",
                       description=_EVAL_DESC, epilog=_EVAL_EPILOG, formatter_class=HelpFormatter)
    _add_robot(p)
    p.add_argument("measurements", metavar="MEAS.csv", help="measurement CSV (format: README.md)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: n_poses, position_mm and rotation_rad statistics "
                        "(mean, rms, max, min) for all, cal and val rows")
    add_file_format(p, tracker=True)
    add_frames(p)
    g = add_compliance(p, "evaluate")
    g.add_argument("--nominal", metavar="NOMINAL.urdf", default=None,
                   help="with --compliance: the nominal URDF of the calibration, whose inertias give "
                        "the gravity torques as in calibrate (reproduces its numbers exactly); "
                        "default: ROBOT.urdf's (its calibrated geometry moves the torques by ~1e-3 "
                        "of themselves, sub-micrometre at the tool); required for a calibration of "
                        "several targets")
    _add_verbose(p, top=False)
    p.set_defaults(func=cmd_evaluate)

    add_select_poses_parser(sub)
    add_compensate_parser(sub)
    return parser


# ====================================================================== entry points
class _ElapsedFormatter(logging.Formatter):
    """Log lines with the seconds since the command started (``%(elapsed)``)."""

    def __init__(self, fmt: str):
        super().__init__(fmt)
        self.start = time.monotonic()

    def format(self, record: logging.LogRecord) -> str:
        record.elapsed = time.monotonic() - self.start
        return super().format(record)


class Interrupted(BaseException):
    """A termination signal (SIGTERM) received while a command runs (SIGINT arrives as
    KeyboardInterrupt); a BaseException so that no ``except Exception`` swallows it."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _run(args) -> int:
    """``args.func(args)`` with library warnings (numpy, scipy) kept off the terminal: logged at
    debug level (``-vv``) instead."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return args.func(args)
        finally:
            for w in caught:
                log.debug("warning from %s:%d: %s", Path(w.filename).name, w.lineno, _one_line(w.message))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``calib`` command with ``argv`` (default ``sys.argv[1:]``); return the exit code.

    Bad input: one line ``calib: error: ...`` on stderr and 2. SIGINT / SIGTERM: one line
    ``calib: interrupted by SIGINT`` and 130 / 143 (128 + the signal number); outputs are
    committed as a set with the signals held back, so none is half-written."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # reported by the subcommand's parser, so that its usage line is shown
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # --help, --version (0) and usage errors (2)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else EXIT_INPUT)
    args.argv = argv

    root_log = logging.getLogger("calib")     # every module logs as calib.<module>
    handler = None
    if args.verbose:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_ElapsedFormatter(f"{PROG}: %(message)s  [%(elapsed).2f s]"))
        root_log.addHandler(handler)
        root_log.setLevel(logging.DEBUG if args.verbose > 1 else logging.INFO)
    previous_term = None
    if threading.current_thread() is threading.main_thread():
        previous_term = signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        return _run(args)
    except CalibError as exc:
        sys.stderr.write(f"{PROG}: error: {_one_line(exc)}\n")
        return EXIT_INPUT
    except OSError as exc:     # an input or output the system refuses (permissions, full disk)
        where = f"{exc.filename}: " if exc.filename else ""
        sys.stderr.write(f"{PROG}: error: {where}{_one_line(exc.strerror or exc)}\n")
        return EXIT_INPUT
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: interrupted by SIGINT\n")
        return 128 + signal.SIGINT
    except Interrupted as exc:
        name = signal.Signals(exc.signum).name
        sys.stderr.write(f"{PROG}: interrupted by {name}\n")
        return 128 + exc.signum
    finally:
        if previous_term is not None:
            signal.signal(signal.SIGTERM, previous_term)
        if handler is not None:
            root_log.removeHandler(handler)
            root_log.setLevel(logging.NOTSET)


def main_entry() -> None:
    """Console-script entry point: ``sys.exit(main())`` with one BLAS thread. calib's matrices
    are small (tens of columns): BLAS threads only add start-up and, on a busy machine,
    contention (a 70 ms calibration was seen taking 2 s with them)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        code = main()
    sys.exit(code)
