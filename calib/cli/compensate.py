"""``calib compensate CALIBRATED.urdf NOMINAL.urdf TARGETS.csv -o CORRECTED.csv``: corrected joint
values, where to send a calibrated robot so that its tool reaches the targets (a thin layer over
:mod:`calib.compensation.compensate`). Exit code 3 when some targets are not ``ok``: the output is
written all the same, with the status of each row."""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from calib.cli.args import (HelpFormatter, add_compliance, add_file_format, add_frames, add_verbose, nonnegative, print_notes, read_options, with_compliance_file)
from calib.cli.inputs import add_ur_type, robot_description, urdf_only
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
                         the default; with a --convention naming a controller, that controller's
                         base frame, e.g. UR's Base = ROS-I 'base', pi about z from base_link;
                         meas: the calibration's measurement frame; --targets-link LINK),
    [+ qw, qx, qy, qz]   with an orientation (unit quaternion, scalar first; or rz_deg, ry_deg,
                         rx_deg, R = Rz Ry Rx; or e1..e3 with --euler, rvx..rvz, r11..r33 as in
                         measurement files); joint columns, if also given, are the start of the
                         solver and choose the solution branch; else the configuration columns
                         (KUKA S and T, ABB cf1 cf4 cf6 cfx, FANUC config 'N U T, 0, 0, 0';
                         with --convention); else the nominal model's own solution (from the
                         nearest of 512 seed configurations). Corrected joints that leave that
                         branch are refused (status branch)
  name                   the target's name, written back in the output

Other columns are ignored (listed on stderr). Semicolon or tab separators with decimal commas,
--rename and --limit-tolerance work as for measurement files (calib formats; docs/formats.md).
The controller's frames, configurations and programs: docs/compensation.md.

A robot program instead of TARGETS.csv (by its suffix: KUKA .dat, ABB .mod, URScript .script,
FANUC .ls): -o names a corrected copy of the same kind, every other character kept. Joint
targets (E6AXIS, jointtarget, movej [..], J1..) are corrected; pose targets (E6POS, robtarget,
p[..], X..R) are taken in the controller's base frame on their configuration's branch and
rewritten as the pose the controller turns into the corrected joints, with their configuration.
Nothing is written unless every target is ok.

Output CSV, one row per target in the same order: name (when the targets have names), the
corrected joint columns (degrees, millimetres for prismatic joints; with --convention, the
controller's joint names, units and digits, and its configuration of the corrected joints), then status, residual_mm, residual_rad (pose targets),
frame_std_mm and frame_std_deg (after a calibration that estimated the measurement frame, for
targets in the robot's base frame: the 1-sigma error of the reached pose that the uncertainty
of the measurement->base transform causes) and detail. status is
  ok             the calibrated model reaches the target within the joint limits
  limit          reached, but a joint is beyond its limit (detail: which and by how much);
                 the joint values are written as computed, never clipped
  singular       the joint Jacobian's smallest singular value is below --singular-threshold
                 (near a singularity: a tiny pose error needs a large joint motion)
  not_converged  the target was not reached
  branch         refused: the corrected joints left the branch asked for (detail: how)
Rows that are not ok must not be sent to the robot as they are.

Which tool the targets are for (one line on stdout says it): the tool frame (--tool-frame,
default the one the calibration was made for), or a tool fixed to it, --tool-offset X,Y,Z[,ROLL,
PITCH,YAW] (mm and degrees, URDF roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll), in the tool frame).
After a calibration of several targets (reflectors, a target column) the tool frame stays at the
flange in CALIBRATED.urdf, the targets fixed links tool_<id> under it: targets are for the
flange (or the tool given), not for the reflectors.

Joint targets after a calibration that estimated the tool frame (one reflector, not the nominal
tool) are compensated for the pose of the last link: every tool on it reaches its nominal pose.

Frames: --base-frame and --tool-frame name frames of NOMINAL.urdf; the calibrated URDF's matching
frames are found as calib's URDF writer made them (its root link plays the meas frame when the
nominal base frame is the root link; a link the writer added under the tool frame is the tool)."""

_COMP_EPILOG = """\
examples:
  calib compensate calibrated.urdf robot.urdf program_joints.csv -o corrected.csv
  calib compensate calibrated.urdf robot.urdf cad_poses.csv -o corrected.csv --tool-frame tool0
  calib compensate calibrated.urdf robot.urdf cad_poses.csv -o corrected.csv --tool-offset 0,0,180,0,0,45
      (the centre point of a tool 180 mm along tool0's z, turned 45 deg about it)
  calib compensate calibrated.urdf robot.urdf tracker_poses.csv -o corrected.csv --targets-frame meas
  calib compensate calibrated.urdf ur5e.urdf waypoints.csv -o corrected.csv --convention ur --tool-frame tool0
  calib compensate calibrated.urdf kr16_2.urdf cell.dat -o cell_corrected.dat
  (CALIBRATED.urdf comes from: calib calibrate robot.urdf meas.csv -o calibrated.urdf)

Exit codes: 0 every target ok; 3 some targets are not ok (the output is written, see the status
column; a summary is printed; a program's copy is not written); 2 bad input (one-line message,
nothing written)."""



def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``compensate`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    from calib.choices import SINGULAR_THRESHOLD

    p = subparsers.add_parser("compensate", help="corrected joint values for targets",
                              description=_COMP_DESC, epilog=_COMP_EPILOG,
                              formatter_class=HelpFormatter)
    p.add_argument("calibrated", metavar="CALIBRATED.urdf",
                   help="calibrated URDF (written by calib calibrate)")
    p.add_argument("nominal", metavar="NOMINAL.urdf",
                   help="nominal URDF (the model the controller uses), or a UR kinematics YAML (with --ur-type)")
    add_ur_type(p)
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
    frames = p.add_mutually_exclusive_group()
    frames.add_argument("--targets-frame", choices=("base", "controller", "meas"), default=None,
                        help="frame of pose targets: controller (the default with a --convention naming a "
                             "controller), that controller's own base frame, the one its programs and "
                             "pendant use (ROS-Industrial's link 'base' of NOMINAL.urdf, e.g. UR: pi about z "
                             "from base_link); base (the default otherwise), the robot's base frame "
                             "(--base-frame); meas, the measurement frame of the calibration (the "
                             "tracker's), taken from CALIBRATED.urdf's record. One line of the output says "
                             "which frame was used")
    frames.add_argument("--targets-link", metavar="LINK", default=None,
                        help="pose targets in the frame of this link (or joint) of NOMINAL.urdf, fixed to "
                             "the robot's base (a work object or user frame the URDF holds)")
    add_file_format(p)
    add_frames(p, base_help="link (or joint) of NOMINAL.urdf that is the robot's base frame, in which "
                            "pose targets are given with --targets-frame base (default: the root link)",
               tool_help="link (or joint) of NOMINAL.urdf whose pose is targeted (default: the "
                         "last link before the tree branches)")
    p.add_argument("--tool-offset", type=_tool_offset, default=None, metavar="X,Y,Z[,ROLL,PITCH,YAW]",
                   help="targets are for a tool fixed to the tool frame: its centre point at X,Y,Z mm in the "
                        "tool frame, turned by ROLL,PITCH,YAW deg (URDF roll-pitch-yaw; default 0,0,0)")
    p.add_argument("--j23-factor", type=float, choices=(-1.0, 0.0, 1.0), default=None, metavar="F",
                   help="FANUC programs of joint positions: the model's J2/J3 interaction, as ROS-Industrial's "
                        "FANUC driver takes it (J23_factor: J3 of the URDF = J3 + F * J2): -1, 0 or 1")
    add_compliance(p, "compensate")
    add_verbose(p, help="log progress on stderr")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib compensate`` with parsed arguments; returns the exit code."""
    from calib.compensation.compensate import check_joint_targets, compensate, load_compensation_models
    from calib.io.csv.specs import read_targets

    from calib.io.programs import vendor_of

    program = vendor_of(args.targets)
    outputs = Outputs([args.calibrated, args.nominal, args.targets])
    if program is not None and vendor_of(args.output) != program:
        raise ParameterError(f"-o {args.output}: {args.targets} is a {program} program; the corrected copy is one "
                             f"too (a file ending in {Path(args.targets).suffix})")
    out = outputs.add(args.output)
    urdf_only(args.calibrated, "CALIBRATED must be the URDF calib calibrate wrote")
    nominal_source = robot_description(args, args.nominal)
    calibrated, nominal = load_compensation_models(args.calibrated, nominal_source,
                                                   base_frame=args.base_frame,
                                                   tool_frame=args.tool_frame)
    if program is not None:
        calibrated = with_compliance_file(calibrated, args, torques_from=nominal,
                                          hint=" (the report or the compliance sidecar of the calibration)")
        return _run_program(args, calibrated, nominal, outputs, out, program)
    calibrated = with_compliance_file(calibrated, args, torques_from=nominal,
                                      hint=" (the report or the compliance sidecar of the calibration)")
    if args.compliance is not None:
        log.info("compliance from %s: %s", args.compliance, calibrated.describe().splitlines()[-1])
    rec = calibrated.source.document.frames if calibrated.source is not None else None
    if args.tool_offset is not None:
        from calib.compensation.compensate import with_tool_offset

        if rec is not None and rec.tool_estimated:
            raise ParameterError(f"--tool-offset: {args.calibrated}'s tool frame is the point the calibration measured "
                                 f"(a reflector), not the nominal tool frame {nominal.tool_frame!r}: an offset from "
                                 f"it is no tool's; calibrate with several reflectors (the tool frame then stays at "
                                 f"the flange) or give the tool's poses")
        calibrated, nominal = (with_tool_offset(m, args.tool_offset[0]) for m in (calibrated, nominal))
    log.info("nominal %s (frames %r -> %r), calibrated %s (frames %r -> %r)", args.nominal,
             nominal.base_frame, nominal.tool_frame, args.calibrated, calibrated.base_frame,
             calibrated.tool_frame)
    targets = read_targets(args.targets, nominal, options=read_options(args))
    print_notes(targets.notes)
    uncalibrated_orientation, several = _orientation_notes(args, rec, targets)
    kind = {"joints": "joint"}.get(targets.kind, targets.kind)      # joint, pose, position
    log.info("read %d %s targets from %s", targets.n_targets, kind, args.targets)
    T_meas_base = None if rec is None else rec.measurement_transform
    opts = dict(singular_threshold=args.singular_threshold)
    frame = None
    if targets.kind == "joints":
        given = (f"--targets-frame {args.targets_frame}" if args.targets_frame not in (None, "base") else
                 f"--targets-link {args.targets_link}" if args.targets_link is not None else None)
        if given:
            raise ParameterError(f"{given}: {args.targets} holds joint targets, "
                                 f"which have no frame (their poses are the nominal model's)")
        check_joint_targets(calibrated)
        if rec is not None and rec.tool_estimated:
            calibrated, nominal = _last_link_models(args, calibrated, nominal, nominal_source)
        result = compensate(calibrated, nominal, targets.q, measure=args.measure, **opts)
    else:
        result, frame = _pose_targets(args, calibrated, nominal, targets, T_meas_base, opts)
    if T_meas_base is not None and (targets.kind == "joints" or _targets_frame_name(args) != "meas"):
        from calib.compensation.compensate import with_frame_uncertainty

        result = with_frame_uncertainty(result, T_meas_base=T_meas_base, covariance=rec.measurement_covariance)
    if frame is not None:
        where = frame.text
    elif targets.kind != "joints" and T_meas_base is not None:
        where = f"the measurement frame of {args.calibrated}"
    else:
        where = f"base frame {nominal.base_frame}"
    tool_line = f"{kind} targets of {args.targets} are for {_tool_line(args, calibrated, rec)}, in {where}"
    comment = (f"Corrected joint values, computed by: {command_line(args)}\n"
               f"Targets: {tool_line}; status ok: the calibrated model reaches the "
               f"target; other rows must not be sent to the robot as they are"
               + ("\nThe calibration measured the positions of several targets: the orientations reached are "
                  "calibrated but for the turn about the last joint's axis and the tilt from it (nominal)" if several
                  else "\nThe calibration measured no tool orientation: the orientations reached are the model's "
                  "prediction, not calibrated" if uncalibrated_orientation else ""))
    if targets.names is not None:
        from dataclasses import replace

        result = replace(result, names=targets.names)
    _stage_output(args, outputs, out, result, targets, nominal, frame, comment)
    outputs.commit()
    sys.stdout.write(f"{result.format()}\n{tool_line}\n\nwrote {out}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"{PROG}: warning: {bad} of {result.n_targets} targets are not ok (see the "
                         f"status and detail columns of {out})\n")
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _orientation_notes(args, rec, targets) -> tuple[bool, bool]:
    """(whether the calibration measured no tool orientation that the targets ask for, whether
    it measured the positions of several targets instead), each said on stderr."""
    uncalibrated_orientation = (rec is not None and not rec.orientation_measured
                                and (targets.kind == "pose" or (targets.kind == "joints" and args.measure == "pose")))
    several = uncalibrated_orientation and len(rec.targets) > 2
    if several:
        sys.stderr.write(f"{PROG}: note: {args.calibrated}'s calibration measured the positions of "
                         f"{len(rec.targets)} targets: the tool's orientation follows from them but for the turn "
                         f"about the last joint's axis and the tilt from it, held at the nominal (targets cannot "
                         f"tell them from their own offsets)\n")
    elif uncalibrated_orientation:
        sys.stderr.write(f"{PROG}: note: {args.calibrated}'s calibration measured no tool orientation (positions "
                         f"only, or touch rows): the corrected joints reach the targets' orientations as the "
                         f"model predicts them, which the measurements did not check; status ok vouches for "
                         f"the position (--measure position corrects the position alone)\n")
    return uncalibrated_orientation, several


def _pose_targets(args, calibrated, nominal, targets, T_meas_base, opts):
    """The compensation of pose or position targets, taken in the frame the options name (the
    controller's, a link, the base frame or the measurement frame) on the branch their seeds or
    configurations give: (the result, the frame or None for the measurement / base frame)."""
    from calib.compensation.compensate import compensate_poses

    T = _homogeneous(targets.rotation, targets.position) if targets.kind == "pose" else None
    p = targets.position if targets.kind != "pose" else None
    where, frame = _targets_frame_name(args), None
    if where != "meas":
        from calib.compensation.compensate import pose_targets_from_frame
        from calib.io.urdf.controller_frame import targets_frame

        frame = targets_frame(nominal, convention=args.convention if where == "controller" else None,
                              link=args.targets_link)
        if T is not None:
            T = pose_targets_from_frame(T_base_frame=frame.T_base_frame, T_frame_tool=T)
        else:
            p = pose_targets_from_frame(T_base_frame=frame.T_base_frame, p_frame_tool=p)
    elif T_meas_base is None:
        sys.stderr.write(f"{PROG}: note: {args.calibrated} records no measurement frame (the calibration's "
                         f"measurements were in the robot's base frame): meas = base\n")
    else:
        from calib.compensation.compensate import pose_targets_in_base

        if T is not None:
            T = pose_targets_in_base(T_meas_base=T_meas_base, T_meas_tool=T)
        else:
            p = pose_targets_in_base(T_meas_base=T_meas_base, p_meas_tool=p)
    configurations = None
    if targets.q is None:
        from calib.compensation.configuration import Configurations
        from calib.io.csv.targets import configurations_of

        values = configurations_of(targets, args.convention)
        if values is not None:
            configurations = Configurations(args.convention, values, None if frame is None else frame.T_base_frame)
    branch = dict(nominal=nominal, configurations=configurations) if targets.q is None else {}
    if T is not None:
        return compensate_poses(calibrated, T_meas_tool=T, q_start=targets.q, **opts, **branch), frame
    return compensate_poses(calibrated, p_meas_tool=p, q_start=targets.q, **opts, **branch), frame


def _stage_output(args, outputs, out, result, targets, nominal, frame, comment) -> None:
    """The corrected joints staged in ``outputs``: in the convention's terms (its names, units,
    digits and the vendor's configuration of each target) or calib's own."""
    if args.convention not in (None, "calib"):
        from calib.compensation.configuration import VENDORS, vendor_configuration
        from calib.io.csv.compensation_output import write_compensation_convention

        confs = None
        if args.convention in VENDORS and _six_revolute(nominal):
            confs = vendor_configuration(nominal, result.q, args.convention,
                                         T_base_frame=None if frame is None else frame.T_base_frame)
        outputs.stage_from_file(out, lambda p: write_compensation_convention(
            p, result, convention=args.convention, names=targets.names, configurations=confs, comment=comment))
    else:
        from calib.io.csv.specs import write_compensation

        outputs.stage_from_file(out, lambda p: write_compensation(p, result, comment=comment, names=targets.names))


def _six_revolute(robot) -> bool:
    return robot.n_joints >= 6 and not robot.prismatic[:6].any()


def _targets_frame_name(args) -> str:
    """The frame of pose targets: "meas", "base", "controller" (the --convention's controller
    frame) or "link" (--targets-link); the default is the controller's frame under a
    --convention that names one, else the robot's base frame."""
    from calib.io.csv.conventions import CONVENTIONS

    if args.targets_link is not None:
        return "link"
    convention = getattr(args, "convention", None)
    named = convention is not None and CONVENTIONS[convention].controller is not None
    if args.targets_frame == "controller" and not named:
        raise ParameterError("--targets-frame controller: give the controller with --convention "
                             + "/".join(k for k, c in CONVENTIONS.items() if c.controller is not None))
    return args.targets_frame or ("controller" if named else "base")


def _last_link_models(args, calibrated, nominal, nominal_source):
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
    cal, nom = load_compensation_models(args.calibrated, nominal_source, base_frame=args.base_frame,
                                        tool_frame=link)
    cal = with_compliance_file(cal, args, torques_from=nom,
                               hint=" (the report or the compliance sidecar of the calibration)")
    return cal, nom


def _tool_offset(text: str):
    """``X,Y,Z[,ROLL,PITCH,YAW]`` (mm, deg) of --tool-offset: ((4, 4) T_tool_tcp in metres, the six
    numbers as given)."""
    import math

    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (3, 6) or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected X,Y,Z or X,Y,Z,ROLL,PITCH,YAW (mm, deg), got {text!r}")
    import numpy as np
    import pinocchio as pin

    v += [0.0] * (6 - len(v))
    T = np.eye(4)
    T[:3, :3] = pin.rpy.rpyToMatrix(*np.radians(v[3:]))
    T[:3, 3] = np.array(v[:3]) * 1e-3
    return T, tuple(v)


def _tool_line(args, calibrated, rec) -> str:
    """What the targets are for, for the line compensate prints: the tool frame (the flange of a
    calibration of several targets, whose target links are named) or the tool of --tool-offset."""
    tool = calibrated.tool_frame
    flange = rec is not None and rec.tool_kept and len(rec.targets) > 1
    where = f"at the flange of {args.calibrated}" if flange else f"of {args.calibrated}"
    if flange:
        where += (" (the calibration measured the links "
                  + ", ".join(f"{link} ({t})" for t, link in rec.targets) + " under it)")
    if rec is not None and tool not in calibrated.source.document.links:     # a tool link added since
        what = (f"tool frame {tool!r} of {args.nominal}, fixed to {rec.tool_frame!r} "
                + where.replace("at the flange of", "at the flange in", 1))
    elif flange and tool == rec.tool_frame:
        what = f"tool frame {tool!r} {where}"
    else:
        what = f"tool frame {tool!r} of {args.calibrated}"
    if args.tool_offset is None:
        return what
    x, y, z, r, p, w = args.tool_offset[1]
    return (f"the tool at {x:g}, {y:g}, {z:g} mm, roll-pitch-yaw {r:g}, {p:g}, {w:g} deg in "
            + what.replace("tool frame ", "", 1))


def _homogeneous(R, p):
    """(N, 4, 4) from rotations (N, 3, 3) and positions (N, 3)."""
    import numpy as np

    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T


def _run_program(args, calibrated, nominal, outputs, out, vendor: str) -> int:
    """``calib compensate CALIBRATED.urdf NOMINAL.urdf PROGRAM -o CORRECTED``: a corrected copy of a
    robot program (KRL .dat, RAPID .mod, URScript .script, FANUC .LS), its structure and comments kept
    (:mod:`calib.io.programs`, :mod:`calib.compensation.program`). Nothing is written unless every
    target is ok: a refused target (a frame the program does not define) is one line and exit 2;
    targets the calibrated robot cannot reach on their branch are listed (exit 3)."""
    from calib.compensation.program import compensate_program
    from calib.io.urdf.controller_frame import targets_frame
    from calib.io.programs import corrected_program, read_program

    if args.convention not in (None, vendor):
        raise ParameterError(f"--convention {args.convention}: {args.targets} is a {vendor} program")
    if args.targets_frame == "meas":
        raise ParameterError("--targets-frame meas: a program's poses are in its controller's base frame")
    options = {"j23_factor": args.j23_factor} if vendor == "fanuc" else {}
    program = read_program(args.targets, nominal, options=options)
    for note in program.notes:
        sys.stderr.write(f"{PROG}: note: {args.targets}: {note}\n")
    frame = targets_frame(nominal, convention=None if args.targets_frame == "base" or args.targets_link else vendor,
                          link=args.targets_link)
    comp = compensate_program(calibrated, nominal, program, T_base_frame=frame.T_base_frame,
                              singular_threshold=args.singular_threshold)
    result = comp.result
    kinds = {t.kind for t in program.targets}
    sys.stdout.write(result.format() + f"\n  {len(program.targets)} targets of {args.targets} "
                     f"({', '.join(sorted(kinds))}); poses of tool frame {nominal.tool_frame}; {frame.text}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"{PROG}: {bad} of {result.n_targets} targets of {args.targets} are not ok (listed above): "
                         f"nothing written\n")
        return EXIT_NOT_CONVERGED
    text = corrected_program(program, nominal, q=comp.q, T=comp.T_out, configurations=list(comp.configurations),
                             options=options)
    outputs.stage(out, text.encode(program.encoding))
    outputs.commit()
    sys.stdout.write(f"\nwrote {out}\n")
    return EXIT_OK
