"""The options that read a ROS bag in place of a measurement CSV (``--bag FILE --joints TOPIC --pose
TOPIC``, :func:`add_bag`) and the reading itself (:func:`read_bag_args`; :mod:`calib.io.bag`)."""
from __future__ import annotations

import argparse
import logging

from calib.cli.args import nonnegative, positive

__all__ = ["add_bag", "bag_options", "read_bag_args", "check_measurement_input"]

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
