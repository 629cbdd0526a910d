"""The ``ur-yaml`` export: a calibrated 6R chain as the ``kinematics`` file of Universal Robots'
``ur_description`` (what ``ur_robot_driver`` reads through ``kinematics_params_file``).

The format (``ur_description/config/<type>/default_kinematics.yaml``)::

    kinematics:
      shoulder:  {x: ..., y: ..., z: ..., roll: ..., pitch: ..., yaw: ...}
      upper_arm: {...}
      forearm:   {...}
      wrist_1:   {...}
      wrist_2:   {...}
      wrist_3:   {...}
      hash: calib_...

How ``ur_description`` uses it: the template rule this module inverts is ``urdf/ur_macro.xacro``
of Universal_Robots_ROS2_Description 2.4.5, quoted with its source in
:mod:`calib.io.urdf.ur_description` (which builds the nominal URDF from such a file). In short:

* ``base_link`` -> ``base_link_inertia``: a fixed joint ``rpy="0 0 pi"``;
* six revolute joints in series, ``shoulder_pan_joint`` (parent ``base_link_inertia``, child
  ``shoulder_link``), ``shoulder_lift_joint``, ``elbow_joint``, ``wrist_1_joint``,
  ``wrist_2_joint``, ``wrist_3_joint`` (child ``wrist_3_link``), each with the origin of its
  entry, shoulder .. wrist_3 in that order, and axis z;
* ``wrist_3_link`` -> ``flange`` (``rpy="0 -pi/2 -pi/2"``) -> ``tool0`` (``rpy="pi/2 0 pi/2"``):
  fixed, together the identity (:data:`T_WRIST3_TOOL0`): ``tool0`` is ``wrist_3_link``. (A
  fork's ``flange-tool0 rpy="${pi/2.0} ${pi} ${pi/2.0}"``, a rotation of pi about z, is not
  ur_description's: exports made with it turned tool0 by pi about the flange axis.)
* ``kinematics.hash`` becomes the ``hash_kinematics`` parameter of the driver, which compares it
  with the robot controller's own calibration checksum and warns when they differ.

The roll, pitch, yaw of an entry are one of the equivalent triples of its rotation: the one
nearest the published files' triple of that entry (:data:`UR_RPY_PUBLISHED`; ``wrist_3`` is
``1.570796326589793 3.141592653589793 3.141592653589793`` in every
``config/<type>/default_kinematics.yaml``), so that the nominal robot's export reproduces the
published numbers and a calibrated robot's reads entry by entry against them.

Mapping rule: by chain order. The six moving joints between the base frame and the tool frame
(the calibrated URDF's recorded frames by default) are shoulder, upper_arm, forearm, wrist_1,
wrist_2, wrist_3, whatever their names. The chain must be UR-like: six revolute (or continuous)
joints, axes 2, 3 and 4 parallel, axis 1 normal to axis 2, axis 5 normal to axes 4 and 6 (to
:data:`UR_ANGLE_TOL`); anything else is refused (:class:`calib.ChainError`).

The template's frames and the URDF's: the template's ``base_link`` is the URDF's base frame; its
``tool0`` is the URDF's flange frame (``tool0`` when the URDF has such a link fixed to the last
link, else the tool frame; ``flange_frame=`` chooses) projected onto axis 6 (origin at the foot
of the perpendicular, z along axis 6, x the flange x projected). Every link of the template has
z on its joint axis, so link frames whose joint turns about another axis of the URDF (the
older ``ur_description`` URDFs of example-robot-data turn about y) are rotated, and the fixed
joints between two moving joints are folded into the next joint's origin; the forward kinematics
of ``tool0`` in ``base_link`` are the URDF's of the flange frame in the base frame, exactly
(checked on the written numbers, :func:`template_tool0`). The tool frame, when it is not the
flange, is given in the file's ``calib`` block as ``tool_in_tool0`` (x, y, z, roll, pitch, yaw,
URDF convention): the TCP to set in the controller. ``ur_description`` reads only the
``kinematics`` block.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib.errors import ChainError, FrameNotFound, ParameterError
from calib.io.urdf.ur_description import UR_FIXED_JOINTS, UR_SEGMENTS
from calib.io.urdf.document import rpy_nearest
from calib.io.urdf.reader import UrdfChain
from calib.model.spatial import inverse

__all__ = ["UR_SEGMENTS", "UR_ANGLE_TOL", "T_BASE_LINK_INERTIA", "T_WRIST3_TOOL0", "UR_RPY_PUBLISHED", "UrKinematics",
           "ur_kinematics", "template_tool0", "default_hash", "check_hash"]

#: Largest deviation (rad) of a UR-like chain's axes from parallel / normal where the UR
#: structure has them so: far above any calibration's correction (milliradians), far below the
#: angles of other arms (a spherical wrist's axis 4 is normal to axis 3: pi/2 from parallel).
UR_ANGLE_TOL = 0.1
#: Largest offset (metres, radians) between the flange frame and its projection onto axis 6
#: below which the flange is taken as on the axis (no note).
FLANGE_TOL = 1e-9


def _rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = pin.rpy.rpyToMatrix(roll, pitch, yaw)
    return T


_FIXED = {name: _rpy(*rpy) for name, _, _, rpy in UR_FIXED_JOINTS}
#: ``base_link`` -> ``base_link_inertia`` of ur_description (rpy 0 0 pi).
T_BASE_LINK_INERTIA = _FIXED["base_link-base_link_inertia"]
#: ``wrist_3_link`` -> ``flange`` -> ``tool0`` of ur_description: ``rpy="0 -pi/2 -pi/2"`` then
#: ``rpy="pi/2 0 pi/2"``, the identity (to rounding, 1e-16).
T_WRIST3_TOOL0 = _FIXED["wrist_3-flange"] @ _FIXED["flange-tool0"]
#: roll, pitch, yaw of each entry shoulder .. wrist_3 in the published
#: ``config/<type>/default_kinematics.yaml`` of ur_description 2.4.5 (ur3 .. ur30 alike; 1.570796327
#: written for pi/2): the triple an export chooses is the nearest to these.
UR_RPY_PUBLISHED = np.array([[0.0, 0.0, 0.0], [math.pi / 2, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                             [math.pi / 2, 0.0, 0.0], [math.pi / 2, math.pi, math.pi]])


@dataclass(frozen=True)
class UrKinematics:
    """The six joint origins of the ur_description template for one URDF chain.

    origins : (6, 6) float: x, y, z (metres), roll, pitch, yaw (radians, URDF convention
        ``R = Rz(yaw) Ry(pitch) Rx(roll)``) of shoulder .. wrist_3, in :data:`UR_SEGMENTS` order.
    joints : the URDF's joint names mapped to them, in that order.
    base_frame, flange_frame, tool_frame : the URDF frames that stand for ``base_link``, for
        ``tool0`` (before its projection onto axis 6) and the tool.
    T_tool0_tool : (4, 4) the tool frame in the template's tool0 (identity when they coincide).
    flange_offset : (translation m, rotation rad) of the flange frame from its projection onto
        axis 6 (0, 0 for a flange on the axis).
    mount : (link, translation m, rotation rad): the robot's own base_link (the parent link of
        the first joint, or in ur_description's layout the link base_link_inertia is fixed to) and
        its distance from the base frame (a pedestal or work-cell offset that the shoulder entry
        then includes).
    """

    origins: np.ndarray
    joints: tuple[str, ...]
    base_frame: str
    flange_frame: str
    tool_frame: str
    T_tool0_tool: np.ndarray
    flange_offset: tuple[float, float]
    mount: tuple[str, float, float] = ("", 0.0, 0.0)


def _rotation_z_to(axis: np.ndarray) -> np.ndarray:
    """(4, 4) the smallest rotation taking z onto the unit vector ``axis`` (pi about x for -z)."""
    z = np.array([0.0, 0.0, 1.0])
    w = np.cross(z, axis)
    s, c = np.linalg.norm(w), float(z @ axis)
    T = np.eye(4)
    if s < 1e-12:
        if c < 0:
            T[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return T
    T[:3, :3] = pin.exp3(w / s * math.atan2(s, c))
    return T


def _line_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad, 0 .. pi/2) between the lines of directions a and b."""
    return math.acos(min(1.0, abs(float(a @ b))))


def check_ur_like(chain: UrdfChain, axes_base: np.ndarray) -> None:
    """Refuse (:class:`calib.ChainError`) a chain the UR template cannot describe: not six
    revolute joints, or axes not in the UR structure (see the module docstring)."""
    names = [j.name for j in chain.joints]
    rule = ("ur-yaml maps the chain's moving joints by order to shoulder, upper_arm, forearm, "
            "wrist_1, wrist_2, wrist_3")
    if len(chain.joints) != 6:
        raise ChainError(chain.path, f"not a UR-like chain: {len(chain.joints)} moving joints between "
                                     f"{chain.base_frame!r} and {chain.tool_frame!r} ({', '.join(names)}); "
                                     f"{rule}: six revolute joints")
    prismatic = [j.name for j in chain.joints if j.is_prismatic]
    if prismatic:
        raise ChainError(chain.path, f"not a UR-like chain: joint {prismatic[0]!r} is prismatic; {rule}: "
                                     f"six revolute joints")
    a = axes_base
    rules = [("parallel", 1, 2), ("parallel", 2, 3), ("normal", 0, 1), ("normal", 3, 4), ("normal", 4, 5)]
    for kind, i, k in rules:
        angle = _line_angle(a[i], a[k])
        off = angle if kind == "parallel" else math.pi / 2 - angle
        if off > UR_ANGLE_TOL:
            raise ChainError(chain.path, f"not a UR-like chain: the axes of joints {i + 1} ({names[i]}) and "
                                         f"{k + 1} ({names[k]}) are {math.degrees(angle):.1f} deg apart, a UR "
                                         f"arm has them {kind} (within {math.degrees(UR_ANGLE_TOL):.1f} deg); "
                                         f"{rule}")


def _flange_frame_id(chain: UrdfChain, flange_frame: str | None) -> int:
    """Pinocchio frame id of the flange frame: ``flange_frame``, else ``tool0`` when it is fixed to
    the last link, else the tool frame."""
    model, last = chain.model, chain.joint_ids[-1]
    bodies = {f.name: k for k, f in enumerate(model.frames) if f.type == pin.FrameType.BODY}
    if flange_frame is None:
        k = bodies.get("tool0")
        return k if k is not None and model.frames[k].parentJoint == last else chain.tool_frame_id
    if flange_frame not in bodies:
        raise FrameNotFound(flange_frame, list(bodies), chain.path)
    k = bodies[flange_frame]
    if model.frames[k].parentJoint != last:
        raise ChainError(chain.path, f"flange frame {flange_frame!r} is not fixed to the link of the last "
                                     f"joint {chain.joints[-1].name!r}: the UR flange moves with wrist_3")
    return k


def ur_kinematics(chain: UrdfChain, flange_frame: str | None = None) -> UrKinematics:
    """The ur_description joint origins that reproduce ``chain``'s forward kinematics (see the
    module docstring). Raises :class:`calib.ChainError` for a chain that is not UR-like,
    :class:`calib.FrameNotFound` for an unknown ``flange_frame``."""
    model = chain.model
    data, oMb = chain.at_zero()
    J, axes_local = [], []
    for jid in chain.joint_ids:
        J.append(oMb.actInv(data.oMi[jid]).homogeneous)          # T_base_joint at q = 0
        w = pin.getJointJacobian(model, data, jid, pin.LOCAL)[3:, model.joints[jid].idx_v]
        axes_local.append(w / np.linalg.norm(w) if np.linalg.norm(w) > 0 else w)
    axes_base = np.array([Jk[:3, :3] @ a for Jk, a in zip(J, axes_local)])
    check_ur_like(chain, axes_base)

    fid = _flange_frame_id(chain, flange_frame)
    P = oMb.actInv(data.oMf[fid]).homogeneous                      # T_base_flange
    z, p6 = axes_base[5], J[5][:3, 3]
    x = P[:3, 0] - (P[:3, 0] @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = P[:3, 1] - (P[:3, 1] @ z) * z
    x /= np.linalg.norm(x)
    Phi = np.eye(4)                                                # T_base_tool0 (template)
    Phi[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    Phi[:3, 3] = p6 + ((P[:3, 3] - p6) @ z) * z
    off = inverse(Phi) @ P
    flange_offset = (float(np.linalg.norm(off[:3, 3])), float(np.linalg.norm(pin.log3(off[:3, :3]))))

    W = [T_BASE_LINK_INERTIA]                                      # template link frames at q = 0
    W += [J[k] @ _rotation_z_to(axes_local[k]) for k in range(5)]
    W.append(Phi @ inverse(T_WRIST3_TOOL0))
    origins = np.empty((6, 6))
    for k in range(6):
        O = inverse(W[k]) @ W[k + 1]
        origins[k, :3] = O[:3, 3]
        origins[k, 3:] = rpy_nearest(O[:3, :3], UR_RPY_PUBLISHED[k])
    T_tool = oMb.actInv(data.oMf[chain.tool_frame_id]).homogeneous
    return UrKinematics(mount=_mount(chain, data, oMb), origins=origins, joints=tuple(j.name for j in chain.joints),
                        base_frame=chain.base_frame, flange_frame=model.frames[fid].name,
                        tool_frame=chain.tool_frame, T_tool0_tool=inverse(Phi) @ T_tool,
                        flange_offset=flange_offset)


def _mount(chain: UrdfChain, data, oMb) -> tuple[str, float, float]:
    """(link, translation m, rotation rad): where the robot's own base_link is, and its distance
    from the base frame. The first joint hangs from base_link itself in older descriptions, from
    base_link_inertia, base_link turned pi about z (:data:`T_BASE_LINK_INERTIA`), in
    ur_description's: of the two readings the one nearer the base frame's orientation (its link:
    the first joint's parent, or the link that parent is fixed to)."""
    model, doc = chain.model, chain.document
    first = doc.joints.get(chain.joints[0].name) if doc is not None else None
    if first is None or not model.existFrame(first.parent):
        return ("", 0.0, 0.0)
    M = oMb.actInv(data.oMf[model.getFrameId(first.parent)]).homogeneous      # T_base_parent
    up = doc.parent_joint.get(first.parent)
    above = up.parent if up is not None and up.kind == "fixed" else first.parent
    best = ("", math.inf, math.inf)
    for link, T in ((first.parent, M), (above, M @ inverse(T_BASE_LINK_INERTIA))):
        t, r = float(np.linalg.norm(T[:3, 3])), float(np.linalg.norm(pin.log3(T[:3, :3])))
        if r < best[2] - 1e-9:
            best = (link, t, r)
    return best


def template_tool0(origins: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) the pose of ``tool0`` in ``base_link`` of the ur_description template with the
    joint ``origins`` (6, 6) (x, y, z, roll, pitch, yaw) at configurations Q (N, 6), rad."""
    Q = np.atleast_2d(np.asarray(Q, float))
    out = np.empty((len(Q), 4, 4))
    for n, q in enumerate(Q):
        T = T_BASE_LINK_INERTIA.copy()
        for k in range(6):
            O = _rpy(*origins[k, 3:])
            O[:3, 3] = origins[k, :3]
            Rz = np.eye(4)
            Rz[:3, :3] = pin.rpy.rpyToMatrix(0.0, 0.0, q[k])
            T = T @ O @ Rz
        out[n] = T @ T_WRIST3_TOOL0
    return out


def default_hash(origins: np.ndarray) -> str:
    """``calib_<decimal>``: 63 bits of the SHA-256 of the origins' text (the pattern of the hashes
    UR's own calibration writes, ``calib_4890363623803256388``); the same numbers give the same hash."""
    text = " ".join(repr(float(v)) for v in np.asarray(origins, float).ravel())
    return f"calib_{int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], 'big') >> 1}"


def check_hash(value) -> str:
    """``value`` as the ``kinematics.hash`` text: a non-empty string of one line of printable
    characters, at most 200; else :class:`calib.ParameterError`."""
    if not isinstance(value, str) or not value.strip() or len(value) > 200 or not value.isprintable():
        raise ParameterError(f"kinematics hash must be one line of 1 to 200 printable characters (e.g. "
                             f"calib_4890363623803256388), got {value!r:.60}")
    return value.strip()
