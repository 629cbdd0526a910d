"""The robot argument the ``calib`` subcommands share: a URDF, a robot name of
example-robot-data, a UR kinematics YAML with ``--ur-type``, or a xacro with ``--xacro-arg`` and
``--package`` (:func:`robot_description`: what :func:`calib.load_robot` reads), and its loading
with the frames of --base-frame / --tool-frame (:func:`load`)."""
from __future__ import annotations

import argparse
import logging

from calib.cli.args import print_notes

__all__ = ["add_robot", "add_ur_type", "add_xacro", "robot_description", "urdf_only", "load"]


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
