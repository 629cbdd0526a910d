"""FANUC TP programs in ASCII (``.LS``): the positions of the ``/POS`` section.

Grammar followed (quoted from published files):

* programs exported from FANUC controllers (public ``.LS`` files)::

      /POS
      P[1]{
         GP1:
      	UF : 1, UT : 3,		CONFIG : 'N U T, 0, 0, 0',
      	X =  -258.768  mm,	Y =   397.980  mm,	Z =  1033.305  mm,
      	W =    89.999 deg,	P =      .002 deg,	R =     2.111 deg
      };
      P[2:"Prise cloueur"]{ ... };
      /END

* RoboDK's FANUC R-30iA post processor (ros-industrial-attic/robodk_postprocessors
  ``Fanuc_R30iA.py``, Apache-2.0), its joint and Cartesian positions::

      P[1]{
         GP1:
          UF : 1, UT : 1,
          J1=    0.000 deg,    J2=    -40.966 deg,    J3=    43.328 deg,
          J4=    0.000 deg,    J5=    -84.792 deg,    J6=    180.000 deg
      };

  written with ``%.3f`` (``'\\tX =%10.3f  mm,...'``) and the configuration ``CONFIG : 'F U T, 0, 0,
  0'`` (:mod:`calib.compensation.configuration`).

A position's first group (``GP1``) is the robot: Cartesian (X, Y, Z mm; W, P, R deg with ``R =
Rz(R) Ry(P) Rx(W)``, in user frame UF) or joints (J1.. deg; E1.. kept). Other groups are left as
they are. A Cartesian position in a user frame other than 0 (the World frame) is refused: the
program does not define that frame. Joint values: FANUC's J3 is measured from the horizontal on
many models (the J2/J3 interaction); ROS-Industrial's FANUC driver converts with its
``J23_factor`` (``J3_urdf = J3 + J23_factor * J2``, fanuc_driver ``linkage_transform``), which a
FANUC program's joint positions need too (``j23_factor``; refused without it).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.programs import NUMBER, ProgramTarget, line_of

EXPECTED = "a /POS section with P[n]{ GP1: ... X = .. mm, ... } or J1= .. deg positions"
_POS = re.compile(r"^\s*P\[(\d+)(?::\"[^\"]*\")?\]\s*\{", re.MULTILINE)
_FIELD = re.compile(rf"\b(X|Y|Z|W|P|R|J\d|E\d)\s*=(\s*)({NUMBER})\s*(mm|deg)?", re.IGNORECASE)
_CONFIG = re.compile(r"CONFIG\s*:\s*'([^']*)'", re.IGNORECASE)
_UF = re.compile(r"\bUF\s*:\s*(\d+)", re.IGNORECASE)
_CFG = re.compile(r"^\s*([NF])\s+([UD])\s+([TB])\s*,\s*(-?\d+)\s*,\s*(-?\d+)\s*,\s*(-?\d+)\s*$", re.IGNORECASE)


def parse_config(path, line, name, text: str) -> tuple:
    """A FANUC configuration string ``'N U T, 0, 0, 0'`` as the tuple of
    :func:`calib.compensation.configuration.vendor_configuration`."""
    m = _CFG.match(text)
    if not m:
        raise MeasurementFormatError(path, f"{name}: configuration {text!r}; expected 'F|N U|D T|B, t1, t4, t6' "
                                           f"(e.g. 'N U T, 0, 0, 0')", row=line)
    return (m.group(1).upper(), m.group(2).upper(), m.group(3).upper(), int(m.group(4)), int(m.group(5)),
            int(m.group(6)))


def parse(path: Path, text: str, robot, *, j23_factor: float | None = None) -> tuple[list[ProgramTarget], list[str]]:
    """The positions of a FANUC ``.LS`` program for ``robot`` (see the module docstring)."""
    from scipy.spatial.transform import Rotation

    start = text.upper().find("\n/POS")
    if start < 0:
        return [], []
    stop = text.upper().find("\n/END", start + 1)
    stop = len(text) if stop < 0 else stop
    n = robot.n_joints
    targets = []
    for m in _POS.finditer(text, start, stop):
        close = text.find("};", m.end(), stop)
        if close < 0:
            raise MeasurementFormatError(path, f"P[{m.group(1)}] has no closing '}};'", row=line_of(text, m.start()))
        body_end = close
        gp2 = re.search(r"\bGP[2-9]\s*:", text[m.end():close])
        if gp2:
            body_end = m.end() + gp2.start()
        name = f"P[{m.group(1)}]"
        line = line_of(text, m.start())
        fields = {}
        for f in _FIELD.finditer(text, m.end(), body_end):
            key = f.group(1).upper()
            # the span takes the blanks before the number: a value is rewritten right-aligned in it
            fields[key] = (f.start(2), f.end(3), f.group(3))
        uf = _UF.search(text, m.end(), body_end)
        if all(k in fields for k in ("X", "Y", "Z", "W", "P", "R")):
            v = {k: float(fields[k][2]) for k in ("X", "Y", "Z", "W", "P", "R")}
            T = np.eye(4)
            T[:3, :3] = Rotation.from_euler("ZYX", [v["R"], v["P"], v["W"]], degrees=True).as_matrix()
            T[:3, 3] = np.array([v["X"], v["Y"], v["Z"]]) * 1e-3
            c = _CONFIG.search(text, m.end(), body_end)
            config = None if c is None else parse_config(path, line_of(text, c.start()), name, c.group(1))
            keys = ["X", "Y", "Z", "W", "P", "R"]
            spans = [(k, *fields[k]) for k in keys]
            if c is not None:
                spans.append(("CONFIG", c.start(1), c.end(1), c.group(1)))
            refused = ""
            if uf is not None and int(uf.group(1)) != 0:
                refused = (f"it is in user frame UF {uf.group(1)}, which the program does not define (positions are "
                           f"taken in the World frame, UF 0)")
            targets.append(ProgramTarget(name=name, line=line, kind="pose", q=None, T=T, configuration=config,
                                         fields=tuple(spans), refused=refused))
        elif all(f"J{i + 1}" in fields for i in range(n)):
            deg = np.array([float(fields[f"J{i + 1}"][2]) for i in range(n)])
            if j23_factor is None:
                raise MeasurementFormatError(path, f"{name}: joint positions need the J2/J3 interaction of this model "
                                                   f"(--j23-factor, ROS-Industrial's J23_factor: -1, 0 or 1)",
                                             row=line)
            if n >= 3:
                deg[2] = deg[2] + j23_factor * deg[1]
            q = np.where(robot.prismatic, deg * 1e-3, np.radians(deg))
            spans = tuple((f"J{i + 1}", *fields[f"J{i + 1}"]) for i in range(n))
            targets.append(ProgramTarget(name=name, line=line, kind="joints", q=q, T=None, configuration=None,
                                         fields=spans))
        else:
            raise MeasurementFormatError(path, f"{name}: GP1 holds neither X, Y, Z, W, P, R nor J1..J{n}; expected a "
                                               f"Cartesian or a joint position of the robot's {n} joints", row=line)
    return targets, []


def value(x: float, width: int = 0) -> str:
    """A FANUC number: three decimals, no 0 before the point (``-.000``, ``.002``, ``89.999``),
    right-aligned in ``width`` characters."""
    s = f"{x:.3f}"
    if s.startswith("0."):
        s = s[1:]
    elif s.startswith("-0."):
        s = "-" + s[2:]
    return s.rjust(width)


def joint_fields(target: ProgramTarget, q: np.ndarray, robot, *, j23_factor: float | None = None) -> dict:
    deg = np.where(robot.prismatic, q * 1e3, np.degrees(q))
    if len(deg) >= 3:
        deg = deg.copy()
        deg[2] = deg[2] - (j23_factor or 0.0) * deg[1]
    width = {f[0]: f[2] - f[1] for f in target.fields}
    return {f"J{i + 1}": value(float(v), width[f"J{i + 1}"]) for i, v in enumerate(deg)}


def pose_fields(target: ProgramTarget, T: np.ndarray, configuration) -> dict:
    from scipy.spatial.transform import Rotation

    r, p, w = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    width = {f[0]: f[2] - f[1] for f in target.fields}
    vals = dict(zip("XYZ", T[:3, 3] * 1e3))
    vals.update(W=w, P=p, R=r)
    out = {k: value(float(v), width[k]) for k, v in vals.items()}
    if configuration is not None and "CONFIG" in width:
        out["CONFIG"] = f"{configuration[0]} {configuration[1]} {configuration[2]}, {configuration[3]}, " \
                        f"{configuration[4]}, {configuration[5]}"
    return out


def joint_program(path: Path, robot, q: np.ndarray, names: list[str], *, j23_factor: float | None = None) -> dict:
    """A FANUC ``.LS`` program moving through ``q`` with joint motions ``J P[k] 20% FINE``, the
    positions as joints (J1.. deg, RoboDK's layout), UF 0 and UT 1."""
    if j23_factor is None:
        raise MeasurementFormatError(path, "a FANUC program of joint positions needs the model's J2/J3 interaction "
                                           "(--j23-factor, ROS-Industrial's J23_factor: -1, 0 or 1)")
    n = robot.n_joints
    prog = re.sub(r"[^A-Za-z0-9_]", "_", path.stem).upper()[:36] or "CALIB"
    deg = np.where(robot.prismatic, q * 1e3, np.degrees(q))
    if n >= 3:
        deg = deg.copy()
        deg[:, 2] = deg[:, 2] - j23_factor * deg[:, 1]
    lines = [f"/PROG  {prog}", "/ATTR", 'COMMENT\t\t= "calib joint moves";', f"LINE_COUNT\t= {len(q)};",
             "DEFAULT_GROUP\t= 1,*,*,*,*;", "/MN"]
    for k, name in enumerate(names):
        lines.append(f"{k + 1:4d}:J P[{k + 1}] 20% FINE    ;")
    lines.append("/POS")
    for k, (name, row) in enumerate(zip(names, deg)):
        label = re.sub(r'["]', "", str(name))[:16]
        lines.append(f'P[{k + 1}:"{label}"]{{')
        lines.append("   GP1:")
        lines.append("\tUF : 0, UT : 1,")
        cells = [f"J{i + 1}= {value(float(v), 9)} {'mm' if robot.prismatic[i] else 'deg'}" for i, v in enumerate(row)]
        for a in range(0, n, 3):
            lines.append("\t" + ",\t".join(cells[a:a + 3]) + ("," if a + 3 < n else ""))
        lines.append("};")
    lines.append("/END")
    return {path: "\n".join(lines) + "\n"}
