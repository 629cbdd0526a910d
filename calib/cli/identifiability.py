"""``calib identifiability ROBOT.urdf``: which parameters the measurements can identify."""
from __future__ import annotations

import argparse
import sys

from calib.cli.args import (COMMON_EPILOG, HelpFormatter, add_compliance, add_frames, add_targets, add_verbose, compliance_options, count, positive_int, with_targets)
from calib.cli.inputs import add_robot, load
from calib.cli.output import EXIT_OK, json_text
from calib.errors import CalibError, ParameterError

__all__ = ["add_parser", "run"]

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
""" + COMMON_EPILOG


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``identifiability`` to ``subparsers`` (from ``add_subparsers``); it runs :func:`run`."""
    p = subparsers.add_parser("identifiability", help="which parameters the measurements can identify",
                       description=_IDENT_DESC, epilog=_IDENT_EPILOG, formatter_class=HelpFormatter)
    add_robot(p)
    p.add_argument("--measure", choices=("pose", "position"), default="pose",
                   help="what is measured: position and orientation, or position only")
    p.add_argument("--poses", type=positive_int, default=100, metavar="N",
                   help="number of random configurations")
    p.add_argument("--seed", type=count, default=0, metavar="S",
                   help="random seed of the configurations")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (n_params, rank, identifiable, unidentifiable with "
                        "tied partners, condition_number, observability, ...)")
    p.add_argument("--touch", metavar="TOUCH.csv", default=None,
                   help="analyse these touch rows (points, planes, spheres touched, docs/touch.md) instead of "
                        "random measured poses: the robot parameters they determine with the features, "
                        "those held nominal and what they are tied to")
    p.add_argument("--params", choices=("auto", "tool"), default="auto",
                   help="with --touch: every geometric parameter a candidate, or the tool offset only")
    add_frames(p)
    add_compliance(p, "calibrate")
    add_targets(p)
    add_verbose(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib identifiability`` with parsed arguments; returns the exit code."""
    from calib.units import DISPLAY_UNITS
    from calib.model.identifiability_report import analyze_identifiability

    if args.touch is not None:
        from calib.calibration.parameters import touch_identifiability
        from calib.io.csv.touch import read_touch

        robot = load(args)
        data = read_touch(args.touch, robot)
        try:
            ident = touch_identifiability(robot, data, params=args.params)
        except CalibError as exc:   # about the rows as a whole (a degenerate design): name the file
            raise type(exc)(f"{args.touch}: {exc}") from None
        sys.stdout.write((json_text(ident.to_dict()) if args.json else ident.format() + "\n"))
        return EXIT_OK
    robot = with_targets(load(args), args)
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
        sys.stdout.write(json_text(out))
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
        lines.append(f"{p.name:<{w}}{DISPLAY_UNITS[p.unit][0]:>5}  {of:<14}{status:<13}"
                     f"{partners}".rstrip())
    lines += ["", report.format(), ""]
    sys.stdout.write("\n".join(lines))
    return EXIT_OK

