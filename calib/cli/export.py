"""``calib export CALIBRATED.urdf --format F -o OUT``: a calibrated URDF in the form the user's
stack takes (UR kinematics YAML, joint origins for a xacro, an MDH table)."""
from __future__ import annotations

import argparse
import sys

from calib.choices import EXPORT_FORMATS
from calib.cli.args import COMMON_EPILOG, HelpFormatter, add_frames, add_verbose, print_notes
from calib.cli.inputs import add_ur_type, robot_description
from calib.cli.output import EXIT_OK, PROG, Outputs
from calib.errors import ParameterError

__all__ = ["add_parser", "run"]

_EXPORT_DESC = """\
Export a calibrated URDF (written by calib calibrate, or any URDF) for the user's stack:

  ur-yaml             the `kinematics:` file of Universal Robots' ur_description, which
                      ur_robot_driver reads through kinematics_params_file: x, y, z, roll, pitch,
                      yaw of the joint origins shoulder, upper_arm, forearm, wrist_1, wrist_2,
                      wrist_3 and a hash. The chain's six moving joints map by order (the first
                      from the base is shoulder ... the sixth wrist_3), whatever their names; a
                      chain that is not UR-like (six revolute joints, axes 2-4 parallel, 1 normal
                      to 2, 5 normal to 4 and 6) is refused. The template's base_link is the
                      URDF's base frame, its tool0 the --flange link; the forward kinematics of
                      the URDF built from the file equal the calibrated ones (checked to 1e-9 m).
  joint-origins-yaml  every joint of the URDF: type, parent, child and the text of its origin xyz,
                      rpy (and axis), ready for a xacro's properties (docs/exports.md).
  mdh-csv             theta, d, a, alpha, beta per joint and the base and tool transforms, mm and
                      deg in the column names; with --report, the calibration's own parameters
                      and their standard deviations (1 sigma).

Every export is read back and checked against the URDF's kinematics before it is written."""

_EXPORT_EPILOG = """\
examples:
  calib export calibrated.urdf --format ur-yaml -o my_robot_calibration.yaml --hash calib_lab2
  calib export calibrated.urdf --format joint-origins-yaml -o calibrated_joints.yaml
  calib export calibrated.urdf --format mdh-csv --report report.json -o mdh.csv
""" + COMMON_EPILOG


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``export`` to ``subparsers`` (from ``add_subparsers``); it runs :func:`run`."""
    p = subparsers.add_parser("export", help="a calibrated URDF as UR kinematics YAML, xacro joint origins or "
                                             "an MDH table", description=_EXPORT_DESC, epilog=_EXPORT_EPILOG,
                              formatter_class=HelpFormatter)
    p.add_argument("robot", metavar="CALIBRATED.urdf", help="the calibrated URDF (calib calibrate -o), or any URDF, "
                                                            "or a UR kinematics YAML (with --ur-type)")
    add_ur_type(p)
    p.add_argument("--format", required=True, choices=EXPORT_FORMATS, metavar="F",
                   help=f"what to write: {', '.join(EXPORT_FORMATS)}")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="the file to write (never an input)")
    p.add_argument("--hash", default=None, metavar="TEXT",
                   help="ur-yaml: kinematics.hash, which ur_robot_driver compares with the controller's "
                        "calibration checksum (default: calib_ and 63 bits of the SHA-256 of the "
                        "exported numbers)")
    p.add_argument("--flange", default=None, metavar="LINK",
                   help="ur-yaml: the link the template's tool0 stands for, fixed to the last link (default: "
                        "tool0 if the URDF has it there, else the tool frame); projected onto axis 6")
    p.add_argument("--report", default=None, metavar="REPORT.json",
                   help="mdh-csv: the calibration's JSON report (calib calibrate --report): its parameters "
                        "and their standard deviations, checked against the URDF")
    add_frames(p, base_help="URDF link of the chain's base (default: the one the calibrated URDF records, "
                            "else the root link)",
               tool_help="URDF link of the chain's tool (default: the one the calibrated URDF records)")
    add_verbose(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib export`` with parsed arguments; returns the exit code."""
    for flag, value, fmt in (("--hash", args.hash, "ur-yaml"), ("--flange", args.flange, "ur-yaml"),
                             ("--report", args.report, "mdh-csv")):
        if value is not None and args.format != fmt:
            raise ParameterError(f"{flag} applies to --format {fmt} only, not {args.format}")
    outputs = Outputs([args.robot, args.report])
    out = outputs.add(args.output)
    from calib.io.exports.export import export_calibration

    result = export_calibration(robot_description(args, args.robot), args.format, kinematics_hash=args.hash,
                                report=args.report, flange_frame=args.flange, base_frame=args.base_frame,
                                tool_frame=args.tool_frame)
    outputs.stage(out, result.text)
    outputs.commit()
    print_notes(result.notes, PROG)
    sys.stdout.write(f"wrote {out} ({args.format}; read back, its kinematics are the URDF's to "
                     f"{result.read_back[0]:.2g} m, {result.read_back[1]:.2g} rad)\n")
    return EXIT_OK
