"""``calib compensate CALIBRATED.urdf NOMINAL.urdf TARGETS.csv -o CORRECTED.csv``: corrected joint
values, where to send a calibrated robot so that its tool reaches the targets (a thin layer over
:mod:`calib.compensation.compensate`). Exit code 3 when some targets are not ``ok``: the output is
written all the same, with the status of each row."""
from __future__ import annotations

import argparse
import logging
import sys

from calib.cli.args import (HelpFormatter, add_compliance, add_file_format, add_frames, add_verbose, nonnegative,
                            print_notes, read_options, with_compliance_file)
from calib.cli.output import EXIT_NOT_CONVERGED, EXIT_OK, PROG, Outputs, command_line
from calib.errors import ParameterError

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
  x_mm, y_mm, z_mm       a target tool position in the robot's base frame (--targets-frame base,
                         the default; meas: in the calibration's measurement frame),
    [+ qw, qx, qy, qz]   with an orientation (unit quaternion, scalar first; or rz_deg, ry_deg,
                         rx_deg, R = Rz Ry Rx; or e1..e3 with --euler, rvx..rvz, r11..r33 as in
                         measurement files); joint columns, if also given, are the start of the
                         solver and choose the solution branch (without them, the solution
                         reached from the nearest of 512 seed configurations, others tried
                         for the targets not ok)

Other columns are ignored (listed on stderr). Semicolon or tab separators with decimal commas,
--rename and --limit-tolerance work as for measurement files (calib formats; docs/formats.md).

Output CSV, one row per target in the same order: the corrected joint columns (degrees;
millimetres for prismatic joints), then status, residual_mm, residual_rad (pose targets),
frame_std_mm and frame_std_deg (after a calibration that estimated the measurement frame, for
targets in the robot's base frame: the 1-sigma error of the reached pose that the uncertainty
of the measurement->base transform causes) and detail. status is
  ok             the calibrated model reaches the target within the joint limits
  limit          reached, but a joint is beyond its limit (detail: which and by how much);
                 the joint values are written as computed, never clipped
  singular       the joint Jacobian's smallest singular value is below --singular-threshold
                 (near a singularity: a tiny pose error needs a large joint motion)
  not_converged  the target was not reached
Rows that are not ok must not be sent to the robot as they are.

Joint targets after a calibration that estimated the tool frame (a reflector, not the nominal
tool) are compensated for the pose of the last link: every tool on it reaches its nominal pose.

Frames: --base-frame and --tool-frame name frames of NOMINAL.urdf; the calibrated URDF's matching
frames are found as calib's URDF writer made them (its root link plays the meas frame when the
nominal base frame is the root link; a link the writer added under the tool frame is the tool)."""

_COMP_EPILOG = """\
examples:
  calib compensate calibrated.urdf robot.urdf program_joints.csv -o corrected.csv
  calib compensate calibrated.urdf robot.urdf cad_poses.csv -o corrected.csv --tool-frame tool0
  calib compensate calibrated.urdf robot.urdf tracker_poses.csv -o corrected.csv --targets-frame meas
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
    p.add_argument("--targets-frame", choices=("base", "meas"), default="base",
                   help="frame of pose targets: base (default), the robot's base frame (the calibrated "
                        "URDF's, what a robot program holds); meas, the measurement frame of the "
                        "calibration (the tracker's), taken from CALIBRATED.urdf's record")
    add_file_format(p)
    add_frames(p, base_help="link (or joint) of NOMINAL.urdf that is the robot's base frame, in which "
                            "pose targets are given with --targets-frame base (default: the root link)",
               tool_help="link (or joint) of NOMINAL.urdf whose pose is targeted (default: the "
                         "last link before the tree branches)")
    add_compliance(p, "compensate")
    add_verbose(p, help="log progress on stderr")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib compensate`` with parsed arguments; returns the exit code."""
    from calib.compensation.compensate import (check_joint_targets, compensate, compensate_poses,
                                                load_compensation_models)
    from calib.io.csv.specs import read_targets, write_compensation

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
    rec = calibrated.source.document.frames if calibrated.source is not None else None
    uncalibrated_orientation = (rec is not None and not rec.orientation_measured
                                and (targets.kind == "pose" or (targets.kind == "joints" and args.measure == "pose")))
    if uncalibrated_orientation:
        sys.stderr.write(f"{PROG}: note: {args.calibrated}'s calibration measured no tool orientation (positions "
                         f"only, or touch rows): the corrected joints reach the targets' orientations as the "
                         f"model predicts them, which the measurements did not check; status ok vouches for "
                         f"the position (--measure position corrects the position alone)\n")
    kind = {"joints": "joint"}.get(targets.kind, targets.kind)      # joint, pose, position
    log.info("read %d %s targets from %s", targets.n_targets, kind, args.targets)
    T_meas_base = None if rec is None else rec.measurement_transform
    opts = dict(singular_threshold=args.singular_threshold)
    if targets.kind == "joints":
        if args.targets_frame != "base":
            raise ParameterError(f"--targets-frame {args.targets_frame}: {args.targets} holds joint targets, "
                                 f"which have no frame (their poses are the nominal model's)")
        check_joint_targets(calibrated)
        if rec is not None and rec.tool_estimated:
            calibrated, nominal = _last_link_models(args, calibrated, nominal)
        result = compensate(calibrated, nominal, targets.q, measure=args.measure, **opts)
    else:
        T = _homogeneous(targets.rotation, targets.position) if targets.kind == "pose" else None
        p = targets.position if targets.kind != "pose" else None
        if args.targets_frame == "meas":
            if T_meas_base is None:
                sys.stderr.write(f"{PROG}: note: {args.calibrated} records no measurement frame (the calibration's "
                                 f"measurements were in the robot's base frame): meas = base\n")
            else:
                from calib.compensation.compensate import pose_targets_in_base

                if T is not None:
                    T = pose_targets_in_base(T_meas_base=T_meas_base, T_meas_tool=T)
                else:
                    p = pose_targets_in_base(T_meas_base=T_meas_base, p_meas_tool=p)
        if T is not None:
            result = compensate_poses(calibrated, T_meas_tool=T, q_start=targets.q, **opts)
        else:
            result = compensate_poses(calibrated, p_meas_tool=p, q_start=targets.q, **opts)
    if T_meas_base is not None and (targets.kind == "joints" or args.targets_frame == "base"):
        from calib.compensation.compensate import with_frame_uncertainty

        result = with_frame_uncertainty(result, T_meas_base=T_meas_base, covariance=rec.measurement_covariance)
    frame = (f"the measurement frame of {args.calibrated}" if args.targets_frame == "meas" and
             T_meas_base is not None else f"base frame {nominal.base_frame}")
    comment = (f"Corrected joint values, computed by: {command_line(args)}\n"
               f"Targets: {kind} targets of {args.targets} (tool frame {nominal.tool_frame} "
               f"in {frame}); status ok: the calibrated model reaches the "
               f"target; other rows must not be sent to the robot as they are"
               + ("\nThe calibration measured no tool orientation: the orientations reached are the model's "
                  "prediction, not calibrated" if uncalibrated_orientation else ""))
    outputs.stage_from_file(out, lambda p: write_compensation(p, result, comment=comment))
    outputs.commit()
    sys.stdout.write(result.format() + f"\n\nwrote {out}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"{PROG}: warning: {bad} of {result.n_targets} targets are not ok (see the "
                         f"status and detail columns of {out})\n")
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _last_link_models(args, calibrated, nominal):
    """The models with the last joint's child link as tool frame, for joint targets after a
    calibration whose tool frame was estimated (a measured point, not the nominal tool): the
    link's pose is compensated, so any tool on it reaches its nominal pose (note on stderr)."""
    from calib.compensation.compensate import flange_link, load_compensation_models

    if args.measure == "position":
        raise ParameterError(f"--measure position: {args.calibrated}'s tool frame is the point the calibration "
                             f"measured, not the nominal tool, so joint targets are compensated for the pose of "
                             f"the last link (every tool on it then reaches its nominal pose): use --measure pose")
    link = flange_link(nominal)
    sys.stderr.write(f"{PROG}: note: {args.calibrated}'s tool frame is the point the calibration measured, "
                     f"not the nominal tool: joint targets are compensated for the pose of the last link "
                     f"{link!r} (every tool fixed to it reaches its nominal pose; the tool's own error was "
                     f"not calibrated)\n")
    cal, nom = load_compensation_models(args.calibrated, args.nominal, base_frame=args.base_frame,
                                        tool_frame=link)
    cal = with_compliance_file(cal, args, torques_from=nom,
                               hint=" (the report or the compliance sidecar of the calibration)")
    return cal, nom


def _homogeneous(R, p):
    """(N, 4, 4) from rotations (N, 3, 3) and positions (N, 3)."""
    import numpy as np

    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T

