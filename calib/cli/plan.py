"""``calib plan ROBOT.urdf --poses N -o plan.csv [--cell CELL.yaml]``: a measurement plan a robot
can run (a thin layer over :mod:`calib.design.plan` and :mod:`calib.design.touch_plan`).

Why a command of its own beside ``select-poses``: ``select-poses`` is the unconstrained
selection, which needs no collision geometry (it runs from a UR kinematics YAML) and whose poses
``plan`` prints beside its own (what the cell costs); ``plan`` needs the URDF's collision
geometry and checks every pose and move, and writes the robot's programs.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from calib.cli.args import (HelpFormatter, add_frames, add_progress, add_verbose, count, positive, positive_int,
                            progress_enabled)
from calib.cli.output import EXIT_OK, Outputs, command_line

__all__ = ["add_parser", "run", "PROGRAM_SUFFIXES"]

log = logging.getLogger(__name__)

#: Program files ``--program`` writes, by suffix: the vendor (:mod:`calib.io.programs`).
PROGRAM_SUFFIXES = {".script": "ur", ".urscript": "ur", ".src": "kuka", ".mod": "abb", ".ls": "fanuc"}

_DESC = """\
Plan the poses of a calibration so that the robot can run them: free of collisions with itself
and its cell, in sight of the instrument, informative, in a short order, as the robot's program.

Candidates are drawn within the joint limits (less the cell's joint margin); with an instrument
each is turned so that a target on the tool faces it (within the target's acceptance cone).
Feasible are those with no collision (Pinocchio's collision model of the URDF's collision
geometry: the robot's links with each other, less adjacent links and pairs in collision at every
sampled configuration, and with the floor, the cell's boxes and the instrument, at the
clearances), the tool in the workspace box, and the instrument's line of sight to a target free
of the links and boxes. Of these, --poses are chosen by the optimality criterion (as
select-poses), then exchanged for nearby ones where that shortens the travel by more than it
costs (--travel-budget: the share the predicted error may grow by), ordered for short travel
(joint moves at the URDF's velocity limits), and each move checked along its length, with
waypoints where a straight joint move would collide.

Without --cell: no instrument (the tool's pose measured), self-collision and the floor (the base
frame's xy-plane) checked. A cell with touch features (nests, planes) plans touch rows instead:
their poses are given per feature in the cell file, and the output is a touch file.

Prints the plan's criteria and predicted accuracy beside those of the unconstrained selection of
as many candidates, and the travel beside a random order's. Writes the poses (the point column
names them P01 ... in visiting order: give the instrument's points the same names and join the
files with `calib calibrate ROBOT.urdf PLAN.csv --tracker TRACKER.csv --key point`), the
programs (--program) and a picture (--picture)."""

_EPILOG = """\
examples:
  calib plan ur10.urdf --poses 50 -o plan.csv --cell cell.yaml --program plan.script --picture plan.png
  calib plan kr16_2.urdf --poses 50 -o plan.csv --cell cell.yaml --program plan.src --program plan.mod
  calib plan ur10.urdf -o touch.csv --cell nest.yaml --tool-frame tool0

The cell file (YAML, mm and degrees): docs/plan.md. Same --seed, same plan. Exit codes: 0
success, 2 bad input (one line; nothing written): an unreachable nest, an instrument inside the
robot, a cell in which too few poses are feasible, a move no waypoint frees."""


def _criterion(text: str) -> str:
    from calib.choices import POSE_CRITERIA

    if text.upper() not in POSE_CRITERIA:
        raise argparse.ArgumentTypeError(f"{text!r} is not a criterion; choose from {', '.join(POSE_CRITERIA)}")
    return text.upper()


def _percent(text: str) -> float:
    value = positive(text) if text.strip() not in ("0", "0.0") else 0.0
    if value > 100:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a percentage from 0 to 100")
    return value


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``plan`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser("plan", help="a measurement plan the robot can run (poses, order, program)",
                              description=_DESC, epilog=_EPILOG, formatter_class=HelpFormatter)
    p.add_argument("robot", metavar="ROBOT.urdf", help="URDF of the robot with its collision geometry (or a "
                                                       "robot name example-robot-data knows)")
    p.add_argument("-n", "--poses", dest="n", type=positive_int, default=None, metavar="N",
                   help="poses to measure (an instrument's plan; a touch plan takes them per feature "
                        "from the cell file)")
    p.add_argument("-o", "--output", required=True, metavar="PLAN.csv",
                   help="the poses in visiting order (degrees; mm for prismatic joints), or the touch file")
    p.add_argument("--cell", metavar="CELL.yaml", default=None,
                   help="the cell: instrument and targets, or touch features; boxes, clearances (docs/plan.md)")
    p.add_argument("--candidates", type=positive_int, default=10000, metavar="M",
                   help="configurations drawn (a touch plan: approaches per feature, default 300)")
    p.add_argument("--criterion", type=_criterion, default="D", metavar="D|O1|O4",
                   help="what the selection maximises (as select-poses)")
    p.add_argument("--measure", choices=("pose", "position"), default=None,
                   help="what the instrument measures (default: position with an instrument, else pose)")
    p.add_argument("--params", choices=("auto", "tool"), default=None,
                   help="a touch plan: the tool offset only (the TCP; default with nests alone) or the "
                        "identifiable parameters")
    p.add_argument("--seed", type=count, default=0, metavar="S", help="random seed of the draws")
    p.add_argument("--sigma-pos-mm", type=positive, default=0.02, metavar="S",
                   help="position measurement noise per axis, mm (the prediction and the row weights)")
    p.add_argument("--sigma-rot-rad", type=positive, default=0.002, metavar="S",
                   help="orientation measurement noise per axis, rad")
    p.add_argument("--sigma-touch-mm", type=positive, default=0.02, metavar="S",
                   help="a touch plan: the touch noise, mm")
    p.add_argument("--travel-budget", type=_percent, default=5.0, metavar="PCT",
                   help="the share (percent) the predicted error may grow by for shorter travel (0: the "
                        "optimal selection as it is)")
    p.add_argument("--program", action="append", default=[], metavar="FILE",
                   help="write the plan as the robot's program, by suffix: .script (URScript movej), .src "
                        "(KUKA KRL, with its .dat of E6AXIS), .mod (ABB RAPID MoveAbsJ), .ls (FANUC, with "
                        "--j23-factor); repeat for several")
    p.add_argument("--j23-factor", type=float, choices=(-1.0, 0.0, 1.0), default=None, metavar="F",
                   help="a FANUC program: the J2/J3 interaction of the model (ROS-Industrial's J23_factor)")
    p.add_argument("--picture", metavar="PLAN.png", default=None, help="a picture of the plan (PNG)")
    p.add_argument("--package-dir", action="append", default=[], metavar="DIR",
                   help="a folder to find package:// meshes in (before the folders above the URDF)")
    add_frames(p)
    add_progress(p)
    add_verbose(p, help="log the stages on stderr")
    p.set_defaults(func=run)
    return p


def _programs(args, robot, outputs: Outputs) -> list[tuple[str, list[Path]]]:
    """(vendor, output paths) of each --program, checked before any work."""
    from calib.errors import ParameterError

    out = []
    for name in args.program:
        path = Path(name)
        vendor = PROGRAM_SUFFIXES.get(path.suffix.lower())
        if vendor is None:
            raise ParameterError(f"--program {name}: unknown suffix; expected one of {', '.join(PROGRAM_SUFFIXES)}")
        if robot.n_joints > 6 or (vendor == "ur" and robot.n_joints != 6):
            raise ParameterError(f"--program {name}: a {vendor} program holds six robot axes; the chain has "
                                 f"{robot.n_joints} joints")
        if vendor == "fanuc" and args.j23_factor is None:
            raise ParameterError(f"--program {name}: a FANUC program of joint positions needs --j23-factor")
        files = [path.with_suffix(".src"), path.with_suffix(".dat")] if vendor == "kuka" else [path]
        out.append((vendor, [outputs.add(f) for f in files]))
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``calib plan`` with parsed arguments; returns the exit code."""
    from calib.cli.progress import Progress, stage
    from calib.io.cell import DEFAULT_CELL
    from calib.io.cell_file import read_cell
    from calib.io.urdf.collision import collision_geometry
    from calib.io.urdf.reader import load_robot

    outputs = Outputs([args.robot, args.cell])
    out = outputs.add(args.output)
    picture = outputs.add(args.picture) if args.picture else None
    robot = load_robot(args.robot, base_frame=args.base_frame, tool_frame=args.tool_frame)
    programs = _programs(args, robot, outputs)
    cell = read_cell(args.cell) if args.cell else DEFAULT_CELL
    touch = bool(cell.features)
    if not touch and args.n is None:
        from calib.errors import ParameterError

        raise ParameterError("--poses N: how many poses to plan (a touch plan takes them per feature from the cell)")
    geometry = collision_geometry(robot, args.package_dir)
    log.info("robot %s: %d joints, %d collision shapes; cell %s", args.robot, robot.n_joints, geometry.ngeoms,
             args.cell or "(none: the floor only)")
    with Progress(100, "planning, %", enabled=progress_enabled(args)) as progress, stage(log, "plan"):
        if touch:
            from calib.design.touch_plan import plan_touch, probe_model

            plan = plan_touch(robot, cell, geometry=geometry, params=args.params, sigma=args.sigma_touch_mm * 1e-3,
                              seed=args.seed, **({"candidates": args.candidates} if args.candidates != 10000 else {}))
            model = probe_model(robot, cell)
        else:
            from calib.design.plan import plan_measurements

            plan = plan_measurements(robot, args.n, cell, geometry=geometry, candidates=args.candidates,
                                     criterion=args.criterion, measure=args.measure, seed=args.seed,
                                     sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad,
                                     travel_budget=args.travel_budget / 100,
                                     progress=lambda d, t: progress.set(int(100 * d / max(t, 1))))
            model = plan.robot
    _stage_outputs(args, robot, model, cell, plan, touch, out, picture, programs, outputs)
    outputs.commit()
    written = [out] + [p for _, paths in programs for p in paths] + ([picture] if picture else [])
    sys.stdout.write(plan.format() + "\n\n" + "".join(f"wrote {p}\n" for p in written))
    return EXIT_OK


def _stage_outputs(args, robot, model, cell, plan, touch, out, picture, programs, outputs) -> None:
    from calib.io.programs import joint_program_texts

    comment = _comment(args, robot, cell, plan, touch)
    if touch:
        from calib.io.csv.touch import write_touch

        outputs.stage_from_file(out, lambda p: write_touch(p, plan.data, robot, comment=comment))
    else:
        from calib.io.csv.specs import write_poses

        sees = None
        if len(cell.targets) > 1:       # (each pose measures the targets it sees)
            sees = {"sees": [" ".join(t.name for t, v in zip(cell.targets, row) if v) for row in plan.visible]}
        outputs.stage_from_file(out, lambda p: write_poses(p, robot, plan.q, names=plan.names, comment=comment,
                                                           extra=sees))
    for vendor, paths in programs:
        options = {"j23_factor": args.j23_factor} if vendor == "fanuc" else {}
        texts = joint_program_texts(vendor, paths[0], robot, plan.path, names=list(plan.path_names), options=options)
        for path, text in texts.items():
            outputs.stage(Path(path), text)
    if picture is not None:
        from calib.design.plan_picture import plan_png

        title = (f"{Path(args.robot).name}: {len(plan.q)} {'touches' if touch else 'poses'}, "
                 f"travel {plan.travel:.0f} s" + (f", cell {Path(args.cell).name}" if args.cell else ""))
        outputs.stage(picture, plan_png(robot, model, cell, plan.path, plan.measured, title))


def _comment(args, robot, cell, plan, touch: bool) -> str:
    lines = [f"Plan made by: {command_line(args)}",
             f"Robot {args.robot}: base frame {robot.base_frame}, tool frame {robot.tool_frame}; rows in visiting "
             f"order (the program moves through waypoints between some)"]
    if touch:
        lines.append(f"Touch each feature at its rows; the tool point is the probe's tip at "
                     f"({', '.join(f'{v * 1e3:g}' for v in cell.tip)}) mm in {robot.tool_frame}; record the joints "
                     f"at contact; calibrate with calib calibrate {args.robot} {Path(args.output).name} --params "
                     f"{plan.params}")
        lines.append(f"Predicted error {plan.predicted * 1e3:.4f} mm: {plan.what}")
    else:
        if cell.instrument is not None:
            lines.append(f"Measure at each row the targets {', '.join(t.name for t in cell.targets)} at offsets "
                         + "; ".join(f"{t.name} ({', '.join(f'{v * 1e3:g}' for v in t.offset)}) mm"
                                     for t in cell.targets) + f" in {robot.tool_frame}")
        frames = "".join(f" --{k.replace('_', '-')} {v}" for k, v in (("base_frame", args.base_frame),
                                                                      ("tool_frame", args.tool_frame)) if v)
        if len(cell.targets) > 1:
            lines.append("Each row measures the targets its sees column names (the others are out of sight there); give the instrument's rows the point "
                         "and a target column (or names such as P01_A and --target-from "
                         "'(?P<key>P\\d+)_(?P<target>\\w+)')")
        lines.append(f"Name the instrument's points as the point column, then: calib calibrate {args.robot} "
                     f"{Path(args.output).name} --tracker TRACKER.csv --key point{frames}")
        a = plan.accuracy
        lines.append(f"Predicted error over the cell {a['plan']['cell'][0] * 1e3:.4f} mm (unconstrained selection "
                     f"{a['unconstrained']['cell'][0] * 1e3:.4f} mm); travel {plan.travel:.1f} s")
    return "\n".join(lines)
