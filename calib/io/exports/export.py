"""Exports of a calibrated URDF for the user's stack (:func:`export_calibration`, ``calib export``).

Formats (:data:`calib.choices.EXPORT_FORMATS`):

* ``ur-yaml``: the ``kinematics`` file of Universal Robots' ``ur_description``
  (``kinematics_params_file`` of ``ur_robot_driver``), for a UR-like 6R chain
  (:mod:`calib.io.exports.ur`).
* ``joint-origins-yaml``: every joint of any URDF with its ``xyz``, ``rpy`` (and ``axis``,
  ``type``, ``parent``, ``child``) as the text of the URDF attributes, for a xacro's
  properties (below).
* ``mdh-csv``: the TM-MDH table and the base and tool transforms, units in the column names,
  with uncertainties from the calibration's JSON report (:mod:`calib.io.exports.mdh`).

Every export is read back before it is handed out (the YAML parsed, the CSV read by
:func:`calib.io.exports.mdh.parse_mdh_csv`) and checked against the URDF's kinematics, to
:data:`READ_BACK_TOL`; files are written atomically and never over an input.

joint-origins-yaml in a xacro: the file holds ``joints: {NAME: {type, parent, child, xyz, rpy,
axis}}`` with xyz / rpy / axis as the URDF attribute text (``"0.1 0 0.089159"``), so a xacro
takes them as they are::

    <xacro:property name="cal" value="${xacro.load_yaml('calibrated_joints.yaml')['joints']}"/>
    <joint name="shoulder_pan_joint" type="revolute">
      <origin xyz="${cal['shoulder_pan_joint']['xyz']}" rpy="${cal['shoulder_pan_joint']['rpy']}"/>
      ...

Joints a calibration added (the writer's ``tool`` link) are listed like the others, with their
parent and child links.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.checks import check_choice, check_path
from calib.choices import EXPORT_FORMATS
from calib.errors import CalibError, OutputError, ParameterError
from calib.io.fileio import atomic_write_text, check_not_input, output_target

__all__ = ["ExportResult", "export_calibration", "READ_BACK_TOL"]

#: Largest difference (metres, radians) between the kinematics an export describes, read back,
#: and the URDF's; an export that misses it is an error (a bug), never written.
READ_BACK_TOL = 1e-9
#: ur-yaml: a base frame farther than this (m, rad) from the parent link of the first joint is
#: a mounting (a pedestal, a work cell), beyond any calibration's base correction: a note says so.
MOUNT_NOTE_M, MOUNT_NOTE_RAD = 0.01, 0.01


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_calibration` returns.

    format : the format; text : the file's content; path : where it was written (None when no
    output was given); notes : one-line remarks for the user (e.g. what a format leaves out);
    read_back : (metres, radians) the largest difference between the kinematics of the text
    read back and the URDF's (0, 0 for joint-origins-yaml, compared number by number).
    """

    format: str
    text: str
    path: Path | None
    notes: tuple[str, ...]
    read_back: tuple[float, float]


def _yaml():
    try:
        import yaml
    except ImportError:        # a dependency (pyproject.toml), but may be missing from an environment
        raise CalibError("the YAML exports need PyYAML: pip install pyyaml") from None
    return yaml


def _frame(value, name: str) -> str | None:
    if value is not None and not (isinstance(value, str) and value):
        raise ParameterError(f"{name} must be a frame name (a non-empty str) or None, got {value!r:.60}")
    return value


def export_calibration(urdf_path, format: str, output: str | Path | None = None, *,
                       kinematics_hash: str | None = None, report: str | Path | None = None,
                       flange_frame: str | None = None, base_frame: str | None = None,
                       tool_frame: str | None = None) -> ExportResult:
    """Export the calibrated URDF ``urdf_path`` in ``format`` (``ur-yaml``, ``joint-origins-yaml``
    or ``mdh-csv``); write it to ``output`` atomically when given.

    Parameters
    ----------
    urdf_path : a URDF (calibrated by calib or not; its recorded frames are the defaults), or a
        :class:`calib.io.urdf.reader.UrdfText` (e.g. a UR kinematics YAML's,
        :func:`calib.io.urdf.ur_description.ur_description`).
    format : one of :data:`calib.choices.EXPORT_FORMATS`.
    output : the file to write (never an input), or None to only return the text.
    kinematics_hash : ur-yaml only: the ``kinematics.hash`` text; default ``calib_<decimal>`` from
        the SHA-256 of the exported numbers (:func:`calib.io.exports.ur.default_hash`).
    report : mdh-csv only: the calibration's JSON report (``calib calibrate --report``): the table
        then holds the calibration's own parameters and their standard deviations.
    flange_frame : ur-yaml only: the URDF link the template's ``tool0`` stands for (default
        ``tool0`` when fixed to the last link, else the tool frame).
    base_frame, tool_frame : the chain's frames (default: the URDF's recorded frames, else the
        root link and the default tool frame of :func:`calib.load_robot`).

    Raises :class:`calib.CalibError` (one line) on bad input, before anything is written:
    unknown format, option of another format, not a URDF, a chain ur-yaml cannot map, output =
    input, a report of another calibration.
    """
    from calib.io.urdf.reader import UrdfText

    # a URDF made in memory (a UR kinematics YAML's, calib.io.urdf.ur_description) is read as it is;
    # its source file is the input that the output must not overwrite
    if not isinstance(urdf_path, UrdfText):
        urdf_path = check_path(urdf_path, "urdf_path")
    input_path = urdf_path.path if isinstance(urdf_path, UrdfText) else urdf_path
    format = check_choice(format, "format", EXPORT_FORMATS)
    output = None if output is None else check_path(output, "output")
    report = None if report is None else check_path(report, "report")
    for value, name, fmt in ((kinematics_hash, "kinematics_hash", "ur-yaml"), (report, "report", "mdh-csv"),
                             (flange_frame, "flange_frame", "ur-yaml")):
        if value is not None and format != fmt:
            raise ParameterError(f"{name} applies to the {fmt} format only, not {format}")
    if kinematics_hash is not None:
        from calib.io.exports.ur import check_hash

        kinematics_hash = check_hash(kinematics_hash)
    flange_frame, base_frame, tool_frame = (_frame(v, n) for v, n in ((flange_frame, "flange_frame"),
                                                                      (base_frame, "base_frame"), (tool_frame, "tool_frame")))
    if output is not None:
        check_not_input(output, [input_path, report])
        output_target(output)                    # a device, FIFO or socket: refused before any work
        if output.is_dir() or not output.parent.is_dir():
            raise OutputError(output, "is a folder, expected a file name" if output.is_dir() else
                              f"folder {output.parent} does not exist")
    if format == "ur-yaml":
        text, notes, back = _ur_yaml(urdf_path, kinematics_hash, flange_frame, base_frame, tool_frame)
    elif format == "joint-origins-yaml":
        text, notes, back = _joint_origins(urdf_path, base_frame, tool_frame)
    else:
        text, notes, back = _mdh_csv(urdf_path, report, base_frame, tool_frame)
    if output is not None:
        atomic_write_text(output, text)
    return ExportResult(format=format, text=text, path=output, notes=tuple(notes), read_back=back)


def _version() -> str:
    from calib import __version__

    return __version__


# ====================================================================== ur-yaml
def _ur_yaml(urdf_path, kinematics_hash, flange_frame, base_frame, tool_frame):
    from calib.io.exports.ur import UR_SEGMENTS, default_hash, template_tool0, ur_kinematics
    from calib.io.urdf.document import rpy_nearest
    from calib.io.urdf.reader import read_urdf_chain

    yaml = _yaml()
    chain = read_urdf_chain(urdf_path, base_frame, tool_frame)
    ur = ur_kinematics(chain, flange_frame)
    h = kinematics_hash or default_hash(ur.origins)
    kin = {seg: dict(zip(("x", "y", "z", "roll", "pitch", "yaw"), map(_tidy, row)))
           for seg, row in zip(UR_SEGMENTS, ur.origins)}
    kin["hash"] = h
    T = ur.T_tool0_tool
    tool = dict(zip(("x", "y", "z", "roll", "pitch", "yaw"),
                    map(_tidy, np.concatenate([T[:3, 3], rpy_nearest(T[:3, :3])]))))
    doc = {"kinematics": kin,
           "calib": {"source": str(urdf_path), "base_frame": ur.base_frame, "flange_frame": ur.flange_frame,
                     "tool_frame": ur.tool_frame, "joints": dict(zip(UR_SEGMENTS, ur.joints)),
                     "tool_in_tool0": tool}}
    header = [f"Kinematics of {urdf_path} for Universal Robots' ur_description (kinematics_params_file),",
              f"written by calib {_version()} (calib export --format ur-yaml).",
              f"base_link = {ur.base_frame!r}; tool0 = {ur.flange_frame!r} on axis 6; the entries map the chain's",
              "joints by order (shoulder = the first moving joint from the base ... wrist_3 = the sixth).",
              "hash: " + ("given by the user (--hash)" if kinematics_hash else
                          "calib_ + 63 bits of the SHA-256 of the numbers (set another with --hash)") + ".",
              "The 'calib' block (ignored by ur_description) says where the numbers come from; tool_in_tool0",
              "is the calibrated tool frame in tool0 (x y z in m, roll pitch yaw in rad, URDF convention)."]
    text = "".join(f"# {line}\n" for line in header) + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    # read back: the template's tool0 from the written numbers, then the tool, against the URDF
    back = yaml.safe_load(text)
    origins = np.array([[back["kinematics"][s][k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]
                        for s in UR_SEGMENTS], float)
    Q = _configurations(chain, 12)
    tb = back["calib"]["tool_in_tool0"]
    import pinocchio as pin

    T_t = np.eye(4)
    T_t[:3, :3] = pin.rpy.rpyToMatrix(tb["roll"], tb["pitch"], tb["yaw"])
    T_t[:3, 3] = (tb["x"], tb["y"], tb["z"])
    dp, dr = _difference(template_tool0(origins, Q) @ T_t, chain.T_meas_tool(Q))
    _check_read_back("ur-yaml", dp, dr)
    notes = []
    rec = chain.document.frames if chain.document is not None else None
    if rec is not None and rec.measurement_estimated and chain.base_frame == rec.base_frame:
        notes.append(f"{urdf_path} records that its calibration estimated the measurement frame: base_link of the "
                     f"export is its base frame {chain.base_frame!r}; check that it is the robot's base, not the "
                     f"instrument's")
    link, t_m, r_m = ur.mount
    if link and link != chain.base_frame and (t_m > MOUNT_NOTE_M or r_m > MOUNT_NOTE_RAD):
        notes.append(f"base_link of the export is {chain.base_frame!r}, {t_m * 1e3:.4g} mm / {r_m:.4g} rad from "
                     f"{link!r} (the robot's own base, where its first joint hangs from): the shoulder entry "
                     f"includes that offset; if "
                     f"your xacro mounts the robot there, export with --base-frame {link}")
    t_off, r_off = ur.flange_offset
    if t_off > 1e-9 or r_off > 1e-9:
        notes.append(f"flange frame {ur.flange_frame!r} is {t_off * 1e3:.4g} mm / {r_off:.4g} rad off axis 6: "
                     f"tool0 is its projection onto the axis (tool_in_tool0 gives the tool exactly)")
    p = float(np.linalg.norm(T[:3, 3]))
    if ur.tool_frame != ur.flange_frame or p > 1e-9:
        notes.append(f"the calibration's tool frame {ur.tool_frame!r} is {p * 1e3:.4g} mm from the template's tool0: the kinematics "
                     f"block holds the arm up to tool0, calib.tool_in_tool0 in the file the tool frame in tool0 "
                     f"(the controller's TCP, if that frame is the tool)")
    return text, notes, (dp, dr)


def _tidy(v: float) -> float:
    """``v`` to 15 significant digits (error < 1e-15 of it), 0.0 below 1e-15: ``-0.1197``, not
    ``-0.11969999999999997``, and no ``1.4e-39`` of rounding."""
    v = float(v)
    return 0.0 if abs(v) < 1e-15 else float(f"{v:.15g}")


def _configurations(chain, n: int) -> np.ndarray:
    lo = np.array([j.lower for j in chain.joints])
    hi = np.array([j.upper for j in chain.joints])
    lo, hi = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    rng = np.random.default_rng(0)
    return np.vstack([np.zeros(len(lo)), rng.uniform(lo, hi, size=(n, len(lo)))])


def _difference(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Largest position (m) and rotation (rad) difference of two stacks of poses (N, 4, 4)."""
    from calib.io.exports.mdh import rotation_angle

    dp = float(np.max(np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)))
    dr = max(rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in zip(A, B))
    return dp, dr


def _check_read_back(fmt: str, dp: float, dr: float) -> None:
    if not (dp <= READ_BACK_TOL and dr <= READ_BACK_TOL):
        raise CalibError(f"{fmt}: the export read back differs from the URDF's kinematics by {dp:.3g} m / "
                         f"{dr:.3g} rad (more than {READ_BACK_TOL:g}); nothing written (a bug: please report it)")


# ====================================================================== joint-origins-yaml
def _numbers(text: str | None, default: str) -> str:
    """The attribute text with its numbers written in full (``repr``), single-spaced."""
    return " ".join(repr(float(v)) for v in (text or default).split())


def _joint_origins(urdf_path, base_frame, tool_frame):
    from calib.io.urdf.reader import read_urdf_chain

    yaml = _yaml()
    chain = read_urdf_chain(urdf_path, base_frame, tool_frame)   # a URDF Pinocchio can build
    root = chain.document.tree.getroot()
    joints = {}
    for el in root.findall("joint"):
        origin, axis = el.find("origin"), el.find("axis")
        entry = {"type": el.get("type"), "parent": el.find("parent").get("link"),
                 "child": el.find("child").get("link"),
                 "xyz": _numbers(None if origin is None else origin.get("xyz"), "0 0 0"),
                 "rpy": _numbers(None if origin is None else origin.get("rpy"), "0 0 0")}
        if el.get("type") != "fixed":
            entry["axis"] = _numbers(None if axis is None else axis.get("xyz"), "1 0 0")
        joints[el.get("name")] = entry
    doc = {"source": str(urdf_path), "base_frame": chain.base_frame, "tool_frame": chain.tool_frame,
           "chain": [j.name for j in chain.joints], "joints": joints}
    header = [f"Joint origins of {urdf_path}, written by calib {_version()} (calib export --format joint-origins-yaml).",
              "Each joint: type, parent, child, and the URDF attribute text of <origin xyz rpy> (m, rad) and",
              "<axis xyz>. In a xacro:",
              "  <xacro:property name=\"cal\" value=\"${xacro.load_yaml('THIS.yaml')['joints']}\"/>",
              "  <origin xyz=\"${cal['JOINT']['xyz']}\" rpy=\"${cal['JOINT']['rpy']}\"/>"]
    text = "".join(f"# {line}\n" for line in header) + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    back = yaml.safe_load(text)["joints"]
    if back != joints:
        raise CalibError("joint-origins-yaml: the export read back differs from the URDF's joints; nothing "
                         "written (a bug: please report it)")
    return text, [], (0.0, 0.0)


# ====================================================================== mdh-csv
def _mdh_csv(urdf_path, report, base_frame, tool_frame):
    from calib.io.exports.mdh import kinematics_difference, mdh_csv_text, model_from_report, parse_mdh_csv
    from calib.io.urdf.reader import load_robot

    robot = load_robot(urdf_path, base_frame, tool_frame)
    notes: list[str] = []
    std = None
    model = robot
    if report is not None:
        model, std, notes = model_from_report(report, robot)
    source = (f"the parameters of the calibration report {report} (checked against the URDF)" if report is not None
              else "calib's MDH derivation of the URDF")
    comments = (f"MDH table of {urdf_path} ({source}), written by calib {_version()} (calib export --format mdh-csv).",
                "L_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i) (q_i adds to d_i for a prismatic joint);",
                f"T_{model.base_frame}_{model.tool_frame}(q) = T_base . L_1 ... L_n . T_tool, "
                "with T_base, T_tool = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx).",
                "beta empty: the joint has no Hayati beta." + (" *_std_*: standard deviation (1 sigma) of the "
                                                                "calibration; empty: held fixed." if std is not None else ""))
    text = mdh_csv_text(model, std=std, comments=comments)
    back = parse_mdh_csv(text)
    if report is not None:
        dp, dr = kinematics_difference(back, model)
    else:
        dp, dr = kinematics_difference(back, robot)
    _check_read_back("mdh-csv", dp, dr)
    return text, notes, (dp, dr)
