"""ROS bags written by the tests themselves, in the three formats calib reads (ROS 1 ``.bag``, ROS 2
sqlite3 and MCAP), with rosbags' own writers and typestores (the message definitions of ROS 1
Noetic and ROS 2 Humble as rosbags ships them): a calibration campaign of a robot that moves
between poses and holds each still (:func:`campaign`), its messages (:func:`joint_state`,
:func:`pose_stamped`, :func:`tf_message`) and :func:`write_bag`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

FORMATS = ("ros1", "sqlite3", "mcap")
JS, PS, TF = "sensor_msgs/msg/JointState", "geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage"
#: The campaign's clock starts here (ns since 1970: 2023-11-14).
T0_NS = 1_700_000_000_000_000_000


def typestore(fmt: str):
    """rosbags' typestore of ROS 1 Noetic or ROS 2 Humble (Noetic's lacks tf2_msgs: its one message,
    as tf2_msgs/msg/TFMessage.msg defines it, is added)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    if TF not in ts.types:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    return ts


def bag_path(folder: Path, fmt: str, name: str = "campaign") -> Path:
    """Where :func:`write_bag` writes a bag of ``fmt``: ``name.bag``; a ROS 2 bag folder ``name_db3`` /
    ``name_mcap``."""
    return Path(folder) / (f"{name}.bag" if fmt == "ros1" else f"{name}_{'db3' if fmt == 'sqlite3' else 'mcap'}")


def _header(ts, t_ns: int, frame: str = ""):
    H, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=int(t_ns // 10**9), nanosec=int(t_ns % 10**9))
    return H(seq=0, stamp=stamp, frame_id=frame) if "seq" in H.__dataclass_fields__ else H(stamp=stamp, frame_id=frame)


def joint_state(ts, t_ns: int, names, q):
    return JS, ts.types[JS](header=_header(ts, t_ns), name=list(names), position=np.asarray(q, float),
                            velocity=np.zeros(0), effort=np.zeros(0))


def _pose_parts(ts, T):
    P, Q = ts.types["geometry_msgs/msg/Point"], ts.types["geometry_msgs/msg/Quaternion"]
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return P(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])), Q(x=x, y=y, z=z, w=w)


def pose_stamped(ts, t_ns: int, frame: str, T):
    p, q = _pose_parts(ts, T)
    return PS, ts.types[PS](header=_header(ts, t_ns, frame), pose=ts.types["geometry_msgs/msg/Pose"](position=p, orientation=q))


def tf_message(ts, t_ns: int, parent: str, child: str, T):
    p, q = _pose_parts(ts, T)
    V = ts.types["geometry_msgs/msg/Vector3"]
    tr = ts.types["geometry_msgs/msg/Transform"](translation=V(x=p.x, y=p.y, z=p.z), rotation=q)
    stamped = ts.types["geometry_msgs/msg/TransformStamped"](header=_header(ts, t_ns, parent), child_frame_id=child,
                                                              transform=tr)
    return TF, ts.types[TF](transforms=[stamped])


def campaign(robot, Q, *, T_of=None, hz_joints=100.0, hz_pose=50.0, move_s=1.0, hold_s=2.0, pose_offset_s=0.003):
    """The samples of a campaign: the robot at Q[0] for ``move_s + hold_s``, then for each next pose
    moving ``move_s`` (joints linear in time) and holding ``hold_s``; joint states at
    ``hz_joints``, the instrument's pose ``T_of(q)`` (default: ``robot.T_meas_tool``) at
    ``hz_pose`` from ``pose_offset_s``. Returns (joints [(t_ns, q)], poses [(t_ns, T)])."""
    T_of = T_of or (lambda q: robot.T_meas_tool(q))
    seg = move_s + hold_s

    def q_at(s):
        k = min(int(s // seg), len(Q) - 1)
        u, prev = s - k * seg, Q[max(k - 1, 0)]
        return prev + (Q[k] - prev) * (u / move_s) if u < move_s else Q[k]

    total = len(Q) * seg
    joints = [(T0_NS + round(i / hz_joints * 1e9), q_at(i / hz_joints)) for i in range(int(total * hz_joints))]
    poses = [(T0_NS + round((i / hz_pose + pose_offset_s) * 1e9), T_of(np.asarray(q_at(i / hz_pose + pose_offset_s))))
             for i in range(int(total * hz_pose))]
    return joints, poses


def campaign_messages(ts, robot, joints, poses, *, joint_topic="/joint_states", pose_topic="/tracker/pose",
                      tf=None, frame="tracker"):
    """(topic, msgtype, t_ns, message) of a campaign's samples, in time order; with ``tf`` =
    (parent, child) the poses as /tf transforms instead of ``pose_topic``."""
    out = []
    for t, q in joints:
        msgtype, msg = joint_state(ts, t, robot.joint_names, q)
        out.append((joint_topic, msgtype, t, msg))
    for t, T in poses:
        msgtype, msg = pose_stamped(ts, t, frame, T) if tf is None else tf_message(ts, t, tf[0], tf[1], T)
        out.append((pose_topic if tf is None else "/tf", msgtype, t, msg))
    return sorted(out, key=lambda m: m[2])


def write_bag(path: Path, fmt: str, messages, ts=None) -> Path:
    """Write ``messages`` ((topic, msgtype, t_ns, message), in time order) as a bag of ``fmt``
    (one of :data:`FORMATS`) at ``path``; returns ``path``."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

    ts = ts or typestore(fmt)
    if fmt == "ros1":
        writer, serialize = Writer1(path), ts.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer2(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    with writer:
        conns = {}
        for topic, msgtype, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], t, serialize(msg, msgtype))
    return path
