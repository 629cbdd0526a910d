"""The messages of a ROS bag that a calibration uses, streamed into arrays (:func:`read_streams`):
the joint states of the robot and the instrument's pose, each with its header stamp.

Read with rosbags (``rosbags.highlevel.AnyReader``: ROS 1 ``.bag`` files; ROS 2 bags, a folder
with ``metadata.yaml`` or one ``.db3`` / ``.mcap`` file), pure Python, the message definitions
taken from the bag itself. Only the connections of the topics asked for are read, one message at
a time: memory grows with the numbers kept (8 bytes per joint value), not with the bag.

Messages (the ROS definitions, the same in ROS 1 and ROS 2):

* joints: ``sensor_msgs/msg/JointState`` (``header.stamp``, ``name[]``, ``position[]``: rad for
  revolute joints, m for prismatic). A message naming none of the chain's joints (a gripper's
  own joint states on the same topic) is skipped; one naming some but not all of them, or a
  joint the URDF does not have, is an error.
* the instrument: ``geometry_msgs/msg/PoseStamped`` (``pose.position``, ``pose.orientation``),
  ``PoseWithCovarianceStamped`` (``pose.pose``) or ``TransformStamped`` (``transform``), or from
  ``tf2_msgs/msg/TFMessage`` (``/tf``) the transforms with ``header.frame_id`` = PARENT and
  ``child_frame_id`` = CHILD (or the reverse, inverted): the pose of the measured frame in the
  instrument's, ``T_meas_tool``, in metres, quaternion (x, y, z, w) as ROS writes it.

Every error is a :class:`calib.MeasurementFormatError` naming the bag, then the topic and the
message (1-based, in the topic's order) where one applies.
"""
from __future__ import annotations

from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.bag.layout import Layouts
from calib.io.urdf.packages import ros_extra

__all__ = ["JOINT_STATE", "POSE_TYPES", "TF_MESSAGE", "JointSamples", "PoseSamples", "read_streams", "open_bag",
           "stamp_text"]

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped",
              "geometry_msgs/msg/TransformStamped")
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: A quaternion whose norm is farther than this from 1 is refused (a ROS quaternion is a unit one).
QUATERNION_NORM_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class JointSamples:
    """The joint states of the chain: ``t_ns`` (N,) int64 header stamps (ns), ``q`` (N, n)
    rad / m in chain order, ``index`` (N,) the 1-based message number in the topic."""

    t_ns: np.ndarray
    q: np.ndarray
    index: np.ndarray


@dataclass(frozen=True, eq=False)
class PoseSamples:
    """The instrument's poses: ``t_ns`` (M,) int64, ``position`` (M, 3) m and ``quaternion``
    (M, 4) unit (x, y, z, w) of ``T_meas_tool``; ``index`` (M,) the 1-based message number in
    the topic; ``frame``: the instrument's frame (the header's ``frame_id``)."""

    t_ns: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray
    index: np.ndarray
    frame: str


def open_bag(path: Path):
    """An opened ``rosbags.highlevel.AnyReader`` of ``path`` (the caller closes it);
    MeasurementFormatError for a file or folder that is not a readable bag."""
    highlevel = ros_extra("rosbags.highlevel", f"{path}: reading a ROS bag")
    if not path.exists():
        raise MeasurementFormatError(path, "file not found")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise MeasurementFormatError(path, "is a folder without metadata.yaml: expected a ROS 1 .bag file, a ROS 2 "
                                           "bag folder, or a ROS 2 .db3 / .mcap file")
    if path.is_file() and path.suffix.lower() not in (".bag", ".db3", ".mcap"):
        raise MeasurementFormatError(path, f"unknown bag suffix {path.suffix!r}: expected a ROS 1 .bag file, a ROS 2 "
                                           f"bag folder, or a ROS 2 .db3 / .mcap file")
    try:
        reader = highlevel.AnyReader([path])
        reader.open()
    except Exception as exc:        # rosbags raises its own errors, and sqlite's, struct's, ... on a damaged file
        raise MeasurementFormatError(path, f"not a readable ROS bag: {_said(exc)}") from None
    return reader


def _said(exc: Exception) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _connections(reader, path: Path, topic: str, types: tuple[str, ...], option: str):
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        known = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
        raise MeasurementFormatError(path, f"no topic {topic} (given by {option}); the bag has "
                                           f"{', '.join(known) if known else 'no topics'}")
    bad = sorted({c.msgtype for c in conns} - set(types))
    if bad:
        raise MeasurementFormatError(path, f"topic {topic} ({option}) carries {bad[0]}, expected "
                                           f"{' or '.join(types)}")
    return conns


def stamp_text(t_ns: int) -> str:
    """A stamp in ns as seconds, every digit exact: ``1700000000.050000000``."""
    t_ns = int(t_ns)
    return f"{t_ns // 1_000_000_000}.{t_ns % 1_000_000_000:09d}"


def _stamp(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class _JointMap:
    """Which entries of a JointState message are the chain's joints, per list of names (checked
    once per distinct list)."""

    def __init__(self, path: Path, topic: str, chain: tuple[str, ...], urdf_joints: frozenset):
        self.path, self.topic, self.chain, self.urdf = path, topic, chain, urdf_joints
        self.known: dict[tuple, np.ndarray | None] = {}

    def __call__(self, names: tuple, k: int):
        take = self.known.get(names, False)
        if take is not False:
            return take
        where = f"topic {self.topic}, message {k}"
        unknown = [n for n in names if n not in self.urdf]
        if unknown:
            raise MeasurementFormatError(self.path, f"{where}: joint {unknown[0]!r} is not a joint of the URDF "
                                                    f"(its joints: {', '.join(sorted(self.urdf))})")
        if len(set(names)) != len(names):
            raise MeasurementFormatError(self.path, f"{where}: a joint named twice in name[]: {', '.join(names)}")
        present = [j for j in self.chain if j in names]
        if not present:
            take = None
        elif len(present) < len(self.chain):
            missing = [j for j in self.chain if j not in names]
            raise MeasurementFormatError(self.path, f"{where}: names {', '.join(present)} of the chain but not "
                                                    f"{', '.join(missing)}: expected every joint of the chain in one "
                                                    f"message")
        else:
            take = np.array([names.index(j) for j in self.chain])
        self.known[names] = take
        return take


def _pose_of(msg, msgtype: str):
    if msgtype.endswith("TransformStamped"):
        tr, rot = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if msgtype.endswith("WithCovarianceStamped") else msg.pose
        tr, rot = pose.position, pose.orientation
    return (tr.x, tr.y, tr.z), (rot.x, rot.y, rot.z, rot.w)


def _inverse(position, quaternion):
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(quaternion).inv()
    return tuple(-r.apply(position)), tuple(r.as_quat())


def _check_samples(path: Path, topic: str, t: np.ndarray, index: np.ndarray, values: np.ndarray):
    """Stamps present and in order; the same stamp twice only with the same values (then kept
    once). Returns the mask of the samples kept."""
    zero = np.flatnonzero(t <= 0)
    if len(zero):
        raise MeasurementFormatError(path, f"topic {topic}, message {index[zero[0]]}: header stamp "
                                           f"{stamp_text(t[zero[0]]).rstrip('0').rstrip('.')} s: expected the time of the reading (the publisher "
                                           f"does not stamp its messages)")
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise MeasurementFormatError(path, f"topic {topic}, message {index[k]}: a value is NaN or infinite")
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        k = int(back[0])
        raise MeasurementFormatError(path, f"topic {topic}, message {index[k + 1]}: header stamp {stamp_text(t[k + 1])} s "
                                           f"is earlier than message {index[k]}'s ({stamp_text(t[k])} s): stamps out of "
                                           f"order{f' ({len(back)} times)' if len(back) > 1 else ''}")
    keep = np.ones(len(t), bool)
    for k in np.flatnonzero(dt == 0):
        if np.array_equal(values[k], values[k + 1]):
            keep[k + 1] = False
        else:
            raise MeasurementFormatError(path, f"topic {topic}, messages {index[k]} and {index[k + 1]} have the same "
                                               f"header stamp {stamp_text(t[k])} s and different values: expected one "
                                               f"reading per stamp")
    return keep


class _Stream:
    """One topic's samples as read: stamps (ns), message numbers and rows of ``width`` float64,
    kept compactly (16 bytes and 8 per number a sample, no object per sample)."""

    def __init__(self, width: int):
        self.t, self.k, self.values, self.width = array("q"), array("q"), bytearray(), width

    def add(self, t: int, k: int, values) -> None:
        self.t.append(t)
        self.k.append(k)
        self.values += values

    def __len__(self) -> int:
        return len(self.t)

    def arrays(self):
        values = np.frombuffer(self.values, "<f8").reshape(-1, self.width).copy()
        self.values = bytearray()
        return np.array(self.t, np.int64), values, np.array(self.k, np.int64)


class _Topics:
    """The joint and instrument messages of a bag, each decoded in place when its layout is known
    (:class:`calib.io.bag.layout.Layouts`), else by rosbags."""

    def __init__(self, path: Path, reader, *, joints: str, chain, urdf_joints, ptopic: str, want):
        self.path, self.reader, self.joints, self.ptopic, self.want = path, reader, joints, ptopic, want
        self.jmap = _JointMap(path, joints, chain, frozenset(urdf_joints))
        self.all = np.arange(len(chain))
        self.joint, self.pose = _Stream(len(chain)), _Stream(7)
        self.jlay, self.play = Layouts(reader.is2), Layouts(reader.is2)
        self.frame, self.seen = None, set()

    def on_joint(self, raw, k: int) -> None:
        hit = self.jlay.read(raw)
        if hit is None:
            msg = self.reader.deserialize(raw, JOINT_STATE)
            names = tuple(msg.name)
            take = self.jmap(names, k)
            if len(msg.position) != len(names) and take is not None:
                raise MeasurementFormatError(self.path, f"topic {self.joints}, message {k}: {len(msg.position)} "
                                                        f"positions for {len(names)} names")
            t, position = _stamp(msg.header), np.asarray(msg.position, "<f8")
            self.jlay.learn(raw, t, position, take)
            hit = (t, position.tobytes(), take)
        t, values, take = hit
        if take is not None:
            self.joint.add(t, k, values if np.array_equal(take, self.all) and len(values) == 8 * len(take)
                           else np.frombuffer(values, "<f8")[take].tobytes())

    def on_pose(self, raw, k: int, msgtype: str) -> None:
        hit = self.play.read(raw) if msgtype != TF_MESSAGE else None
        if hit is not None:
            self.pose.add(hit[0], k, hit[1])
            return
        msg = self.reader.deserialize(raw, msgtype)
        for t, position, quaternion, frame in _instrument(msg, msgtype, self.want, self.seen):
            if self.frame is None:
                self.frame = frame
            elif frame != self.frame:
                raise MeasurementFormatError(self.path, f"topic {self.ptopic}, message {k}: frame_id {frame!r}, while "
                                                        f"earlier messages are in {self.frame!r}: expected one "
                                                        f"instrument frame")
            values = np.array(position + quaternion, "<f8")
            if msgtype != TF_MESSAGE:
                self.play.learn(raw, t, values)
            self.pose.add(t, k, values.tobytes())


def _messages(reader, connections):
    """(connection, raw) of ``connections`` in the bag's order: straight from the one storage
    reader when there is one (AnyReader's merge of several readers costs a heap step a message)."""
    if len(reader.readers) == 1:
        for conn, _, raw in reader.readers[0].messages(connections=connections):
            yield conn, raw
    else:
        for conn, _, raw in reader.messages(connections=connections):
            yield conn, raw


def read_streams(path: Path, reader, *, joints: str, chain: tuple[str, ...], urdf_joints, pose: str | None = None,
                 tf: tuple[str, str] | None = None) -> tuple[JointSamples, PoseSamples]:
    """Stream the joint states of ``joints`` (the ``chain``'s joints in chain order; every name
    must be one of ``urdf_joints``) and the instrument's poses (topic ``pose``, or the ``/tf``
    transform ``tf`` = (parent, child)) out of the open bag ``reader`` (:func:`open_bag`), with
    the checks of the module docstring."""
    jconns = _connections(reader, path, joints, (JOINT_STATE,), "--joints")
    ptopic, ptypes = (pose, POSE_TYPES) if pose is not None else ("/tf", (TF_MESSAGE,))
    pconns = _connections(reader, path, ptopic, ptypes, "--pose" if pose is not None else "--tf")
    topics = _Topics(path, reader, joints=joints, chain=chain, urdf_joints=urdf_joints, ptopic=ptopic,
                     want=tf and (tf[0].lstrip("/"), tf[1].lstrip("/")))
    counts = {joints: 0, ptopic: 0}
    try:
        for conn, raw in _messages(reader, jconns + pconns):
            counts[conn.topic] += 1
            if conn.topic == joints:
                topics.on_joint(raw, counts[joints])
            else:
                topics.on_pose(raw, counts[ptopic], conn.msgtype)
    except MeasurementFormatError:
        raise
    except Exception as exc:           # a damaged bag fails while it is read, in any of its libraries
        raise MeasurementFormatError(path, f"not a readable ROS bag: {_said(exc)} (after "
                                           f"{sum(counts.values())} messages of {joints} and {ptopic})") from None
    if not len(topics.joint):
        raise MeasurementFormatError(path, f"topic {joints}: no message names the chain's joints "
                                           f"({', '.join(chain)}) among {counts[joints]} messages")
    if not len(topics.pose):
        what = (f"no transform {tf[0]} -> {tf[1]} (nor the reverse) among its {counts[ptopic]} messages; it has "
                f"{', '.join(sorted(f'{a} -> {b}' for a, b in topics.seen)[:20]) or 'none'}" if tf else "no message")
        raise MeasurementFormatError(path, f"topic {ptopic}: {what}")
    t, q, idx = topics.joint.arrays()
    keep = _check_samples(path, joints, t, idx, q)
    joint = JointSamples(t_ns=t[keep], q=q[keep], index=idx[keep])
    t, pq, idx = topics.pose.arrays()
    keep = _check_samples(path, ptopic, t, idx, pq)
    p, q = pq[:, :3], pq[:, 3:]
    norm = np.linalg.norm(q, axis=1)
    off = np.flatnonzero(np.abs(norm - 1) > QUATERNION_NORM_TOL)
    if len(off):
        raise MeasurementFormatError(path, f"topic {ptopic}, message {idx[off[0]]}: orientation quaternion of norm "
                                           f"{norm[off[0]]:.6g}: expected a unit quaternion")
    return joint, PoseSamples(t_ns=t[keep], position=p[keep], quaternion=(q / norm[:, None])[keep],
                              index=idx[keep], frame=topics.frame or "")


def _instrument(msg, msgtype: str, want, seen: set) -> list:
    """The poses one instrument message gives: [(stamp ns, position, quaternion xyzw, frame)]."""
    if msgtype != TF_MESSAGE:
        position, quaternion = _pose_of(msg, msgtype)
        return [(_stamp(msg.header), tuple(position), tuple(quaternion), msg.header.frame_id.lstrip("/"))]
    out = []
    for tr in msg.transforms:
        pair = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
        if pair == want or pair[::-1] == want:
            position, quaternion = _pose_of(tr, "TransformStamped")
            if pair != want:
                position, quaternion = _inverse(position, quaternion)
            out.append((_stamp(tr.header), tuple(position), tuple(quaternion), want[0]))
        elif len(seen) < 1000:
            seen.add(pair)
    return out
