"""``calib select-poses ROBOT.urdf -n N -o POSES.csv``: the configurations worth measuring (a thin
layer over :mod:`calib.design.poses`)."""
from __future__ import annotations

import argparse
import logging
import sys

from calib.cli.args import (HelpFormatter, add_frames, add_progress, add_targets, add_verbose, count, positive, positive_int, progress_enabled, with_targets)
from calib.cli.inputs import add_ur_type, robot_description
from calib.cli.output import EXIT_OK, Outputs, command_line
from calib.cli.progress import Progress, stage

__all__ = ["add_parser", "run"]

log = logging.getLogger(__name__)

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
with few poses (20 to 30 for a 6-axis arm).

The poses are not checked for collisions, the floor, the instrument's line of sight or travel:
`calib plan` plans poses a robot can run in its cell, and writes its program (docs/plan.md)."""

_SELECT_EPILOG = """\
examples:
  calib select-poses robots/brtirus0707a/brtirus0707a.urdf -n 25 -o poses.csv --seed 1
  calib select-poses robot.urdf -n 40 -o poses.csv --measure position --criterion O4 \\
      --candidates 5000 --tool-frame tool0
  calib select-poses robot.urdf -n 20 -o poses.csv --measure position \\
      --target A=100,0,50 --target B=-50,80,50 --target C=0,-70,100

Same --seed, same poses. Exit codes: 0 success, 2 bad input (one-line message, nothing written)."""


def _criterion(text: str) -> str:
    from calib.choices import POSE_CRITERIA as CRITERIA

    if text.upper() not in CRITERIA:
        raise argparse.ArgumentTypeError(f"{text!r} is not a criterion; choose from "
                                         f"{', '.join(CRITERIA)}")
    return text.upper()


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``select-poses`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser("select-poses", help="choose the poses to measure (optimal design)",
                              description=_SELECT_DESC, epilog=_SELECT_EPILOG,
                              formatter_class=HelpFormatter)
    p.add_argument("robot", metavar="ROBOT.urdf", help="URDF of the robot (the nominal model), or a UR "
                                                       "kinematics YAML (ROBOT.yaml, with --ur-type)")
    add_ur_type(p)
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
    add_progress(p)
    add_verbose(p, help="log progress on stderr")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``calib select-poses`` with parsed arguments; returns the exit code."""
    from calib.design.poses import design_poses
    from calib.io.csv.specs import write_poses
    from calib.io.urdf.reader import load_robot

    outputs = Outputs([args.robot])
    out = outputs.add(args.output)
    robot = load_robot(robot_description(args, args.robot), base_frame=args.base_frame,
                       tool_frame=args.tool_frame)
    log.info("robot %s: %d joints (%s), base frame %r, tool frame %r", args.robot, robot.n_joints,
             ", ".join(robot.joint_names), robot.base_frame, robot.tool_frame)
    robot = with_targets(robot, args)
    with Progress(12, f"selecting {args.n} of {args.candidates} candidate poses, step",
                  enabled=progress_enabled(args)) as progress, stage(log, "pose selection"):
        design = design_poses(robot, args.n, candidates=args.candidates, criterion=args.criterion,
                              measure=args.measure, seed=args.seed,
                              sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad,
                              progress=progress.set)
    log.info("selection: %d exchange passes, %d swaps, %.3f s", design.passes, design.swaps,
             design.elapsed)
    c, b = design.criteria, design.random_criteria
    comment = (f"Poses to measure, selected by: {command_line(args)}\n"
               f"Robot {args.robot}: base frame {robot.base_frame}, tool frame {robot.tool_frame}; "
               f"{args.measure} measurements"
               + (f" of targets {', '.join(robot.targets)} at every pose" if robot.targets else "") + "\n"
               f"Criterion {design.criterion}: log det {c['D']:.6g} (random sets: {b['D']:.6g}), "
               f"O1 {c['O1']:.4g} ({b['O1']:.4g}), O4 {c['O4']:.4g} ({b['O4']:.4g}), condition "
               f"number {c['condition_number']:.4g} ({b['condition_number']:.4g})\n"
               f"After measuring, add x_mm,y_mm,z_mm (and qw,qx,qy,qz) columns for calib calibrate"
               + ("; one row per target measured, with its id in a target column" if robot.targets else ""))
    outputs.stage_from_file(out, lambda p: write_poses(p, robot, design.q, comment=comment))
    outputs.commit()
    sys.stdout.write(design.format() + f"\n\nwrote {design.n_poses} poses to {out}\n")
    return EXIT_OK

