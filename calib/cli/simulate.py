"""``calib simulate ROBOT.urdf -o MEAS.csv``: synthetic measurements of a perturbed robot."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from calib.cli.args import (COMMON_EPILOG, HelpFormatter, add_compliance, add_frames, add_targets, add_verbose, compliance_options, count, nonnegative, positive_int, with_targets)
from calib.cli.inputs import add_robot, load
from calib.cli.output import EXIT_OK, Outputs, command_line
from calib.errors import CalibError, ParameterError

__all__ = ["add_parser", "run"]

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
""" + COMMON_EPILOG


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``simulate`` to ``subparsers`` (from ``add_subparsers``); it runs :func:`run`."""
    p = subparsers.add_parser("simulate", help="synthetic measurements of a perturbed robot",
                       description=_SIM_DESC, epilog=_SIM_EPILOG, formatter_class=HelpFormatter)
    add_robot(p)
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
    p.add_argument("--constraint", default=None, metavar="point:N,plane:N,sphere:RADIUS_MM,measured:N",
                   help="write a touch file instead (docs/touch.md): N point ids, N planes (faces of a "
                        "cube, perpendicular in threes), a sphere of each radius; --poses rows per "
                        "feature, reached by the true model within the joint limits, --sigma-pos-mm "
                        "the touch noise per axis; measured:N adds N rows measured by an instrument "
                        "(random configurations, noise --sigma-pos-mm / --sigma-rot-rad, --position-only)")
    p.add_argument("--truth-urdf", metavar="TRUE.urdf", default=None,
                   help="also write the true model as a URDF (a copy of ROBOT.urdf with its joint "
                        "origins changed)")
    p.add_argument("--meas-frame", metavar="X,Y,Z,ROLL,PITCH,YAW", default=None,
                   help="measure in an instrument's frame (a laser tracker's): the pose of the URDF's base "
                        "frame in it, mm and degrees (URDF roll-pitch-yaw), e.g. 2400,-1500,800,-17,11,40; "
                        "default: the base frame itself")
    add_frames(p)
    add_compliance(p, "simulate")
    add_targets(p)
    add_verbose(p)
    p.set_defaults(func=run)
    return p


def _deviations(spec: str, robot, rng) -> tuple[dict[str, float], str]:
    """(deviations in SI units, description) from --deviations."""
    from calib.model.simulate import PAPER_DEVIATIONS, random_deviations

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
    import json

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



def _meas_frame(text):
    """(4, 4) T_meas_base of --meas-frame X,Y,Z,ROLL,PITCH,YAW (mm, deg), or None."""
    if text is None:
        return None
    import numpy as np
    import pinocchio as pin

    try:
        v = [float(t) for t in str(text).split(",")]
    except ValueError:
        v = []
    if len(v) != 6 or not all(math.isfinite(x) for x in v):
        raise ParameterError(f"--meas-frame {text!r}: expected six finite numbers X,Y,Z,ROLL,PITCH,YAW "
                             f"(mm, degrees)")
    T = np.eye(4)
    T[:3, :3] = pin.rpy.rpyToMatrix(*np.radians(v[3:]))
    T[:3, 3] = np.array(v[:3]) * 1e-3
    return T


def run(args: argparse.Namespace) -> int:
    """Run ``calib simulate`` with parsed arguments; returns the exit code."""
    import numpy as np

    from calib.units import DISPLAY_UNITS
    from calib.io.csv.specs import write_measurements
    from calib.model.simulate import apply_deviations, simulate_measurements

    dev_file = None if args.deviations == "paper" or args.deviations.startswith("random:") \
        else args.deviations
    outputs = Outputs([args.robot, dev_file])
    out_csv = outputs.add(args.output)
    out_truth = outputs.add(args.truth_urdf) if args.truth_urdf else None

    robot = with_targets(load(args), args)     # --target: flange->target offsets (before c<i>)
    payload, gravity = compliance_options(args)
    if payload is not None or gravity is not None or dev_file is not None:
        # compliance parameters c<i> (zero unless the deviations name them; calib.model.compliance)
        from calib.model.compliance import with_gravity

        robot = with_gravity(robot, payload=payload, gravity=gravity)
    rng = np.random.default_rng(args.seed)
    deviations, described = _deviations(args.deviations, robot, rng)
    true_robot = apply_deviations(robot, deviations)
    T_meas_base = _meas_frame(args.meas_frame)
    measured = true_robot
    if T_meas_base is not None:     # the instrument's frame (the truth URDF stays the robot's)
        from dataclasses import replace

        measured = replace(true_robot, T_meas_base_ref=T_meas_base @ true_robot.T_meas_base_ref)
    if args.constraint is not None:     # a touch file (issue 24): features and measured rows in that frame
        from calib.cli.touch import simulate_touch_file

        text = simulate_touch_file(args, robot, measured, rng, outputs, out_csv, described, out_truth)
        if out_truth is not None:
            from calib.io.urdf.writer import write_calibrated_urdf

            outputs.stage_from_file(out_truth, lambda p: write_calibrated_urdf(
                true_robot.geometry(), p, nominal=robot.geometry()))
        outputs.commit()
        sys.stdout.write(text + "\n")
        return EXIT_OK
    n_cal, n_val = args.poses, args.val_poses
    Q = robot.random_configurations(n_cal + n_val, rng)
    sets = np.array(["cal"] * n_cal + ["val"] * n_val) if n_val else None
    ids = None
    if robot.targets:       # each configuration measured at every target, in --target order
        k = robot.n_targets
        Q, ids = np.repeat(Q, k, axis=0), list(robot.targets) * (n_cal + n_val)
        sets = None if sets is None else np.repeat(sets, k)
    meas = simulate_measurements(measured, Q, sigma_pos=args.sigma_pos_mm * 1e-3,
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
    if T_meas_base is not None:
        noise_text += f"; measured in a frame where the base frame is at {args.meas_frame} (mm, deg)"
    per_pose = ""
    if robot.targets:
        per_pose = (f", each measured at targets {', '.join(robot.targets)} (one row per target, "
                    f"{meas.n_poses} rows)")
    command = command_line(args)
    comment = (f"Simulated by: {command}\n"
               f"True model: {args.robot} with deviations from {described}; {noise_text}; "
               f"{n_cal} calibration + {n_val} validation poses{per_pose}")
    outputs.stage_from_file(out_csv, lambda p: write_measurements(p, meas, comment=comment))
    if out_truth is not None:
        from calib.io.urdf.writer import write_calibrated_urdf

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
            unit, scale = DISPLAY_UNITS[p.unit]
            lines.append(f"{p.name:<{w}}{unit:>5}{deviations[p.name] * scale:>14.6g}")
    sys.stdout.write("\n".join(lines) + "\n")
    return EXIT_OK

