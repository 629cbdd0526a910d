"""KUKA KRL data lists (``.dat``): the ``E6AXIS``/``AXIS`` and ``E6POS``/``POS`` declarations.

Grammar followed, as the controller writes it (quoted from published files):

* ros-industrial/kuka_experimental, ``kuka_kss_hw_interface/krl/KSS_86/Program/ROS/ros_krlptp.dat``::

      DEFDAT  ROS_KRLPTP PUBLIC
      E6AXIS nextMove={A1 -156.919830,A2 -103.435272,A3 29.4374046,A4 2.74812388,A5 -45.1240845,A6 10.6140194,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
      ENDDAT

  and ``kuka_ros_driver.dat`` there: ``GLOBAL E6AXIS ROS_joint_pos_tgt={A1 -41.7453308,...,E1
  0.00540800,...}``, ``vel_ratio[4]=2.12917962E-06`` (nine significant digits, ``E`` exponents);
* RoboDK's KUKA post processors (ros-industrial-attic/robodk_postprocessors, Apache-2.0), the
  data list lines they write: ``DECL E6POS XP1={X 27.0236969,Y 1220.23962,Z 669.846619,A
  -90.0563354,B 53.4202652,C -178.565933,S 2,T 35,E1 0.0,...}``, ``DECL FDAT FP1={TOOL_NO
  1,BASE_NO 0,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}``; and ``S 'B010',T 'B101010'``
  (Status and Turn as binary literals).

A declaration is ``[DECL] [GLOBAL] TYPE NAME={KEY value,...}`` on one line, outside ``;``
comments. Axis values are degrees (mm for linear axes): A1..A6 are the robot's joints in chain
order, E1..E6 external axes (kept as they are). Positions are X, Y, Z mm and A, B, C degrees
with ``R = Rz(A) Ry(B) Rx(C)``, in the base frame of the point's ``FDAT`` (``FP`` + the name after
``X``): a ``BASE_NO`` other than 0 is a base the data list does not define, and the point is
refused. Status and Turn are integers or ``'Bnnn'`` literals
(:mod:`calib.compensation.configuration`).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.programs import NUMBER, ProgramTarget, line_of

EXPECTED = "E6AXIS/AXIS {A1 ..} or E6POS/POS {X .., S .., T ..} declarations"
_IDENT = r"[A-Za-z_$][A-Za-z0-9_$]*"
_DECL = re.compile(rf"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(E6AXIS|AXIS|E6POS|POS|FDAT)[ \t]+({_IDENT})[ \t]*=[ \t]*\{{",
                   re.IGNORECASE | re.MULTILINE)
_PAIR = re.compile(rf"([A-Za-z_][A-Za-z0-9_]*)[ \t]+('B[01]+'|{NUMBER}|#?{_IDENT})", re.IGNORECASE)
_AXES = [f"A{i}" for i in range(1, 7)]


def _comment_start(text: str, at: int) -> bool:
    """Whether ``at`` lies after a ';' on its line (a KRL comment)."""
    start = text.rfind("\n", 0, at) + 1
    return ";" in text[start:at]


def _braces(path, text, m):
    end = text.find("}", m.end())
    if end < 0 or "\n" in text[m.end():end]:
        raise MeasurementFormatError(path, f"{m.group(2)}: the value has no closing '}}' on its line; expected "
                                           f"{m.group(1).upper()} {m.group(2)}={{KEY value,...}}",
                                     row=line_of(text, m.start()))
    return m.end(), end


def _status(path, line, name, key, text) -> int:
    t = text.strip("'").upper()
    try:
        return int(t[1:], 2) if t.startswith("B") else int(float(text))
    except ValueError:
        raise MeasurementFormatError(path, f"{name}: {key} {text!r} is not a status/turn value; expected an "
                                           f"integer or 'Bnnn'", row=line) from None


def parse(path: Path, text: str, robot) -> tuple[list[ProgramTarget], list[str]]:
    """The targets of a KRL data list for ``robot`` (see the module docstring)."""
    n = robot.n_joints
    if n > 6:
        raise MeasurementFormatError(path, f"KRL axis data hold six robot axes A1..A6; the chain has {n} joints")
    scale = np.where(robot.prismatic, 1e-3, math.pi / 180.0)
    fdat, found = {}, []
    for m in _DECL.finditer(text):
        if _comment_start(text, m.start(1)):
            continue
        kind, name = m.group(1).upper(), m.group(2)
        a, b = _braces(path, text, m)
        line = line_of(text, m.start())
        pairs = {}
        for p in _PAIR.finditer(text, a, b):
            pairs[p.group(1).upper()] = (p.group(2), p.start(2), p.end(2))
        if kind == "FDAT":
            fdat[name.upper()] = pairs
            continue
        found.append((kind, name, line, pairs))
    targets, notes = [], []
    for kind, name, line, pairs in found:
        def number(key):
            if key not in pairs:
                raise MeasurementFormatError(path, f"{name}: no {key}; expected {kind} {name}={{{', '.join(keys)} ...}}",
                                             row=line)
            try:
                return float(pairs[key][0])
            except ValueError:
                raise MeasurementFormatError(path, f"{name}: {key} {pairs[key][0]!r} is not a number; expected a REAL "
                                                   f"(degrees, or mm for X, Y, Z)", row=line) from None
        if kind in ("E6AXIS", "AXIS"):
            keys = _AXES[:n]
            q = np.array([number(k) for k in keys]) * scale
            fields = tuple((k, pairs[k][1], pairs[k][2], pairs[k][0]) for k in keys)
            targets.append(ProgramTarget(name=name, line=line, kind="joints", q=q, T=None, configuration=None,
                                         fields=fields))
            continue
        keys = ["X", "Y", "Z", "A", "B", "C"]
        v = [number(k) for k in keys]
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("ZYX", v[3:], degrees=True).as_matrix()
        T[:3, 3] = np.array(v[:3]) * 1e-3
        config = None
        if ("S" in pairs) != ("T" in pairs):
            raise MeasurementFormatError(path, f"{name}: {'S' if 'S' in pairs else 'T'} without "
                                               f"{'T' if 'S' in pairs else 'S'}; expected both Status and Turn, "
                                               f"or neither", row=line)
        if "S" in pairs:
            config = (_status(path, line, name, "S", pairs["S"][0]), _status(path, line, name, "T", pairs["T"][0]))
        fields = tuple((k, pairs[k][1], pairs[k][2], pairs[k][0]) for k in keys + (["S", "T"] if config else []))
        refused = ""
        f = fdat.get(("F" + name[1:]).upper()) if name.upper().startswith("X") else None
        if f is not None and "BASE_NO" in f and f["BASE_NO"][0] not in ("0", "0.0"):
            refused = (f"its FDAT F{name[1:]} names BASE_NO {f['BASE_NO'][0]}, a base frame this data list does not "
                       f"define (targets are taken in $ROBROOT, BASE_NO 0)")
        targets.append(ProgramTarget(name=name, line=line, kind="pose", q=None, T=T, configuration=config,
                                     fields=fields, refused=refused))
    return targets, notes


def real(x: float) -> str:
    """A KRL REAL as the controller writes it: nine significant digits, 'E' exponents, a '.0'
    on whole numbers (``-41.7453308``, ``2.12917962E-06``, ``0.0``)."""
    if x == 0:
        return "0.0"
    s = f"{x:.9g}".replace("e", "E")
    if "." not in s and "E" not in s:
        s += ".0"
    return s


def joint_fields(target: ProgramTarget, q: np.ndarray, robot) -> dict:
    scale = np.where(robot.prismatic, 1e3, 180.0 / math.pi)
    return {k: real(float(v)) for k, v in zip(_AXES, q * scale)}


def _like(original: str, value: int) -> str:
    """A Status or Turn value written as the original was: 'Bnnn' (as many digits) or decimal."""
    o = original.strip()
    if o.startswith("'"):
        return f"'B{value:0{max(len(o) - 3, 1)}b}'"
    return str(value)


def pose_fields(target: ProgramTarget, T: np.ndarray, configuration) -> dict:
    from scipy.spatial.transform import Rotation

    abc = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    out = {k: real(float(v)) for k, v in zip("XYZ", T[:3, 3] * 1e3)}
    out.update({k: real(float(v)) for k, v in zip("ABC", abc)})
    if configuration is not None and target.configuration is not None:
        original = {f[0]: f[3] for f in target.fields}
        out["S"] = _like(original["S"], int(configuration[0]))
        out["T"] = _like(original["T"], int(configuration[1]))
    return out


def status_turn_text(configuration) -> str:
    return f"S {configuration[0]},T {configuration[1]}"


def joint_program(path: Path, robot, q: np.ndarray, names: list[str]) -> dict:
    """A KRL program moving through ``q`` with PTP motions: ``path`` (the .src) and its .dat
    (one ``DECL E6AXIS`` per configuration)."""
    n = robot.n_joints
    if n > 6:
        raise MeasurementFormatError(path, f"KRL axis data hold six robot axes; the chain has {n} joints")
    module = re.sub(r"[^A-Za-z0-9_]", "_", path.stem) or "calib_program"
    idents = [re.sub(r"[^A-Za-z0-9_]", "_", f"X{name}") for name in names]
    if len(set(i.upper() for i in idents)) != len(idents):
        idents = [f"XP{k + 1}" for k in range(len(names))]
    scale = np.where(robot.prismatic, 1e3, 180.0 / math.pi)
    src = [f"DEF {module}()", "  ; written by calib: PTP through the joint configurations of " + path.with_suffix('.dat').name]
    dat = [f"DEFDAT {module} PUBLIC"]
    for ident, name, row in zip(idents, names, q * scale):
        axes = ",".join(f"A{i + 1} {real(float(v))}" for i, v in enumerate(row))
        extra = ",".join(f"A{i + 1} 0.0" for i in range(n, 6))
        dat.append(f"DECL E6AXIS {ident}={{{axes}{',' + extra if extra else ''},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,"
                   f"E6 0.0}} ; {name}")
        src.append(f"  PTP {ident}")
    src.append("END")
    dat.append("ENDDAT")
    return {path.with_suffix(".src"): "\n".join(src) + "\n", path.with_suffix(".dat"): "\n".join(dat) + "\n"}
