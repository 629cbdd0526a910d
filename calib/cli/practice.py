"""Subcommands for putting a calibration into practice: ``select-poses`` and ``compensate``.

Thin layers over :mod:`calib.calibration.poses` and :mod:`calib.calibration.compensation`, to be registered by the main
parser (:mod:`calib.cli.main`)::

    add_select_poses_parser(subparsers)      # calib select-poses ROBOT.urdf -n N -o poses.csv
    add_compensate_parser(subparsers)        # calib compensate CAL.urdf NOM.urdf TARGETS.csv -o out.csv

Each parser sets ``func`` to its ``run_*`` function, which takes the parsed arguments and returns
the exit code: 0 success; 3 for ``compensate`` when some targets are not ``ok`` (the output is
written all the same, with the status of each row). Bad input raises :class:`calib.CalibError`,
which the main command turns into one line on stderr and exit code 2; nothing is written then.
Outputs are written atomically, and an output path that names an input is refused.
"""
from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

import numpy as np

from calib.cli.args import (HelpFormatter, add_compliance, add_file_format, add_frames, add_targets, count,
                            nonnegative, positive, positive_int, print_notes, read_options,
                            with_compliance_file, with_targets)
from calib.calibration.compensation import (SINGULAR_THRESHOLD, check_joint_targets, compensate,
                                            compensate_poses, load_compensation_models)
from calib.errors import CalibError
from calib.io.fileio import check_not_input
from calib.io.specs import read_targets, write_compensation, write_poses
from calib.calibration.poses import CRITERIA, design_poses
from calib.cli.progress import working
from calib.io.urdf_reader import load_robot

__all__ = ["add_select_poses_parser", "run_select_poses", "add_compensate_parser", "run_compensate"]

log = logging.getLogger("calib")

EXIT_OK = 0
EXIT_NOT_ALL_OK = 3

_SELECT_DESC = """\
Choose the configurations to measure for a calibration: N poses that make the identification
as accurate as possible.

Draws --candidates configurations uniformly within the joint limits, computes the
identification Jacobian there (rows weighted by the measurement noise, columns restricted to the
identifiable parameters and scaled once over the pool), and selects N of them that maximise the
criterion: a greedy D-optimal start, then Fedorov exchange passes.

--criterion:
  D    log det of the information matrix: the smallest confidence volume of the identified
       parameters (default; the usual choice)
  O1   Borm and Menq's index of the column-normalised Jacobian (D-optimality with each
       parameter normalised over the chosen poses)
  O4   noise amplification index sigma_min^2 / sigma_max (Nahvi and Hollerbach)

Prints the criteria of the selection against random sets of N poses, and writes the poses as a
CSV of joint values (degrees; millimetres for prismatic joints), one row per pose. Move the robot
to each row, measure the tool pose, and add the columns x_mm, y_mm, z_mm (and qw, qx, qy, qz)
to obtain a measurement file for `calib calibrate`. The advantage over random poses is largest
with few poses (20 to 30 for a 6-axis arm)."""

_SELECT_EPILOG = """\
examples:
  calib select-poses robots/brtirus0707a/brtirus0707a.urdf -n 25 -o poses.csv --seed 1
  calib select-poses robot.urdf -n 40 -o poses.csv --measure position --criterion O4 \\
      --candidates 5000 --tool-frame tool0
  calib select-poses robot.urdf -n 20 -o poses.csv --measure position \\
      --target A=100,0,50 --target B=-50,80,50 --target C=0,-70,100

Same --seed, same poses. Exit codes: 0 success, 2 bad input (one-line message, nothing written)."""

_COMP_DESC = """\
Corrected joint values: where to send a calibrated robot so that its tool reaches the targets.

The controller computes joint values with the nominal model (NOMINAL.urdf). For each target,
compensate finds the joint values with which the calibrated model (CALIBRATED.urdf, as written by
`calib calibrate`) puts the tool at the target pose, by damped Newton iterations from the nominal
joints, to 1e-10 m and 1e-10 rad.

TARGETS.csv (comments with #, one header row, units in the column names as in measurement files):
  joint columns only     joint1_deg, ..., joint6_deg (or q1_deg ..., _rad; _mm or _m for
                         prismatic joints): the joints the controller would use; the target is
                         the nominal tool pose there
  x_mm, y_mm, z_mm       a target tool position in the nominal base frame (the meas frame),
    [+ qw, qx, qy, qz]   with an orientation (unit quaternion, scalar first; or rz_deg, ry_deg,
                         rx_deg, R = Rz Ry Rx; or e1..e3 with --euler, rvx..rvz, r11..r33 as in
                         measurement files); joint columns, if also given, are the start of the
                         solver and choose the solution branch (without them, the solution
                         closest to the middle of the joint ranges from several starts)

Other columns are ignored (listed on stderr). Semicolon or tab separators with decimal commas,
--rename and --limit-tolerance work as for measurement files (README, Measurement file format).

Output CSV, one row per target in the same order: the corrected joint columns (degrees;
millimetres for prismatic joints), then status, residual_mm, residual_rad (pose targets) and
detail. status is
  ok             the calibrated model reaches the target within the joint limits
  limit          reached, but a joint is beyond its limit (detail: which and by how much);
                 the joint values are written as computed, never clipped
  singular       the joint Jacobian's smallest singular value is below --singular-threshold
                 (near a singularity: a tiny pose error needs a large joint motion)
  not_converged  the target was not reached
Rows that are not ok must not be sent to the robot as they are.

Frames: --base-frame and --tool-frame name frames of NOMINAL.urdf; the calibrated URDF's matching
frames are found as calib's URDF writer made them (its root link plays the meas frame when the
nominal base frame is the root link; a link the writer added under the tool frame is the tool)."""

_COMP_EPILOG = """\
examples:
  calib compensate calibrated.urdf robot.urdf program_joints.csv -o corrected.csv
  calib compensate calibrated.urdf robot.urdf cad_poses.csv -o corrected.csv --tool-frame tool0
  (CALIBRATED.urdf comes from: calib calibrate robot.urdf meas.csv -o calibrated.urdf)

Exit codes: 0 every target ok; 3 some targets are not ok (the output is written, see the status
column; a summary is printed); 2 bad input (one-line message, nothing written)."""


def _criterion(text: str) -> str:
    if text.upper() not in CRITERIA:
        raise argparse.ArgumentTypeError(f"{text!r} is not a criterion; choose from "
                                         f"{', '.join(CRITERIA)}")
    return text.upper()


def _add_verbose(p: argparse.ArgumentParser) -> None:
    p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="log progress on stderr")


def _check_output(output: str | Path, inputs) -> Path:
    """Fail before any work on an output path that names an input, a folder, or a missing folder."""
    path = Path(output)
    check_not_input(path, inputs)
    if path.is_dir():
        raise CalibError(f"{path}: is a folder, expected a file name for the output")
    if not path.parent.is_dir():
        raise CalibError(f"{path}: folder {path.parent} does not exist")
    return path


def _command_line(args) -> str:
    argv = getattr(args, "argv", None)
    if argv is None:
        return "calib " + args.command if getattr(args, "command", None) else "calib"
    return " ".join(shlex.quote(a) for a in ["calib", *argv])


# ====================================================================== select-poses
def add_select_poses_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``select-poses`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser("select-poses", help="choose the poses to measure (optimal design)",
                              description=_SELECT_DESC, epilog=_SELECT_EPILOG,
                              formatter_class=HelpFormatter)
    p.add_argument("robot", metavar="ROBOT.urdf", help="URDF of the robot (the nominal model)")
    p.add_argument("-n", "--poses", dest="n", type=positive_int, required=True, metavar="N",
                   help="number of poses to select")
    p.add_argument("-o", "--output", required=True, metavar="POSES.csv",
                   help="CSV of joint values to write (degrees; mm for prismatic joints)")
    p.add_argument("--candidates", type=positive_int, default=2000, metavar="M",
                   help="size of the random pool of configurations to choose from")
    p.add_argument("--criterion", type=_criterion, default="D", metavar="D|O1|O4",
                   help="what to maximise (see above)")
    p.add_argument("--measure", choices=("pose", "position"), default="pose",
                   help="what will be measured: position and orientation, or position only")
    p.add_argument("--seed", type=count, default=0, metavar="S",
                   help="random seed of the candidate pool")
    p.add_argument("--sigma-pos-mm", type=positive, default=0.02, metavar="S",
                   help="position measurement noise per axis, mm (weights position rows)")
    p.add_argument("--sigma-rot-rad", type=positive, default=0.002, metavar="S",
                   help="orientation measurement noise per axis, rad (weights orientation rows)")
    add_targets(p)
    add_frames(p)
    _add_verbose(p)
    p.set_defaults(func=run_select_poses)
    return p


def run_select_poses(args) -> int:
    """Run ``calib select-poses`` with parsed arguments; returns the exit code."""
    out = _check_output(args.output, [args.robot])
    robot = load_robot(args.robot, base_frame=args.base_frame, tool_frame=args.tool_frame)
    log.info("robot %s: %d joints (%s), base frame %r, tool frame %r", args.robot, robot.n_joints,
             ", ".join(robot.joint_names), robot.base_frame, robot.tool_frame)
    robot = with_targets(robot, args)
    with working(f"selecting {args.n} of {args.candidates} candidate poses", logger=log):
        design = design_poses(robot, args.n, candidates=args.candidates, criterion=args.criterion,
                              measure=args.measure, seed=args.seed,
                              sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad)
    log.info("selection: %d exchange passes, %d swaps, %.3f s", design.passes, design.swaps,
             design.elapsed)
    c, b = design.criteria, design.random_criteria
    comment = (f"Poses to measure, selected by: {_command_line(args)}\n"
               f"Robot {args.robot}: base frame {robot.base_frame}, tool frame {robot.tool_frame}; "
               f"{args.measure} measurements"
               + (f" of targets {', '.join(robot.targets)} at every pose" if robot.targets else "") + "\n"
               f"Criterion {design.criterion}: log det {c['D']:.6g} (random sets: {b['D']:.6g}), "
               f"O1 {c['O1']:.4g} ({b['O1']:.4g}), O4 {c['O4']:.4g} ({b['O4']:.4g}), condition "
               f"number {c['condition_number']:.4g} ({b['condition_number']:.4g})\n"
               f"After measuring, add x_mm,y_mm,z_mm (and qw,qx,qy,qz) columns for calib calibrate"
               + ("; one row per target measured, with its id in a target column" if robot.targets else ""))
    write_poses(out, robot, design.q, comment=comment)
    sys.stdout.write(design.format() + f"\n\nwrote {design.n_poses} poses to {out}\n")
    return EXIT_OK


# ====================================================================== compensate
def add_compensate_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``compensate`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser("compensate", help="corrected joint values for targets",
                              description=_COMP_DESC, epilog=_COMP_EPILOG,
                              formatter_class=HelpFormatter)
    p.add_argument("calibrated", metavar="CALIBRATED.urdf",
                   help="calibrated URDF (written by calib calibrate)")
    p.add_argument("nominal", metavar="NOMINAL.urdf",
                   help="nominal URDF (the model the controller uses)")
    p.add_argument("targets", metavar="TARGETS.csv", help="targets CSV (format above)")
    p.add_argument("-o", "--output", required=True, metavar="CORRECTED.csv",
                   help="CSV of corrected joint values with a status per row to write")
    p.add_argument("--measure", choices=("pose", "position"), default="pose",
                   help="for joint targets: reach the nominal tool pose, or its position only "
                        "(least-norm joint change); pose targets follow their columns")
    p.add_argument("--singular-threshold", type=nonnegative, default=SINGULAR_THRESHOLD,
                   metavar="S",
                   help="smallest singular value of the joint Jacobian (position rows in m/rad, "
                        "rotation rows in rad/rad) below which a target is reported singular")
    add_file_format(p)
    add_frames(p, base_help="link (or joint) of NOMINAL.urdf that plays the meas frame, in which "
                            "pose targets are given (default: the root link)",
               tool_help="link (or joint) of NOMINAL.urdf whose pose is targeted (default: the "
                         "last link before the tree branches)")
    add_compliance(p, "compensate")
    _add_verbose(p)
    p.set_defaults(func=run_compensate)
    return p


def run_compensate(args) -> int:
    """Run ``calib compensate`` with parsed arguments; returns the exit code."""
    out = _check_output(args.output, [args.calibrated, args.nominal, args.targets])
    calibrated, nominal = load_compensation_models(args.calibrated, args.nominal,
                                                   base_frame=args.base_frame,
                                                   tool_frame=args.tool_frame)
    calibrated = with_compliance_file(calibrated, args, torques_from=nominal,
                                      hint=" (the report or the compliance sidecar of the calibration)")
    if args.compliance is not None:
        log.info("compliance from %s: %s", args.compliance, calibrated.describe().splitlines()[-1])
    log.info("nominal %s (frames %r -> %r), calibrated %s (frames %r -> %r)", args.nominal,
             nominal.base_frame, nominal.tool_frame, args.calibrated, calibrated.base_frame,
             calibrated.tool_frame)
    targets = read_targets(args.targets, nominal, options=read_options(args))
    print_notes(targets.notes)
    log.info("read %d %s targets from %s", targets.n_targets, targets.kind, args.targets)
    opts = dict(singular_threshold=args.singular_threshold)
    if targets.kind == "joints":
        check_joint_targets(calibrated)
        result = compensate(calibrated, nominal, targets.q, measure=args.measure, **opts)
    elif targets.kind == "pose":
        T = _homogeneous(targets.rotation, targets.position)
        result = compensate_poses(calibrated, T_meas_tool=T, q_start=targets.q, **opts)
    else:
        result = compensate_poses(calibrated, p_meas_tool=targets.position, q_start=targets.q,
                                  **opts)
    comment = (f"Corrected joint values, computed by: {_command_line(args)}\n"
               f"Targets: {targets.kind} targets of {args.targets} (tool frame {nominal.tool_frame} "
               f"in base frame {nominal.base_frame}); status ok: the calibrated model reaches the "
               f"target; other rows must not be sent to the robot as they are")
    write_compensation(out, result, comment=comment)
    sys.stdout.write(result.format() + f"\n\nwrote {out}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"calib: warning: {bad} of {result.n_targets} targets are not ok (see the "
                         f"status and detail columns of {out})\n")
        return EXIT_NOT_ALL_OK
    return EXIT_OK


def _homogeneous(R, p):
    """(N, 4, 4) from rotations (N, 3, 3) and positions (N, 3)."""
    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T
