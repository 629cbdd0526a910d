"""``calib compensate CALIBRATED.urdf NOMINAL.urdf TARGETS.csv -o CORRECTED.csv``: corrected joint
values, where to send a calibrated robot so that its tool reaches the targets (a thin layer over
:mod:`calib.calibration.compensation`). Exit code 3 when some targets are not ``ok``: the output is
written all the same, with the status of each row."""
from __future__ import annotations

import argparse
import logging
import sys

from calib.cli.args import (HelpFormatter, add_compliance, add_file_format, add_frames, add_verbose, nonnegative,
                            print_notes, read_options, with_compliance_file)
from calib.cli.output import EXIT_NOT_CONVERGED, EXIT_OK, PROG, Outputs, command_line

__all__ = ["add_parser", "run"]

log = logging.getLogger(__name__)

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



def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``compensate`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    from calib.choices import SINGULAR_THRESHOLD

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
    add_verbose(p, help="log progress on stderr")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib compensate`` with parsed arguments; returns the exit code."""
    from calib.calibration.compensation import (check_joint_targets, compensate, compensate_poses,
                                                load_compensation_models)
    from calib.io.specs import read_targets, write_compensation

    outputs = Outputs([args.calibrated, args.nominal, args.targets])
    out = outputs.add(args.output)
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
    comment = (f"Corrected joint values, computed by: {command_line(args)}\n"
               f"Targets: {targets.kind} targets of {args.targets} (tool frame {nominal.tool_frame} "
               f"in base frame {nominal.base_frame}); status ok: the calibrated model reaches the "
               f"target; other rows must not be sent to the robot as they are")
    outputs.stage_from_file(out, lambda p: write_compensation(p, result, comment=comment))
    outputs.commit()
    sys.stdout.write(result.format() + f"\n\nwrote {out}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"{PROG}: warning: {bad} of {result.n_targets} targets are not ok (see the "
                         f"status and detail columns of {out})\n")
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _homogeneous(R, p):
    """(N, 4, 4) from rotations (N, 3, 3) and positions (N, 3)."""
    import numpy as np

    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T

