"""The inputs the ``calib`` subcommands share that are not CSV files:

* the robot argument: a URDF, a robot name of example-robot-data, a UR kinematics YAML with
  ``--ur-type``, or a xacro with ``--xacro-arg`` and ``--package`` (:func:`robot_description`:
  what :func:`calib.load_robot` reads), and its loading with the frames of --base-frame /
  --tool-frame (:func:`load`);
* a ROS bag in place of a measurement CSV (``--bag FILE --joints TOPIC --pose TOPIC``,
  :func:`add_bag`) and its reading (:func:`read_bag_args`; :mod:`calib.io.bag`)."""
from __future__ import annotations

import argparse
import logging

from calib.cli.args import nonnegative, positive, print_notes

__all__ = ["add_robot", "add_ur_type", "add_xacro", "robot_description", "urdf_only", "load", "add_bag", "bag_options",
           "read_bag_args", "check_measurement_input"]


def add_robot(p: argparse.ArgumentParser) -> None:
    """The ROBOT.urdf positional argument (a URDF, a robot name, or a UR kinematics YAML with
    --ur-type: :func:`add_ur_type`)."""
    p.add_argument("robot", metavar="ROBOT.urdf",
                   help="URDF of the robot (the nominal model), or a robot name example-robot-data "
                        "knows (ur5, panda, ...), or a xacro (ROBOT.urdf.xacro, with --xacro-arg and --package), "
                        "or a UR kinematics YAML (ROBOT.yaml, with --ur-type); "
                        "a calibrated URDF written by calib brings its own base and tool frames")
    add_ur_type(p)


# ---------------------------------------------------------------------- UR kinematics YAML
#: The attributes of the subcommands' namespaces that name a robot description.
_ROBOT_ARGUMENTS = ("robot", "calibrated", "nominal")


def add_ur_type(p: argparse.ArgumentParser) -> None:
    """--ur-type: a robot argument given as a UR kinematics YAML is read as the URDF
    ur_description builds from it for that type (:func:`robot_description`)."""
    from calib.choices import UR_TYPES

    p.add_argument("--ur-type", choices=UR_TYPES, default=None, metavar="TYPE",
                   help="the robot is given as a UR kinematics YAML (ROBOT.yaml: ur_description's "
                        "config/TYPE/default_kinematics.yaml, or the robot's own factory calibration "
                        "that ur_calibration extracts from its controller): its type, for the joint "
                        f"limits ({', '.join(UR_TYPES)}); the model is the URDF ur_description's xacro "
                        "builds from it (base frame base_link, tool frame tool0)")
    add_xacro(p)


def add_xacro(p: argparse.ArgumentParser) -> None:
    """--xacro-arg and --package: a robot argument given as a xacro (ROBOT.urdf.xacro) is
    expanded with them (:func:`robot_description`)."""
    p.add_argument("--xacro-arg", dest="xacro_args", action="append", default=None, metavar="NAME:=VALUE",
                   help="an argument of a robot given as a xacro (ROBOT.urdf.xacro), as xacro takes it, e.g. "
                        "ur_type:=ur5e; repeat for each")
    p.add_argument("--package", dest="packages", action="append", default=None, metavar="NAME=DIR",
                   help="the folder of a ROS package a xacro names ($(find NAME), package://NAME/...); repeat "
                        "for each; ROS_PACKAGE_PATH, AMENT_PREFIX_PATH and the xacro's own package are looked "
                        "in too (no ROS installation needed: docs/ros.md)")


def _is_ur_kinematics(value) -> bool:
    from pathlib import Path

    return isinstance(value, str) and Path(value).suffix.lower() in (".yaml", ".yml")


def _is_xacro(value) -> bool:
    from pathlib import Path

    return isinstance(value, str) and Path(value).suffix.lower() == ".xacro"


def robot_description(args: argparse.Namespace, value):
    """The robot argument ``value`` as the readers take it: unchanged (a URDF path or a robot
    name), for a xacro (``.xacro``) the URDF it expands to with --xacro-arg and --package
    (:func:`calib.io.urdf.xacro_file.expand_xacro`; its notes on stderr), or for a UR kinematics YAML (``.yaml`` / ``.yml``) the URDF ur_description builds from
    it for ``--ur-type`` (:func:`calib.io.urdf.ur_description.ur_description`). ParameterError for a
    YAML without --ur-type, for --ur-type when no robot argument of the command is a YAML, and for
    --xacro-arg / --package when none is a xacro."""
    from calib.errors import ParameterError

    ur_type = getattr(args, "ur_type", None)
    given = [v for v in (getattr(args, a, None) for a in _ROBOT_ARGUMENTS) if v is not None]
    if ur_type is not None and not any(_is_ur_kinematics(v) for v in given):
        raise ParameterError(f"--ur-type {ur_type} names the type of a UR kinematics YAML (ROBOT.yaml), and "
                             f"{' and '.join(map(str, given)) or 'no robot argument'} "
                             f"{'is' if len(given) < 2 else 'are'} not one: give the YAML, or leave --ur-type "
                             f"out for a URDF")
    xacro_given = [f for f, v in (("--xacro-arg", getattr(args, "xacro_args", None)),
                                  ("--package", getattr(args, "packages", None))) if v]
    if xacro_given and not any(_is_xacro(v) for v in given):
        raise ParameterError(f"{' and '.join(xacro_given)} expand a robot given as a xacro (ROBOT.urdf.xacro), and "
                             f"{' and '.join(map(str, given)) or 'no robot argument'} "
                             f"{'is' if len(given) < 2 else 'are'} not one")
    if _is_xacro(value):
        from calib.io.urdf.packages import RosPackages
        from calib.io.urdf.xacro_file import expand_xacro

        description = expand_xacro(value, getattr(args, "xacro_args", None) or (),
                                   RosPackages.from_options(getattr(args, "packages", None) or ()))
        print_notes(description.notes)
        return description
    if not _is_ur_kinematics(value):
        return value
    if ur_type is None:
        from calib.choices import UR_TYPES

        raise ParameterError(f"{value}: a UR kinematics YAML needs the robot's type: --ur-type "
                             f"{{{','.join(UR_TYPES)}}}")
    from calib.io.urdf.ur_description import ur_description

    return ur_description(value, ur_type)


def urdf_only(value, what: str) -> None:
    """Refuse a UR kinematics YAML where a command needs a URDF (``what``: the argument and why)."""
    if _is_ur_kinematics(value):
        from calib.errors import ParameterError

        raise ParameterError(f"{value}: {what}, not a UR kinematics YAML")


def load(args: argparse.Namespace, description=None):
    """The robot of ``args.robot`` (a URDF, a robot name, a xacro, or a UR kinematics YAML with
    --ur-type) with the frames of --base-frame / --tool-frame (logged); ``description``: what
    :func:`robot_description` already made of it (not made again)."""
    from calib.io.urdf.reader import load_robot

    log = logging.getLogger("calib.cli")
    if description is None:
        description = robot_description(args, args.robot)
    robot = load_robot(description, base_frame=args.base_frame, tool_frame=args.tool_frame)
    log.info("robot %s: %d joints (%s), base frame %r, tool frame %r, %d parameters",
             args.robot, robot.n_joints, ", ".join(robot.joint_names), robot.base_frame,
             robot.tool_frame, robot.n_params)
    log.debug("nominal model:\n%s", robot.describe())
    return robot


#: The CSV file-format options, which a bag has no use for.
_CSV_ONLY = (("rename", "--rename"), ("euler", "--euler"), ("convention", "--convention"),
             ("header_line", "--header-line"), ("tracker", "--tracker"), ("key", "--key"),
             ("target_column", "--target-column"), ("target_from", "--target-from"), ("time", "--time"),
             ("time_unit", "--time-unit"))


def add_bag(p: argparse.ArgumentParser) -> None:
    """--bag and the options that read it, in their own help group (--max-gap and
    --limit-tolerance are the file-format group's, shared)."""
    from calib.choices import BAG_SAMPLINGS as SAMPLINGS

    g = p.add_argument_group("ROS bag (in place of MEAS.csv; docs/ros.md)")
    g.add_argument("--bag", metavar="FILE", default=None,
                   help="read the measurements from a ROS bag: a ROS 1 .bag file, or a ROS 2 bag (its folder, or "
                        "its .db3 or .mcap file); one row per pose the robot held still (--still, --min-still)")
    g.add_argument("--joints", metavar="TOPIC", default="/joint_states",
                   help="the sensor_msgs/JointState topic of the robot's joints")
    g.add_argument("--pose", metavar="TOPIC", default=None,
                   help="the instrument's pose of the measured frame: a geometry_msgs/PoseStamped (or "
                        "PoseWithCovarianceStamped, TransformStamped) topic")
    g.add_argument("--tf", metavar="PARENT:CHILD", default=None,
                   help="the instrument's pose as the /tf transform of CHILD (the measured frame) in PARENT "
                        "(the instrument's frame), in place of --pose")
    g.add_argument("--still", metavar="VEL", type=positive, default=0.1,
                   help="the robot is still while every joint turns at most VEL deg/s (prismatic joints: "
                        "VEL mm/s), its speed taken over 50 ms; instrument samples taken while it moves are "
                        "not used")
    g.add_argument("--min-still", metavar="S", type=nonnegative, default=0.5,
                   help="seconds a pose must be held still to be measured; one row per such pose, the mean "
                        "of the instrument's samples in it")
    g.add_argument("--joint-sampling", choices=SAMPLINGS, default="linear",
                   help="the joints at an instrument stamp: linear, interpolated between the joint samples "
                        "before and after it; nearest, the nearest one; within --max-gap (default 0.1 s for "
                        "a bag)")


def check_measurement_input(args: argparse.Namespace) -> None:
    """Exactly one of MEAS.csv and --bag; with --bag, --pose or --tf and no CSV-only option; without
    it, none of the bag's options. :class:`calib.ParameterError` naming the options."""
    from calib.errors import ParameterError

    bag, csv = getattr(args, "bag", None), getattr(args, "measurements", None)
    if bag is None and csv is None:
        raise ParameterError("give the measurements: MEAS.csv, or a ROS bag with --bag FILE --pose TOPIC")
    if bag is not None and csv is not None:
        raise ParameterError(f"give the measurements once: {csv} or --bag {bag}, not both")
    if bag is None:
        given = [flag for name, flag in (("pose", "--pose"), ("tf", "--tf")) if getattr(args, name, None)]
        if given:
            raise ParameterError(f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} for a ROS bag: give it "
                                 f"with --bag FILE")
        return
    if (args.pose is None) == (args.tf is None):
        raise ParameterError(f"--bag {bag}: give the instrument's pose as a topic (--pose TOPIC) or as a /tf transform "
                             f"(--tf PARENT:CHILD), one of the two")
    given = [flag for name, flag in _CSV_ONLY if getattr(args, name, None) is not None]
    if getattr(args, "join", "key") != "key":
        given.append("--join")
    if given:
        raise ParameterError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for CSV files, not a ROS bag "
                             f"(--bag {bag})")


def bag_options(args: argparse.Namespace):
    """The :class:`calib.io.bag.reader.BagOptions` of the parsed options (deg/s and mm/s of
    --still converted to rad/s and m/s)."""
    import math

    from calib.io.bag.reader import BagOptions

    gap = getattr(args, "max_gap", None)
    return BagOptions(joints=args.joints, pose=args.pose, tf=args.tf, sampling=args.joint_sampling,
                      max_gap_s=0.1 if gap is None else gap, still_rad_s=math.radians(args.still),
                      still_m_s=args.still * 1e-3, min_still_s=args.min_still,
                      limit_tolerance=args.limit_tolerance)


def read_bag_args(args: argparse.Namespace, robot):
    """The measurements of ``--bag`` for ``robot`` (its notes on stderr)."""
    from calib.cli.args import print_notes, progress_enabled
    from calib.cli.progress import working
    from calib.io.bag.reader import read_bag

    log = logging.getLogger("calib.cli")
    options = bag_options(args)
    with working(f"reading {args.bag}", logger=log, enabled=progress_enabled(args)):
        m = read_bag(args.bag, robot, options)
    log.info("read %r", m)
    print_notes(m.notes)
    return m


def bag_file(path):
    """The file of ``--bag`` whose sha256 a report records: the bag itself, or for a ROS 2 bag
    folder its one storage file (.db3, .mcap), else its metadata.yaml."""
    from pathlib import Path

    path = Path(path)
    if not path.is_dir():
        return path
    data = sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
    return data[0] if len(data) == 1 else path / "metadata.yaml"
