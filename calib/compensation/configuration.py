"""The solution branch of a 6R arm's joints, and the vendors' configuration data that name it.

A tool pose is reached by up to eight joint solutions of a six-axis arm, separated by its three
singular surfaces; which one a controller uses is its *configuration*. Compensation must keep it:
a correction of a few millimetres never changes the branch, and a solver that lands on another
one has produced another motion, not a correction (:mod:`calib.compensation.compensate`).

Branch, for any arm whose first six joints are revolute (:func:`branch_indicators`), from the
joint axes ``z_k`` through the points ``o_k`` at the joints (robot base frame) and the wrist point
``W`` (the point of axis 4 nearest axis 5: the wrist centre of a spherical wrist, on axis 4 of a
UR):

* shoulder ``s = (W - o_1) . (z_2 x z_1)``: zero when joint 1 moves ``W`` along the plane of
  motion of joints 2 and 3 (the wrist over axis 1, or in the plane of axes 1 and 2 of a UR);
* elbow ``e = z_2 . ((o_3 - o_2) x (W - o_3))``: zero when the arm is stretched (``W`` on the line
  through axes 2 and 3, seen along ``z_2``);
* wrist ``w = z_5 . (z_4 x z_6)``: zero when axes 4 and 6 are aligned.

The signs of ``(s, e, w)`` name the branch; they change only through a singular configuration.
:func:`branch_change` compares two configurations: another sign, or a joint moved by more than a
quarter turn (another turn of a joint of range beyond 360 deg), is a change of branch.

Vendors' configuration data, computed from the joints (:func:`vendor_configuration`), each from
the published definition quoted:

* KUKA Status and Turn (KSS expert programming, as quoted on robot-forum.com, thread 7173:
  "If the x-value of the wrist root point, expressed in the A1 coordinate system, is positive, the
  robot is in the basic area" (bit 0 = 0; negative: overhead area, 1), "A1 coordinate system: If
  axis 1 is at 0°, it is identical to the $ROBROOT coordinate system. For values not equal to 0°,
  it moves with axis 1"; Siemens SINUMERIK ONE Programming Manual 12/2019 (6FC5398-2EP40-0BA0),
  "Bit 1 Position of axis 3 ... = 0 A3 <0° (elbow down) = 1 A3 ≥0° (elbow up) ... For robots with
  an offset between axes 3 and 4, the angle at which the value of bit 1 changes depends on the
  magnitude of this offset", "Bit 2 Position of axis 5 = 0 A5 ≥0° (no handflip) = 1 A5 <0°
  (handflip)"; Turn: bit i - 1 is 1 when axis i is below 0°). The elbow bit is the sign of ``e``
  against its sign at A3 = +90°, which is exactly "A3 at or beyond the stretched angle".
* ABB confdata (RAPID Reference Manual, confdata: "quadrant 0 is the first quarter revolution,
  0-90°, in a positive direction from the zero position; quadrant 1 is the next revolution,
  90-180°, etc. Quadrant -1 is the revolution 0° - (-90°)": ``cf = floor(angle / 90°)`` for axes
  1, 4, 6; ``cfx`` = 4 x (wrist centre behind axis 1) + 2 x (wrist centre behind the lower arm) +
  (axis 5 negative), the table "cfx: 0 in front of / in front of / positive ... 7 behind / behind
  / negative").
* FANUC configuration string (RoboDK's FANUC R-30iA post processor, Apache-2.0, as published in
  ros-industrial-attic/robodk_postprocessors Fanuc_R30iA.py: "F means axis 5 >= 0, N means axis 5
  < 0"; 'D' when the lower arm (elbow down), 'B' when rear; turns of J1, J4, J6 by
  ``floor((angle + 180) / 360)`` (mirrored below 0)).

"Front" (KUKA's basic area, ABB's "in front of axis 1", FANUC's T) is the sign of ``W`` along the
controller base frame's x axis turned with axis 1; "elbow up" (KUKA bit 1 = 1, ABB and FANUC in
front of the lower arm / U) is the sign of ``e`` as in the vendor's reference pose (KUKA: A3 =
+90°; ABB and FANUC: the zero pose, upper arm vertical and forearm forward). Joint values are the
URDF's, which ROS-Industrial's support packages make equal to the controller's.
"""
from __future__ import annotations

import math

import numpy as np

from dataclasses import dataclass
from calib.errors import CalibError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel

__all__ = ["branch_indicators", "branch_change", "vendor_configuration", "with_turns", "Configurations",
           "branch_key", "format_configuration", "VENDORS"]

#: The vendors whose configuration data are computed, and the name of their data.
VENDORS = {"kuka": "Status and Turn", "abb": "confdata", "fanuc": "configuration string"}
#: A joint moved further than this from its reference (rad) is on another turn or branch.
QUARTER_TURN = math.pi / 2
#: Indicators smaller than this (relative to the arm's size: the reach at q = 0, its square for
#: the elbow, 1 for the wrist's sine) have no sign: the configuration is at a singularity (within
#: about 0.6 deg of the wrist's), where the branch is not defined and the status says "singular"
#: when the Jacobian says so.
SIGN_TOL = 1e-2


def _six_revolute(robot: RobotModel) -> bool:
    return robot.n_joints >= 6 and not robot.prismatic[:6].any()


def branch_indicators(robot: RobotModel, Q: np.ndarray, *, T_base_frame: np.ndarray | None = None) -> dict:
    """The branch indicators of configurations Q (N, n) rad of an arm whose first six joints are
    revolute (see the module docstring), each (N,): ``shoulder`` (m), ``elbow`` (m^2), ``wrist``
    (unitless), ``front`` (m: the wrist point along the x axis of ``T_base_frame``, the controller's
    base frame in the robot's base frame (default: the base frame itself), turned with axis 1),
    and ``wrist_point`` (N, 3) metres in the robot's base frame."""
    if not _six_revolute(robot):
        raise CalibError(f"the branch of a configuration is defined for arms whose first six joints are revolute; "
                         f"this chain has {robot.n_joints} joints ({', '.join(robot.joint_names)})")
    Q = np.atleast_2d(np.asarray(Q, float))
    kin = ChainKinematics(robot)
    kin.set_values(robot.values, twists=False)
    Qe = kin.effective(Q)
    n, N = robot.n_joints, len(Qe)
    frames = (np.empty((n + 1, 3, 3, N)), np.empty((n + 1, 3, N)))
    kin._walk(Qe, frames)
    z = np.transpose(frames[0][:n, 2], (2, 0, 1))          # (N, n, 3) joint axes
    o = np.transpose(frames[1][:n], (2, 0, 1))             # (N, n, 3) points on them
    # wrist point: the point of axis 4 nearest axis 5 (their common perpendicular's foot)
    z4, z5, o4, o5 = z[:, 3], z[:, 4], o[:, 3], o[:, 4]
    b = np.einsum("ij,ij->i", z4, z5)
    d = o5 - o4
    denom = 1.0 - b ** 2
    t = np.where(denom > 1e-12, (np.einsum("ij,ij->i", d, z4) - b * np.einsum("ij,ij->i", d, z5))
                 / np.where(denom > 1e-12, denom, 1.0), 0.0)
    W = o4 + t[:, None] * z4
    z1, z2 = z[:, 0], z[:, 1]
    shoulder = np.einsum("ij,ij->i", W - o[:, 0], np.cross(z2, z1))
    elbow = np.einsum("ij,ij->i", z2, np.cross(o[:, 2] - o[:, 1], W - o[:, 2]))
    wrist = np.einsum("ij,ij->i", z5, np.cross(z4, z[:, 5]))
    f0 = np.array([1.0, 0.0, 0.0]) if T_base_frame is None else np.asarray(T_base_frame, float)[:3, 0]
    # f turned with axis 1 by q1 (Rodrigues), projected on the plane normal to axis 1
    q1 = Qe[:, 0]
    c, s_ = np.cos(q1)[:, None], np.sin(q1)[:, None]
    f = f0 * c + np.cross(z1, f0) * s_ + z1 * (z1 @ f0)[:, None] * (1 - c)
    f -= z1 * np.einsum("ij,ij->i", f, z1)[:, None]
    front = np.einsum("ij,ij->i", W - o[:, 0], f)
    return {"shoulder": shoulder, "elbow": elbow, "wrist": wrist, "front": front, "wrist_point": W}


def _signs(x: np.ndarray, scale: float) -> np.ndarray:
    return np.where(np.abs(x) <= SIGN_TOL * scale, 0, np.sign(x)).astype(int)


def _scale(robot: RobotModel) -> float:
    """A length of the arm (m): the reach at q = 0, at least 1 cm."""
    R, p = ChainKinematics(robot).frame_poses(np.zeros((1, robot.n_joints)))
    return max(float(np.linalg.norm(p[0])), 0.01)


def branch_change(robot: RobotModel, q: np.ndarray, q_ref: np.ndarray) -> list[str]:
    """Why each configuration of ``q`` (N, n) rad is on another branch than ``q_ref`` (N, n): ""
    when it is on the same one, else the first change in words (the shoulder, elbow or wrist
    indicator's sign (arms with six revolute joints first), or a joint moved by more than a
    quarter turn)."""
    q, q_ref = np.atleast_2d(q), np.atleast_2d(q_ref)
    out = [""] * len(q)
    moved = np.abs(q - q_ref)
    if _six_revolute(robot):
        a = branch_indicators(robot, q)
        b = branch_indicators(robot, q_ref)
        L = _scale(robot)
        for key, scale, what in (("shoulder", L, "the wrist crossed the shoulder singularity (front/back)"),
                                 ("elbow", L * L, "the elbow crossed its stretched position (up/down)"),
                                 ("wrist", 1.0, "the wrist flipped (axes 4 and 6 crossed alignment)")):
            sa, sb = _signs(a[key], scale), _signs(b[key], scale)
            for k in np.flatnonzero((sa * sb) < 0):
                out[k] = out[k] or what
    for k in np.flatnonzero(moved.max(axis=1) > QUARTER_TURN):
        i = int(np.argmax(moved[k]))
        out[k] = out[k] or (f"{robot.joint_names[i]} moved by {math.degrees(moved[k, i]):.1f} deg (another turn "
                            f"or branch)")
    return out


# ====================================================================== vendors' configuration data
def vendor_configuration(robot: RobotModel, Q: np.ndarray, vendor: str, *,
                         T_base_frame: np.ndarray | None = None) -> list[tuple]:
    """The configuration data of ``vendor`` ("kuka", "abb", "fanuc") of configurations Q (N, n)
    rad, one tuple per configuration (definitions: module docstring):

    kuka : (S, T) integers (Status bits 0-2, Turn bits 0-5);
    abb : (cf1, cf4, cf6, cfx) integers;
    fanuc : ("F" or "N", "U" or "D", "T" or "B", turn of J1, of J4, of J6).

    ``T_base_frame`` : (4, 4) the controller's base frame in the robot's base frame (its x axis
    defines "front").
    """
    if vendor not in VENDORS:
        raise CalibError(f"no configuration data for {vendor!r}: known are {', '.join(VENDORS)}")
    Q = np.atleast_2d(np.asarray(Q, float))
    ind = branch_indicators(robot, Q, T_base_frame=T_base_frame)
    n = robot.n_joints
    ref = np.zeros((1, n))
    if vendor == "kuka":
        ref[0, 2] = math.pi / 2
    e_ref = branch_indicators(robot, ref)["elbow"][0]
    front = ind["front"] >= 0
    up = np.sign(ind["elbow"]) == np.sign(e_ref)
    deg = np.degrees(Q)
    out = []
    for k in range(len(Q)):
        if vendor == "kuka":
            S = (0 if front[k] else 1) | (2 if up[k] else 0) | (0 if deg[k, 4] >= 0 else 4)
            T = sum(1 << i for i in range(min(n, 6)) if deg[k, i] < 0)
            out.append((S, T))
        elif vendor == "abb":
            cf = [int(math.floor(deg[k, i] / 90.0)) for i in (0, 3, 5)]
            cfx = (0 if front[k] else 4) + (0 if up[k] else 2) + (0 if deg[k, 4] >= 0 else 1)
            out.append((*cf, cfx))
        else:
            out.append(("F" if deg[k, 4] >= 0 else "N", "U" if up[k] else "D", "T" if front[k] else "B",
                        *(_fanuc_turn(deg[k, i]) for i in (0, 3, 5))))
    return out


def _fanuc_turn(angle_deg: float) -> int:
    """The turn number of a FANUC joint angle (RoboDK's post: floor((a + 180) / 360) at or above
    0, mirrored below)."""
    if angle_deg >= 0:
        return int(math.floor((angle_deg + 180.0) / 360.0))
    return -int(math.floor((-angle_deg + 180.0) / 360.0))


def with_turns(robot: RobotModel, Q: np.ndarray, vendor: str, configurations) -> np.ndarray:
    """``Q`` (N, n) rad with revolute joints moved by whole turns, within their limits, to the
    turn (KUKA: the sign of each axis; ABB: the quadrant of axes 1, 4, 6; FANUC: the turn number of
    J1, J4, J6) each configuration of ``configurations`` names: the same poses. Joints no turn
    reaches are left as they are (the configuration then differs, and the solution is not taken)."""
    Q = np.array(Q, float)
    lo, hi = robot.lower, robot.upper
    turn = 2 * math.pi
    for k, c in enumerate(configurations):
        if vendor == "kuka":
            wanted = [(i, (lambda a, i=i: (a < 0) == bool((c[1] >> i) & 1))) for i in range(min(6, robot.n_joints))]
        elif vendor == "abb":
            wanted = [(i, (lambda a, q=q: math.floor(math.degrees(a) / 90.0) == q)) for i, q in zip((0, 3, 5), c[:3])]
        else:
            wanted = [(i, (lambda a, t=t: _fanuc_turn(math.degrees(a)) == t)) for i, t in zip((0, 3, 5), c[3:])]
        for i, ok in wanted:
            if robot.prismatic[i] or ok(Q[k, i]):
                continue
            for m in (1, -1, 2, -2):
                a = Q[k, i] + m * turn
                if lo[i] - 1e-12 <= a <= hi[i] + 1e-12 and ok(a):
                    Q[k, i] = a
                    break
    return Q


@dataclass(frozen=True, eq=False)
class Configurations:
    """The configuration a controller is asked to take at each target (a program's or a targets
    file's), in the vendor's data.

    vendor : "kuka", "abb" or "fanuc". values : one tuple per target as
        :func:`vendor_configuration` returns them. T_base_frame : (4, 4) the controller's base
        frame in the robot's base frame (its x axis says where "front" is), or None (the base
        frame itself).
    """

    vendor: str
    values: tuple
    T_base_frame: np.ndarray | None = None

    def branch_key(self, k: int):
        """The part of target k's configuration that names the branch (KUKA: Status; ABB: cfx;
        FANUC: the three letters); the rest (turns, quadrants) names turns of single joints."""
        return branch_key(self.vendor, self.values[k])


def branch_key(vendor: str, value: tuple):
    """The branch part of a configuration tuple (see :class:`Configurations`)."""
    return value[0] & 7 if vendor == "kuka" else (value[3] if vendor == "abb" else tuple(value[:3]))


def format_configuration(vendor: str, value: tuple) -> str:
    """A configuration as the vendor writes it: KUKA ``S 6, T 27`` (decimal; the bits 'B110',
    'B011011'); ABB ``[0,-1,0,1]``; FANUC ``'N U T, 0, 0, 0'``."""
    if vendor == "kuka":
        return f"S {value[0]}, T {value[1]}"
    if vendor == "abb":
        return "[" + ",".join(str(int(v)) for v in value) + "]"
    return f"'{value[0]} {value[1]} {value[2]}, {value[3]}, {value[4]}, {value[5]}'"
