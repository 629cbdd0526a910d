"""URScript programs (``.script``): ``movej``/``movel``/``movep``/``servoj`` targets and Polyscope's
waypoint variables.

Grammar followed (quoted from published files):

* Universal Robots' URScript manual: ``movej(q, a=1.4, v=1.05, t=0, r=0)`` "q: joint positions
  (q can also be specified as a pose, then inverse kinematics is used to calculate the
  corresponding joint positions)", ``movel(pose, a=1.2, v=0.25, t=0, r=0)``; a pose is
  ``p[x, y, z, ax, ay, az]`` (metres, a rotation vector in radians), joints a list in radians;
* RoboDK's Universal Robots post processor (ros-industrial-attic/robodk_postprocessors
  ``Universal_Robots_SCRIPT.py``, Apache-2.0): ``movej([%.6f, ...],accel_radss,speed_rads,0,%s)``,
  ``movel(p[%.6f, %.6f, %.6f, %.6f, %.6f, %.6f],accel_mss,speed_ms,0,%s)``;
* Polyscope's exported scripts name waypoints ``global Waypoint_1_p=p[.4391, -.1849, .2770, 2.2,
  -2.2, 0]`` and ``global Waypoint_1_q=[...]``.

Targets: the first argument of ``movej``, ``movel``, ``movep`` and ``servoj`` when it is a literal
(a ``p[...]`` pose or a six-number joint list; named ``line N``), and the literals assigned to a
variable whose name ends in ``_p`` (a pose) or ``_q`` (joints). Everything else (``set_tcp(p[...])``,
features, other lists) is left as it is. ``#`` starts a comment. Poses are of the TCP in the
controller's Base frame (ur_description's ``base``); a program that calls ``set_tcp`` with a
non-zero TCP has its poses refused unless the TCP is the tool frame used (a note says so).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.programs import NUMBER, ProgramTarget, line_of

EXPECTED = "movej/movel/movep/servoj with a p[...] pose or a [...] joint list, or Waypoint_n_p / _q variables"
_S = r"\s*"
_LIST = r"\[" + _S + (_S + "," + _S).join([f"({NUMBER})"] * 6) + _S + r"\]"
_MOVE = re.compile(r"\b(movej|movel|movep|servoj)\s*\(\s*(p?)\s*" + _LIST)
_VAR = re.compile(r"(?:\bglobal\s+)?\b([A-Za-z_][A-Za-z0-9_]*_([pq]))\s*=\s*(p?)\s*" + _LIST)
_TCP = re.compile(r"\bset_tcp\s*\(\s*p\s*" + _LIST)


def _in_comment(text: str, at: int) -> bool:
    start = text.rfind("\n", 0, at) + 1
    return "#" in text[start:at]


def parse(path: Path, text: str, robot) -> tuple[list[ProgramTarget], list[str]]:
    """The targets of a URScript program for ``robot`` (see the module docstring)."""
    n = robot.n_joints
    found = []
    for m in _MOVE.finditer(text):
        if not _in_comment(text, m.start()):
            found.append((m.start(), f"line {line_of(text, m.start())} {m.group(1)}", m.group(2) == "p", m, 3))
    for m in _VAR.finditer(text):
        if _in_comment(text, m.start()):
            continue
        pose = m.group(3) == "p"
        if pose != (m.group(2) == "p"):
            raise MeasurementFormatError(path, f"{m.group(1)}: a {'pose' if pose else 'joint list'} in a variable named "
                                               f"_{m.group(2)}; expected p[...] for _p and [...] for _q",
                                         row=line_of(text, m.start()))
        found.append((m.start(), m.group(1), pose, m, 4))
    tcp = [m for m in _TCP.finditer(text) if not _in_comment(text, m.start())
           and any(abs(float(v)) > 0 for v in m.groups())]
    targets = []
    for at, name, pose, m, first in sorted(found, key=lambda f: f[0]):
        line = line_of(text, at)
        vals = np.array([float(m.group(i)) for i in range(first, first + 6)])
        spans = [(m.start(i), m.end(i), m.group(i)) for i in range(first, first + 6)]
        if not pose:
            if n != 6:
                raise MeasurementFormatError(path, f"{name}: a joint list of six values; the chain has {n} joints",
                                             row=line)
            fields = tuple((f"q{i + 1}", *spans[i]) for i in range(6))
            targets.append(ProgramTarget(name=name, line=line, kind="joints", q=vals.copy(), T=None,
                                         configuration=None, fields=fields))
            continue
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(vals[3:]).as_matrix()
        T[:3, 3] = vals[:3]
        refused = ""
        if tcp:
            refused = (f"the program sets a TCP (set_tcp at line {line_of(text, tcp[0].start())}): its poses are of "
                       f"that TCP, not of the tool frame")
        fields = tuple((k, *spans[i]) for i, k in enumerate(("x", "y", "z", "rx", "ry", "rz")))
        targets.append(ProgramTarget(name=name, line=line, kind="pose", q=None, T=T, configuration=None,
                                     fields=fields, refused=refused))
    return targets, []


def real(x: float) -> str:
    """A URScript number: SI (m, rad) to 1e-9, trailing zeros dropped."""
    s = f"{x:.9f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def joint_fields(target: ProgramTarget, q: np.ndarray, robot) -> dict:
    return {f"q{i + 1}": real(float(v)) for i, v in enumerate(q)}


def pose_fields(target: ProgramTarget, T: np.ndarray, configuration) -> dict:
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    old = np.array([float(f[3]) for f in target.fields[3:]])
    angle = float(np.linalg.norm(rv))
    if angle > 1e-9 and rv @ old < 0 and abs(angle - math.pi) < 1e-6:
        rv = -rv                             # (at pi both signs are the same rotation: keep the program's)
    vals = list(T[:3, 3]) + list(rv)
    return {k: real(float(v)) for k, v in zip(("x", "y", "z", "rx", "ry", "rz"), vals)}


def joint_program(path: Path, robot, q: np.ndarray, names: list[str]) -> dict:
    """A URScript program moving through ``q`` with ``movej`` (a=1.4, v=1.05, URScript's
    defaults), each preceded by a comment naming the configuration."""
    if robot.n_joints != 6:
        raise MeasurementFormatError(path, f"URScript joint lists hold six joints; the chain has {robot.n_joints}")
    func = re.sub(r"[^A-Za-z0-9_]", "_", path.stem) or "calib_program"
    if not func[0].isalpha():
        func = "p" + func
    lines = [f"def {func}():", "  # written by calib: movej through joint configurations"]
    for name, row in zip(names, q):
        lines.append(f"  # {name}")
        lines.append("  movej([" + ", ".join(real(float(v)) for v in row) + "], a=1.4, v=1.05)")
    lines.append("end")
    return {path: "\n".join(lines) + "\n"}
