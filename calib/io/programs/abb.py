"""ABB RAPID modules (``.mod``): ``robtarget`` and ``jointtarget`` literals.

Grammar followed (quoted from published files):

* a RAPID module of ABB's YuMi demonstrations (``MODULE DanceR``, public)::

      PERS robtarget pHelix_R:=[[547.59,-9.12,341.68],[0.0201017,-0.0484601,-0.70938,-0.702871],[1,-1,-1,11],[-175.428,9E+09,9E+09,9E+09,9E+09,9E+09]];
      CONST jointtarget jpDance10:=[[20.000007956,-99.999986846,30.000014495,0,40.000015912,0],[-79.999977182,9E9,9E9,9E9,9E9,9E9]];
      MoveAbsJ jpDance10\\ID:=10,vDance,z20,tHandDance\\WObj:=wobj0;

* OrebroUniversity/yumi ``yumi_hw/rapid/EGM/TRobMain.mod`` (ABB, BSD): ``joint_position_home :=
  [[0, -130, 30, 0, 40, 0], [135, 9E9, 9E9, 9E9, 9E9, 9E9]];`` and ``MoveAbsJ
  joint_position_home, speed, fine, tool0;``;
* RoboDK's ABB IRC5 post processor (ros-industrial-attic/robodk_postprocessors, Apache-2.0): a
  robtarget written ``[[x, y, z],[q1, q2, q3, q4],[cf1,cf4,cf6,cfx],[9E+09,...]]`` with ``%.3f``
  millimetres and ``%.8f`` quaternions, a jointtarget's robot axes with six decimals.

A robtarget is ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a,...,eax_f]]``: millimetres, a
unit quaternion scalar first, the configuration (:mod:`calib.compensation.configuration`), the
external axes (kept); a jointtarget ``[[rax_1,...,rax_6],[eax_a,...]]``: degrees (mm for linear
axes). Every such literal outside ``!`` comments is a target, named by the variable it is
declared or assigned to (``line N`` for a literal in an instruction). A robtarget is in the
work object of the instruction that uses it: a module naming a ``\\WObj`` other than ``wobj0`` has
its robtargets refused (a frame the module does not define).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.programs import NUMBER, ProgramTarget, line_of

EXPECTED = ("robtarget [[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax..]] or jointtarget "
            "[[rax_1..rax_6],[eax..]] literals")
_S = r"\s*"
_N = rf"({NUMBER})"


def _group(k: int) -> str:
    return r"\[" + _S + (_S + "," + _S).join([_N] * k) + _S + r"\]"


_ROBTARGET = re.compile(r"\[" + _S + _group(3) + _S + "," + _S + _group(4) + _S + "," + _S + _group(4) + _S + ","
                        + _S + _group(6) + _S + r"\]")
_JOINTTARGET = re.compile(r"\[" + _S + _group(6) + _S + "," + _S + _group(6) + _S + r"\]")
_NAME = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*(?:\{[^}]*\})?\s*:=\s*$")
_WOBJ = re.compile(r"\\WObj\s*:=\s*([A-Za-z_][A-Za-z0-9_]*)", re.IGNORECASE)


def _in_comment(text: str, at: int) -> bool:
    start = text.rfind("\n", 0, at) + 1
    line = text[start:at]
    quoted = False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        elif ch == "!" and not quoted:
            return True
    return False


def _name(text: str, at: int) -> str | None:
    start = text.rfind("\n", 0, at) + 1
    m = _NAME.search(text[start:at])
    return m.group(1) if m else None


def parse(path: Path, text: str, robot) -> tuple[list[ProgramTarget], list[str]]:
    """The targets of a RAPID module for ``robot`` (see the module docstring)."""
    from scipy.spatial.transform import Rotation

    n = robot.n_joints
    scale = np.where(robot.prismatic, 1e-3, math.pi / 180.0)
    wobj = sorted({m.group(1) for m in _WOBJ.finditer(text) if not _in_comment(text, m.start())
                   and m.group(1).lower() != "wobj0"})
    found = []
    for kind, rx in (("pose", _ROBTARGET), ("joints", _JOINTTARGET)):
        for m in rx.finditer(text):
            if not _in_comment(text, m.start()):
                found.append((m.start(), kind, m))
    targets = []
    for at, kind, m in sorted(found, key=lambda f: f[0]):
        line = line_of(text, at)
        name = _name(text, at) or f"line {line}"
        vals = [float(g) for g in m.groups()]
        spans = [(m.start(i), m.end(i), m.group(i)) for i in range(1, len(m.groups()) + 1)]
        if kind == "joints":
            if n > 6:
                raise MeasurementFormatError(path, f"{name}: a jointtarget holds six robot axes; the chain has {n} "
                                                   f"joints", row=line)
            extra = vals[n:6]
            if any(v != 0 and abs(v) < 8.9e9 for v in extra):
                raise MeasurementFormatError(path, f"{name}: robot axes {n + 1}..6 hold values but the robot has {n} "
                                                   f"joints; expected 0 or 9E9 there", row=line)
            q = np.array(vals[:n]) * scale
            fields = tuple((f"rax_{i + 1}", *spans[i]) for i in range(n))
            targets.append(ProgramTarget(name=name, line=line, kind="joints", q=q, T=None, configuration=None,
                                         fields=fields))
            continue
        w = np.array(vals[3:7])
        norm = float(np.linalg.norm(w))
        if abs(norm - 1.0) > 1e-3:
            raise MeasurementFormatError(path, f"{name}: the quaternion [{', '.join(m.group(i) for i in range(4, 8))}] "
                                               f"has norm {norm:.6g}; expected a unit quaternion (q1 scalar first)",
                                         row=line)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat([w[1], w[2], w[3], w[0]]).as_matrix()
        T[:3, 3] = np.array(vals[:3]) * 1e-3
        cf = vals[7:11]
        if any(v != int(v) for v in cf):
            raise MeasurementFormatError(path, f"{name}: confdata {cf} holds a non-integer; expected integers "
                                               f"[cf1,cf4,cf6,cfx]", row=line)
        keys = ["x", "y", "z", "q1", "q2", "q3", "q4", "cf1", "cf4", "cf6", "cfx"]
        fields = tuple((k, *spans[i]) for i, k in enumerate(keys))
        refused = (f"the module moves in the work object {', '.join(wobj)}, which it does not define (targets are "
                   f"taken in the robot's base frame, wobj0)") if wobj else ""
        targets.append(ProgramTarget(name=name, line=line, kind="pose", q=None, T=T,
                                     configuration=tuple(int(v) for v in cf), fields=fields, refused=refused))
    return targets, []


def num(x: float, decimals: int) -> str:
    """A RAPID num with ``decimals`` decimals, trailing zeros dropped (``20``, ``-99.999986846``)."""
    s = f"{x:.{decimals}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def joint_fields(target: ProgramTarget, q: np.ndarray, robot) -> dict:
    scale = np.where(robot.prismatic, 1e3, 180.0 / math.pi)
    return {f"rax_{i + 1}": num(float(v), 9) for i, v in enumerate(q * scale)}


def pose_fields(target: ProgramTarget, T: np.ndarray, configuration) -> dict:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    wxyz = np.array([w, x, y, z])
    old = {f[0]: float(f[3]) for f in target.fields}
    if wxyz @ np.array([old["q1"], old["q2"], old["q3"], old["q4"]]) < 0:
        wxyz = -wxyz                       # the same rotation, the sign the program had
    out = {k: num(float(v), 6) for k, v in zip("xyz", T[:3, 3] * 1e3)}
    out.update({f"q{i + 1}": num(float(v), 9) for i, v in enumerate(wxyz)})
    if configuration is not None:
        out.update({k: str(int(v)) for k, v in zip(("cf1", "cf4", "cf6", "cfx"), configuration)})
    return out


def joint_program(path: Path, robot, q: np.ndarray, names: list[str]) -> dict:
    """A RAPID module moving through ``q`` with MoveAbsJ: one ``CONST jointtarget`` per
    configuration, then ``PROC main()`` with ``MoveAbsJ name, v100, fine, tool0;`` each."""
    n = robot.n_joints
    if n > 6:
        raise MeasurementFormatError(path, f"a jointtarget holds six robot axes; the chain has {n} joints")
    module = re.sub(r"[^A-Za-z0-9_]", "_", path.stem) or "calib_program"
    if not module[0].isalpha():
        module = "M" + module
    idents = [re.sub(r"[^A-Za-z0-9_]", "_", f"j{name}") for name in names]
    if len(set(i.lower() for i in idents)) != len(idents):
        idents = [f"jP{k + 1}" for k in range(len(names))]
    scale = np.where(robot.prismatic, 1e3, 180.0 / math.pi)
    lines = [f"MODULE {module}", "    ! written by calib: MoveAbsJ through joint configurations"]
    for ident, name, row in zip(idents, names, q * scale):
        rax = [num(float(v), 9) for v in row] + ["0"] * (6 - n)
        lines.append(f"    CONST jointtarget {ident}:=[[{','.join(rax)}],[9E9,9E9,9E9,9E9,9E9,9E9]]; ! {name}")
    lines += ["", "    PROC main()"]
    lines += [f"        MoveAbsJ {ident}, v100, fine, tool0;" for ident in idents]
    lines += ["    ENDPROC", "ENDMODULE"]
    return {path: "\n".join(lines) + "\n"}
