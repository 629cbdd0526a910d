"""A calibration campaign recorded as a ROS bag, read into the :class:`calib.Measurements` the CSV
readers produce (:func:`read_bag`), so that :func:`calib.calibrate` takes it unchanged.

The bag holds the robot's joint states (``sensor_msgs/msg/JointState``) and the instrument's
pose of the measured frame (a ``PoseStamped`` topic, or a ``/tf`` transform), each stamped
(:mod:`calib.io.bag.stream`). A row is made for each pose the robot held still long enough: the
mean of the instrument's samples in that still period with the joints at their stamps
(:mod:`calib.io.bag.rows`). The joint readings are checked against the URDF's limits as the CSV
readers check them (``limit_tolerance``).

Rows are numbered by the instrument topic's message number of each row's first sample
(``Measurements.rows``: an outlier is named as "row 1234", message 1234 of the pose topic);
``columns["time_s"]`` holds each row's mean stamp (seconds, the bag's clock) and, for stamps that
are dates (after 2000), ``columns["unix_time_s"]`` the same as the time the robot was measured.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.checks import check_path
from calib.choices import BAG_SAMPLINGS
from calib.errors import MeasurementFormatError, ParameterError
from calib.model.measurements import Measurements

__all__ = ["BagOptions", "read_bag", "SAMPLINGS", "FORMAT_HELP"]

#: How the joints are taken at an instrument stamp (:func:`calib.io.bag.rows.joints_at`).
SAMPLINGS = BAG_SAMPLINGS
#: What ``calib formats`` says of bags.
FORMAT_HELP = """\
ROS bags (calibrate --bag FILE, in place of MEAS.csv; no ROS installation: pip install 'calib[ros]'):
Files: a ROS 1 .bag file; a ROS 2 bag, its folder (metadata.yaml) or its one .db3 (sqlite3) or
  .mcap file. Read with rosbags, the message definitions taken from the bag; only the two topics'
  messages are read, one at a time.
Joints: --joints TOPIC (default /joint_states), sensor_msgs/JointState: name[], position[] in rad
  (m for prismatic joints), header.stamp. Every name must be a joint of the URDF; a message naming
  none of the chain's joints (a gripper's) is skipped, one naming only some of them is an error.
Instrument: --pose TOPIC, geometry_msgs/PoseStamped (or PoseWithCovarianceStamped,
  TransformStamped): the measured frame's pose in the instrument's frame (header.frame_id, one
  frame for the whole bag), metres, quaternion; or --tf PARENT:CHILD, the /tf transform of CHILD
  (the measured frame) in PARENT (the instrument's frame; recorded the other way round it is
  inverted).
Stamps: header stamps, in order on each topic (the same stamp twice only with the same values).
Rows: one per pose the robot held still: every joint turning at most --still VEL deg/s (mm/s
  for prismatic joints; default 0.1) over 50 ms, for at least --min-still S seconds (default
  0.5). A row is the mean of the instrument's samples in that still period (rotations by their
  chordal mean) with the joints at their stamps, --joint-sampling linear (between the joint
  samples before and after, both within --max-gap S, default 0.1 s) or nearest (within
  --max-gap); samples taken while the robot moved are not used (a note counts them). Rows are
  numbered by the pose topic's message number of their first sample. Joint readings beyond a
  limit by more than --limit-tolerance are errors, as in CSV files.
"""
#: Stamps at or after this (seconds since 1970, 2000-01-01) are dates; before, a simulated clock.
_DATES_FROM_S = 946684800.0


def _topic(value, name: str) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip() or any(c.isspace() for c in value.strip()):
        raise ParameterError(f"{name} must be a topic name (/joint_states), got {value!r:.60}")
    value = value.strip()
    return value if value.startswith("/") else "/" + value


def _number(value, name: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value < 0 or (positive and value == 0):
        raise ParameterError(f"{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r:.60}")
    return float(value)


@dataclass(frozen=True)
class BagOptions:
    """How a bag is read (:func:`read_bag`); checked when made.

    joints : the JointState topic (default ``/joint_states``).
    pose : the instrument's pose topic (PoseStamped, PoseWithCovarianceStamped or
        TransformStamped), or None with ``tf``.
    tf : ``"PARENT:CHILD"``: the instrument's pose is the ``/tf`` transform of CHILD (the measured
        frame) in PARENT (the instrument's frame); exactly one of ``pose`` and ``tf``.
    max_gap_s : seconds: the largest time between an instrument stamp and the joint samples it
        is given (default 0.1).
    sampling : ``"linear"`` (default) or ``"nearest"`` (:mod:`calib.io.bag.rows`).
    still_rad_s : rad/s: the largest joint speed of a still robot (revolute joints; default
        0.1 deg/s); still_m_s : m/s, for prismatic joints (default 0.1 mm/s).
    min_still_s : seconds a pose must be held to be measured (default 0.5).
    limit_tolerance : the fraction of a joint's range a reading may pass its limit by (as the
        CSV readers: 0.01).
    """

    joints: str = "/joint_states"
    pose: str | None = None
    tf: str | None = None
    max_gap_s: float = 0.1
    sampling: str = "linear"
    still_rad_s: float = math.radians(0.1)
    still_m_s: float = 1e-4
    min_still_s: float = 0.5
    limit_tolerance: float = 0.01

    def __post_init__(self):
        object.__setattr__(self, "joints", _topic(self.joints, "joints"))
        object.__setattr__(self, "pose", _topic(self.pose, "pose"))
        if (self.pose is None) == (self.tf is None):
            raise ParameterError("give the instrument's pose as a topic (--pose TOPIC) or as a /tf transform "
                                 "(--tf PARENT:CHILD): one of the two")
        if self.tf is not None:
            parent, sep, child = str(self.tf).partition(":") if isinstance(self.tf, str) else ("", "", "")
            if not sep or not parent.strip() or not child.strip() \
                    or parent.strip() == child.strip():
                raise ParameterError(f"tf must be PARENT:CHILD, two frame names (the instrument's frame and the "
                                     f"measured one), got {self.tf!r:.60}")
        for name in ("max_gap_s", "min_still_s"):
            object.__setattr__(self, name, _number(getattr(self, name), name))
        for name in ("still_rad_s", "still_m_s"):
            object.__setattr__(self, name, _number(getattr(self, name), name, positive=True))
        if not isinstance(self.sampling, str) or self.sampling not in SAMPLINGS:
            raise ParameterError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {self.sampling!r:.60}")
        tol = _number(self.limit_tolerance, "limit_tolerance")
        if tol > 1:
            raise ParameterError(f"limit_tolerance must be a fraction in [0, 1], got {tol!r}")
        object.__setattr__(self, "limit_tolerance", tol)

    @property
    def tf_frames(self) -> tuple[str, str] | None:
        """(parent, child) of ``tf``, or None."""
        if self.tf is None:
            return None
        parent, _, child = self.tf.partition(":")
        return parent.strip(), child.strip()


def read_bag(path: str | Path, robot, options: BagOptions) -> Measurements:
    """Read the ROS bag ``path`` (a ROS 1 ``.bag`` file; a ROS 2 bag folder, or its ``.db3`` or
    ``.mcap`` file) into measurements of ``robot`` (see the module docstring).

    Returns Measurements in SI units: ``q`` (R, n) rad / m in chain order, ``position`` (R, 3) m
    and ``rotation`` (R, 3, 3) of the measured frame in the instrument's frame, one row per
    still period with instrument samples; ``notes`` say how many samples were taken while the
    robot moved. Raises :class:`calib.MeasurementFormatError` naming the bag (and the topic and
    message) for anything the module docstrings refuse, and for a bag without a still pose.
    """
    from calib.io.bag.rows import still_rows
    from calib.io.bag.stream import open_bag, read_streams, stamp_text
    from calib.model.robot import check_robot

    path = check_path(path, "path")
    check_robot(robot)
    if not isinstance(options, BagOptions):
        raise ParameterError(f"options must be a BagOptions (calib.BagOptions(pose=...)), got {type(options).__name__}")
    urdf_joints = robot.source.document.joints if robot.source is not None and robot.source.document is not None \
        else robot.joint_names
    reader = open_bag(path)
    try:
        joint, pose = read_streams(path, reader, joints=options.joints, chain=tuple(robot.joint_names),
                                   urdf_joints=urdf_joints, pose=options.pose, tf=options.tf_frames)
    finally:
        reader.close()
    notes = [_check_limits(path, robot, options, joint)] if _beyond(robot, joint.q) else []
    t0 = int(joint.t_ns[0])
    limit = np.where(robot.prismatic, options.still_m_s, options.still_rad_s)
    rows, far = still_rows((joint.t_ns - t0) * 1e-9, joint.q, (pose.t_ns - t0) * 1e-9, pose.position,
                           pose.quaternion, limit=limit, min_still_s=options.min_still_s,
                           max_gap_s=options.max_gap_s, mode=options.sampling)
    ptopic = options.pose or "/tf"
    if far is not None:
        raise MeasurementFormatError(path, f"topic {ptopic}, message {pose.index[far]}: no joint sample of "
                                           f"{options.joints} within --max-gap {options.max_gap_s:g} s "
                                           f"{'on both sides of' if options.sampling == 'linear' else 'of'} its stamp "
                                           f"{stamp_text(pose.t_ns[far])} s")
    if len(rows.q) == 0:
        raise MeasurementFormatError(path, f"no still pose: {rows.periods} still period(s) of at least "
                                           f"{options.min_still_s:g} s in {options.joints} (joint speed at most "
                                           f"--still), none with a sample of {ptopic} ({len(pose.t_ns)} samples)")
    if rows.moving:
        notes.append(f"{path}: {rows.moving} of {len(pose.t_ns)} samples of {ptopic} were taken while the robot moved "
                     f"or stopped for less than {options.min_still_s:g} s: not used; {len(rows.q)} rows, the mean of "
                     f"each still pose's {int(rows.n_samples.min())} to {int(rows.n_samples.max())} samples")
    t_abs = t0 * 1e-9 + rows.t_s
    columns = {"time_s": t_abs}
    if t_abs.min() >= _DATES_FROM_S:
        columns["unix_time_s"] = t_abs
    return Measurements(q=rows.q, position=rows.position, rotation=rows.rotation, rows=pose.index[rows.first],
                        joint_names=robot.joint_names, source=path, prismatic=robot.prismatic, notes=tuple(notes),
                        orientation="quaternion", columns=columns)


def _beyond(robot, q: np.ndarray) -> bool:
    return bool(((q < robot.lower) | (q > robot.upper)).any())


def _check_limits(path: Path, robot, options: BagOptions, joint) -> str:
    """The note for readings past a joint limit within the tolerance; MeasurementFormatError
    naming the message for one further beyond (the CSV readers' rule)."""
    lo, hi = robot.lower, robot.upper
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    excess = np.maximum(lo - joint.q, joint.q - hi)              # > 0 outside
    beyond = excess > options.limit_tolerance * span + 1e-12
    unit = np.where(robot.prismatic, "mm", "deg")
    scale = np.where(robot.prismatic, 1e3, 180 / math.pi)
    if beyond.any():
        k, i = (int(v[0]) for v in np.nonzero(beyond))
        raise MeasurementFormatError(path, f"topic {options.joints}, message {joint.index[k]}: {robot.joint_names[i]} = "
                                           f"{joint.q[k, i] * scale[i]:.6g} {unit[i]} is outside the joint limits "
                                           f"[{lo[i] * scale[i]:.6g}, {hi[i] * scale[i]:.6g}] {unit[i]} by more than the "
                                           f"limit tolerance ({100 * options.limit_tolerance:.3g} % of the range; "
                                           f"--limit-tolerance)")
    i = int(np.flatnonzero((excess > 0).any(axis=0))[0])
    return (f"{path}: {robot.joint_names[i]} is past its joint limit by up to {excess[:, i].max() * scale[i]:.4g} "
            f"{unit[i]} in {int((excess[:, i] > 0).sum())} messages of {options.joints} (within the limit tolerance); "
            f"kept as read")
