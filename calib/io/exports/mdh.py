"""The ``mdh-csv`` export: a robot's TM-MDH table (theta, d, a, alpha, beta per joint) and its
base and tool transforms in one CSV file, with uncertainties when a calibration report gives
them; and its reader (:func:`read_mdh_csv`), the one reader of this file kind.

The file::

    # comment lines (what, from where, the convention)
    item,name,type,theta_deg,d_mm,a_mm,alpha_deg,beta_deg,x_mm,y_mm,z_mm,rz_deg,ry_deg,rx_deg[,<std columns>]
    base,world,,,,,,,0,0,0,0,0,0
    joint,joint_1,revolute,0,330,50,-90,,,,,,,
    ...
    tool,tool,,,,,,,0,0,80,0,0,0

with, in metres and radians inside calib (:class:`calib.RobotModel`)::

    T_meas_tool(q) = T_meas_base . prod_i L_i(q_i) . T_flange_tool
    L_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)   (q_i adds to d_i if prismatic)
    T_meas_base, T_flange_tool = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)  (Eq. 3: u and v)

``beta`` is empty for joints without Hayati's beta. A calibration of several targets has one
``tool`` row per target (``name`` the target id). With a report, the columns ``theta_std_deg``
... ``rx_std_deg`` give each parameter's standard deviation (1 sigma) from the calibration's
covariance; a cell is empty where the calibration held the parameter fixed.

Where the values come from: without a report, from the calibrated URDF by calib's own MDH
derivation (:func:`calib.load_robot`: base and tool transforms carry the frames, u = v = 0 in
the URDF's derived frames); with a report, the calibration's own parameters as identified (the
report's ``parameters``: joint values and the whole base and tool transforms), after a check
that they give the URDF's kinematics (to :data:`REPORT_MATCH_TOL`, up to where the measurement
frame lies, which a report may place apart from the URDF's base).
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
from pathlib import Path

import numpy as np

from calib.errors import CalibError, MeasurementFormatError
from calib.io.csv.cells import read_cell
from calib.model.chain import JOINT_KINDS, U_NAMES, ChainJoint, v_names
from calib.model.robot import RobotModel
from calib.model.spatial import inverse, zyx_parameters, zyx_transform

__all__ = ["MDH_COLUMNS", "mdh_csv_text", "model_from_report", "read_mdh_csv", "parse_mdh_csv"]

_JOINT_COLS = (("theta", "deg"), ("d", "mm"), ("a", "mm"), ("alpha", "deg"), ("beta", "deg"))
_FRAME_COLS = (("x", "mm"), ("y", "mm"), ("z", "mm"), ("rz", "deg"), ("ry", "deg"), ("rx", "deg"))
#: The value columns, in file order (units in the names).
MDH_COLUMNS = ("item", "name", "type") + tuple(f"{k}_{u}" for k, u in _JOINT_COLS + _FRAME_COLS)
_STD_COLUMNS = tuple(f"{k}_std_{u}" for k, u in _JOINT_COLS + _FRAME_COLS)
_SCALE = {"mm": 1e-3, "deg": math.pi / 180}
#: Largest disagreement (metres; radians) between a report's parameters and the URDF's kinematics.
REPORT_MATCH_TOL = 1e-8
#: The units a report's parameter values may be given in, and their factor to SI.
REPORT_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "rad": 1.0, "mrad": 1e-3, "urad": 1e-6,
                "deg": math.pi / 180}
#: The names of geometry parameters (joint MDH values, u, v of every target).
_GEOMETRY = re.compile(r"(theta|d|a|alpha|beta)[0-9]+|[uv]_(x|y|z|alpha|beta|gamma)(@.+)?")


def _cell(value: float | None, unit: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return repr(float(value) / _SCALE[unit])


def mdh_csv_text(robot: RobotModel, *, std: dict[str, float] | None = None, comments: tuple[str, ...] = ()) -> str:
    """The MDH CSV of ``robot``'s geometry (see the module docstring); ``std`` maps parameter
    names (theta1, u_x, v_x@A, ...) to standard deviations in SI units, adding the std columns
    (empty where a name is absent). ``comments`` are written first, one ``#`` line each."""
    from calib.io.csv.cells import comment_line, csv_records, spreadsheet_cell

    t = robot.mdh_table()
    with_std = std is not None
    out = io.StringIO()
    for line in comments:
        out.write(comment_line(line) + "\n")
    records = [list(MDH_COLUMNS + (_STD_COLUMNS if with_std else ()))]
    n_j, n_f = len(_JOINT_COLS), len(_FRAME_COLS)

    def frame_row(item, name, T, names):
        x = zyx_parameters(T)
        row = [item, spreadsheet_cell(name), ""] + [""] * n_j + [_cell(v, u) for v, (_, u) in zip(x, _FRAME_COLS)]
        if with_std:
            row += [""] * n_j + [_cell(std.get(p), u) for p, (_, u) in zip(names, _FRAME_COLS)]
        records.append(row)

    frame_row("base", robot.base_frame, robot.T_meas_base(), list(U_NAMES))
    for i, joint in enumerate(robot.joints, start=1):
        vals = [t[k][i - 1] for k in ("theta", "d", "a", "alpha", "beta")]
        row = ["joint", spreadsheet_cell(joint.name), joint.kind] + \
            [_cell(v, u) for v, (_, u) in zip(vals, _JOINT_COLS)] + [""] * n_f
        if with_std:
            row += [_cell(std.get(f"{k}{i}"), u) for k, u in _JOINT_COLS] + [""] * n_f
        records.append(row)
    for k, target in enumerate(robot.targets or (None,)):
        frame_row("tool", target or robot.tool_frame, robot.T_flange_tool(k), robot.v_names(k))
    out.write(csv_records(records))
    return out.getvalue()


# ====================================================================== reading
def read_mdh_csv(path: str | Path) -> RobotModel:
    """The :class:`calib.RobotModel` of an MDH CSV written by ``calib export --format mdh-csv``
    (u and v hold the base and tool transforms, reference transforms the identity; joints
    without limits). Raises :class:`calib.MeasurementFormatError` naming the file, row and
    column of anything unexpected."""
    from calib.checks import check_path

    path = check_path(path, "path")
    try:
        with open(path, encoding="utf-8", newline="") as fh:     # (a quoted name's own carriage return kept)
            text = fh.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise MeasurementFormatError(path, f"cannot be read: {getattr(exc, 'strerror', None) or exc}") from None
    return parse_mdh_csv(text, path)


def parse_mdh_csv(text: str, path: str | Path | None = None) -> RobotModel:
    """:func:`read_mdh_csv` of the file's ``text`` (``path`` names it in errors)."""
    # (lines end at \n or \r\n: a quoted name may hold a carriage return, or a line end across lines)
    lines = [line[:-1] if line.endswith("\r") else line for line in text.split("\n")]
    rows = [(n, line) for n, line in enumerate(lines, start=1) if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise MeasurementFormatError(path, "no header: expected the columns " + ",".join(MDH_COLUMNS))
    reader = csv.reader([line for _, line in rows])
    parsed, starts, used = [], [], 0
    for record in reader:       # (each record with the file line it starts on)
        parsed.append(record)
        starts.append((rows[used][0], None))
        used = reader.line_num
    rows = starts
    header = [h.strip() for h in parsed[0]]
    missing = [c for c in MDH_COLUMNS if c not in header]
    if missing:
        raise MeasurementFormatError(path, f"missing column(s) {', '.join(missing)}; expected "
                                           f"{','.join(MDH_COLUMNS)}", row=rows[0][0])
    col = {h: k for k, h in enumerate(header)}

    def number(r, line, name, optional=False):
        text = r[col[name]].strip() if col[name] < len(r) else ""
        if not text:
            if optional:
                return math.nan
            raise MeasurementFormatError(path, "empty cell, expected a number", row=line, column=name)
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise MeasurementFormatError(path, f"{text!r} is not a finite number", row=line, column=name)
        return v * _SCALE[name.rsplit("_", 1)[1]]

    joints, table, bases, tools = [], [], [], []
    for (line, _), r in zip(rows[1:], parsed[1:]):
        item = r[col["item"]].strip() if len(r) > col["item"] else ""
        # (a name as written: a leading quote that kept a spreadsheet from running it dropped,
        # surrounding blanks of a hand-edited file dropped, the name's own blanks kept)
        name = read_cell(r[col["name"]]) if len(r) > col["name"] else ""
        name = name if name != r[col["name"]] else name.strip()
        if item == "joint":
            kind = r[col["type"]].strip() if len(r) > col["type"] else ""
            if kind not in JOINT_KINDS:
                raise MeasurementFormatError(path, f"joint type {kind!r}, expected one of {', '.join(JOINT_KINDS)}",
                                             row=line, column="type")
            joints.append(ChainJoint(name or f"joint_{len(joints) + 1}", kind, -math.inf, math.inf))
            table.append([number(r, line, f"{k}_{u}", optional=(k == "beta")) for k, u in _JOINT_COLS])
        elif item in ("base", "tool"):
            T = zyx_parameters(zyx_transform(*[number(r, line, f"{k}_{u}") for k, u in _FRAME_COLS]))
            (bases if item == "base" else tools).append((name, T, line))
        else:
            raise MeasurementFormatError(path, f"item {item!r}, expected joint, base or tool", row=line, column="item")
    if not joints or len(bases) != 1 or not tools:
        raise MeasurementFormatError(path, f"expected one base row, joint rows and tool rows; found {len(bases)} "
                                           f"base, {len(joints)} joint and {len(tools)} tool row(s)")
    theta, d, a, alpha, beta = np.array(table).T
    base_name = bases[0][0] or "meas"
    if len(tools) == 1:
        return RobotModel.from_mdh(joints, theta, d, a, alpha, beta, u=bases[0][1], v=tools[0][1],
                                   base_frame=base_name, tool_frame=tools[0][0] or "tool")
    ids = [t for t, _, _ in tools]
    if len(set(ids)) != len(ids) or not all(ids):
        raise MeasurementFormatError(path, "tool rows of several targets need distinct names (the target ids)",
                                     row=tools[0][2], column="name")
    robot = RobotModel.from_mdh(joints, theta, d, a, alpha, beta, u=bases[0][1], base_frame=base_name)
    return robot.with_targets(ids, np.array([zyx_transform(*v) for _, v, _ in tools]))


# ====================================================================== the calibration's report
def model_from_report(report_path: str | Path, urdf_model: RobotModel) -> tuple[RobotModel, dict[str, float], list[str]]:
    """The calibration's own model from its JSON report (``calib calibrate --report``): joint
    values and the base and tool transforms as identified, on ``urdf_model``'s joints; its
    standard deviations (SI, by parameter name; fixed parameters absent) and notes.

    Refused (:class:`calib.CalibError`, one line naming the report) when the report cannot be
    read, lacks a parameter of the chain, or gives other kinematics than ``urdf_model`` (the
    calibrated URDF's) by more than :data:`REPORT_MATCH_TOL`, compared up to the measurement frame.
    """
    path = Path(report_path)
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CalibError(f"{path}: file not found (the JSON report of calib calibrate --report)") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CalibError(f"{path}: not a JSON report of calib calibrate --report ({' '.join(str(exc).split())})") from None
    params = report.get("parameters") if isinstance(report, dict) else None
    if isinstance(report, dict) and report.get("kind") == "touch":
        raise CalibError(f"{path}: the report of a touch calibration lists its free parameters only, without "
                         f"units: export without --report (the values then come from the calibrated URDF)")
    if not isinstance(params, list) or not all(isinstance(p, dict) and isinstance(p.get("name"), str) for p in params):
        raise CalibError(f"{path}: no 'parameters' list: not a JSON report of calib calibrate --report")
    values, std, notes = {}, {}, []
    for p in params:
        unit = p.get("unit")
        ident = p.get("identified")
        if not _GEOMETRY.fullmatch(p["name"]):
            continue      # compliance / periodic joint terms: not part of the MDH table
        if unit not in REPORT_UNITS:
            raise CalibError(f"{path}: parameter {p['name']!r} has unit {unit!r}; expected one of "
                             f"{', '.join(REPORT_UNITS)}")
        if not isinstance(ident, (int, float)) or isinstance(ident, bool) or not math.isfinite(ident):
            raise CalibError(f"{path}: parameter {p['name']!r}: identified value {ident!r} is not a finite number")
        values[p["name"]] = ident * REPORT_UNITS[unit]
        s = p.get("std")
        if p.get("free") and isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(s):
            std[p["name"]] = s * REPORT_UNITS[unit]
    skipped = [p["name"] for p in params if p["name"] not in values]
    if skipped:
        notes.append(f"{path}: {len(skipped)} joint-term parameter(s) ({', '.join(skipped[:4])}"
                     f"{', ...' if len(skipped) > 4 else ''}) are not part of an MDH table: left out")
    n = urdf_model.n_joints

    def need(name):
        if name not in values:
            raise CalibError(f"{path}: no parameter {name!r}: the report is not of a calibration of this "
                             f"{n}-joint chain ({', '.join(urdf_model.joint_names)})")
        return values[name]

    cols = {k: np.array([need(f"{k}{i}") for i in range(1, n + 1)]) for k in ("theta", "d", "a", "alpha")}
    beta = np.array([values.get(f"beta{i}", math.nan) for i in range(1, n + 1)])
    u = [need(name) for name in U_NAMES]
    targets = urdf_model.targets
    kw = dict(base_frame=urdf_model.base_frame, tool_frame=urdf_model.tool_frame)
    if targets:
        model = RobotModel.from_mdh(urdf_model.joints, cols["theta"], cols["d"], cols["a"], cols["alpha"], beta,
                                    u=u, **kw)
        refs = [zyx_transform(*[need(name) for name in v_names(t)]) for t in targets]
        model = model.with_targets(targets, np.array(refs))
    else:
        model = RobotModel.from_mdh(urdf_model.joints, cols["theta"], cols["d"], cols["a"], cols["alpha"], beta,
                                    u=u, v=[need(name) for name in v_names()], **kw)
    dp, dr = kinematics_difference(model, urdf_model, relative=True)
    if dp > REPORT_MATCH_TOL or dr > REPORT_MATCH_TOL:
        raise CalibError(f"{path}: its parameters do not describe {urdf_model.urdf_path or 'the URDF'}: the "
                         f"kinematics differ by {dp * 1e3:.3g} mm / {dr:.3g} rad (a report of another calibration?)")
    return model, std, notes


def rotation_angle(R: np.ndarray) -> float:
    """The angle (rad) of the rotation matrix R (3, 3), accurate near 0 (not arccos of the trace)."""
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(math.atan2(s, 0.5 * (np.trace(R) - 1.0)))


def kinematics_difference(a: RobotModel, b: RobotModel, *, relative: bool = False, n: int = 12,
                          rng: int = 0) -> tuple[float, float]:
    """Largest position (m) and rotation (rad) difference of the tool poses (every target) of
    two models of the same joints over ``n`` random configurations (and q = 0). ``relative``:
    of the tool pose relative to the one at q = 0 (``T(0)^-1 T(q)``), which does not depend on
    where either model's measurement frame lies."""
    Q = np.vstack([np.zeros(a.n_joints), a.random_configurations(n, rng)])
    dp = dr = 0.0
    for k in range(a.n_targets):
        A0, B0 = a.T_meas_tool(Q[0], k), b.T_meas_tool(Q[0], k)
        for q in Q:
            A, B = a.T_meas_tool(q, k), b.T_meas_tool(q, k)
            if relative:
                A, B = inverse(A0) @ A, inverse(B0) @ B
            dp = max(dp, float(np.linalg.norm(A[:3, 3] - B[:3, 3])))
            dr = max(dr, rotation_angle(A[:3, :3].T @ B[:3, :3]))
    return dp, dr
