"""Write a calibrated robot model back into its URDF.

:func:`write_calibrated_urdf` copies the URDF a :class:`~calib.model.robot.RobotModel` was read from
and changes only the joint origins that carry the chain's kinematics, so that Pinocchio's (or any
URDF consumer's) forward kinematics of the tool frame in the base frame equal
``robot.T_meas_tool(q)``. Everything else stays as it is: links with their visuals, collisions,
inertials and materials, mesh filenames (``package://`` URIs untouched), joint axes, limits,
``dynamics``/``mimic``/``calibration``/``safety_controller`` tags, transmissions, ``gazebo`` and
``ros2_control`` blocks, comments and namespaces.

Why not yourdfpy for writing: yourdfpy 0.0.60 parses only links, joints and materials, and its
writer drops ``<mimic>``, ``<calibration>``, ``<safety_controller>``, every ``<transmission>``
and ``<gazebo>`` element and all comments, and its default filename handler rewrites
``package://`` mesh URIs to absolute paths. The writer therefore edits the XML document itself
(with lxml, the parser yourdfpy uses) and leaves every element it does not need to change alone;
the tests read the result back with yourdfpy and Pinocchio.

How the kinematics go into the URDF (all poses at q = 0, in the meas frame; "nom" is the
nominal model derived from the URDF, "cal" the calibrated one):

* MDH moving frame of joint i: ``X_i(q) = T_meas_base . prod_{k<i} L_k(q_k) . Rot(z, theta_i +
  q_i) Trans(z, d_i)`` (Pinocchio's ``oMi`` of :class:`calib.model.kinematics.ChainKinematics`). The
  URDF link ``L_i`` driven by joint i sits at the constant offset ``C_i = X_i^nom^-1 . T_meas_Li``
  from it (the nominal MDH z axis is the URDF joint axis). ``C_i`` is kept, so each link and its
  geometry stay attached to their body: ``T^cal_meas_Li = X_i^cal . C_i``.
* Fixed joints between ``L_{i-1}`` and the parent link ``P_i`` of joint i keep their nominal
  origins; joint i's origin becomes ``(T^cal_meas_Pi)^-1 . T^cal_meas_Li``. Joint offsets (theta)
  are folded into origins; ``<calibration>`` tags are not used (Pinocchio and ROS ignore them).
  The ``<axis>`` of each joint stays the URDF's.
* Base side: with ``K = T^cal_meas_base . (T^nom_meas_base)^-1`` (the change of MDH frame 0, in
  meas coordinates), the first fixed joint on the path from the base frame to ``P_1`` takes
  ``K`` (its origin becomes ``K . origin``, or ``origin . K^-1`` if the path leaves the base
  frame through its parent joint); the links beyond it move with the robot base. If the base
  frame is ``P_1`` itself (``base_link`` of a UR arm, the root of many arms), joint 1's origin
  takes ``K`` (exact: the URDF joint axis is expressed in the child link, which keeps its
  offset ``C_1`` from the MDH frame), and the base frame keeps its name.
* Tool side: on the fixed path ``L_n -> F_1 -> ... -> F_k = tool``, with k >= 2 the first joint
  takes the change of the MDH flange frame relative to ``L_n`` (``F_1 .. F_{k-1}`` move with the
  flange) and the last the change of flange -> tool; with k = 1 that joint takes both; with
  k = 0 (the tool frame is ``L_n``) a link ``tool`` (``tool_calibrated`` if taken) is added with
  a fixed joint from ``L_n``: the output's tool frame is then that new link (the calibrated
  tool is in general off the last joint's axis, where a URDF child link must sit).

Several targets (reflectors): the tool frame stays the URDF's, at the flange
(:func:`calib.model.flange.flange_robot`), and each target is a fixed link ``tool_<id>`` under it
at its identified offset (``tool_kept`` in the record).

The output records its base and tool frames, and the nominal frames they stand for, in a
``<calib:frames>`` element (:mod:`calib.io.urdf.document`), which :func:`calib.load_robot`, ``evaluate``
and ``compensate`` use by default. Numbers are written with 12 significant digits
(:func:`format_number`, error < 1e-12 m / rad), and of the equivalent roll-pitch-yaw triples the
one nearest the input's (:func:`rpy_nearest`). Origins that do not change (to 1e-13 m / rad)
keep their original text.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import pinocchio as pin
from lxml import etree

from calib.errors import CalibError
from calib.io.fileio import atomic_write_text, check_not_input
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.io.urdf.reader import checked_nominal_poses, mdh_poses, robot_from_chain
from calib.io.urdf.document import (FRAMES_TAG, ROUND_TRIP_TOL, SIGNIFICANT_DIGITS, RecordedFrames,  # noqa: F401
                            UrdfDocument, format_number, rpy_nearest)
from calib.io.urdf.document import origin_attributes as _origin_attrib
from calib.io.urdf.document import target_link_name as _target_link_name
from calib.io.urdf.document import unique_name as _unique_name
from calib.model.spatial import inverse

__all__ = ["calibrated_urdf_text", "check_writable", "format_number", "rpy_nearest", "write_calibrated_urdf"]

#: Origins whose entries change by less than this (metres; rotation-matrix entries) are left as
#: written in the input file.
_UNCHANGED_TOL = 1e-13


# ====================================================================== public API
def write_calibrated_urdf(robot: RobotModel, path: str | Path, *, nominal: RobotModel | None = None,
                          estimated: Sequence[str] = (), T_meas_base: np.ndarray | None = None,
                          meas_covariance: np.ndarray | None = None, measurement_link: str | None = None,
                          orientation_measured: bool = True, nominal_flange: bool = False) -> RecordedFrames:
    """Write a copy of the URDF ``robot`` was read from whose kinematics are exactly ``robot``'s.

    Parameters
    ----------
    robot : the calibrated model; it must have been read from a URDF (it carries the parsed
        document, ``robot.source``; the input file is not read again).
    path : output file; written atomically; must not be the input URDF.
    nominal : the model derived from the input URDF, with the same parameter names, joints and
        base/tool frames as ``robot``. Default: the model derived from the URDF ``robot`` carries
        (``robot_from_chain(robot.source, robot.parallel_threshold)``; no file is read).
    estimated : the frames the calibration estimated from the data
        (:attr:`calib.CalibrationResult.estimated_frames`: "measurement->base", "flange->tool",
        "flange-><id>"), recorded as ``measurement_estimated`` / ``tool_estimated``; a calibrated
        input's record of its frames (same base / tool frame) is kept.
    T_meas_base : (4, 4) the measurement->base transform when ``robot`` holds the robot's base
        frame and the measurement frame is reported apart
        (:func:`calib.calibration.base_frame.robot_base_frame`): recorded in ``<calib:frames>``
        (``<calib:measurement>``, with ``meas_covariance`` (6, 6)); the base frame is then the
        robot's, not the instrument's (``measurement_estimated`` stays false).
    measurement_link : with ``T_meas_base``, the name of a link to add for the measurement frame:
        a new root link with a fixed joint ``<name>_to_<root>`` whose child is the URDF's root
        link (ROS: one tree, one root; robot_state_publisher then publishes the tracker frame
        as the parent of the robot). Must not be a link of the URDF already.
    orientation_measured : False when the calibration's rows measured no tool orientation
        (positions only, touch rows): recorded (``orientation_measured="false"``) so that a
        compensation with orientation targets can say the orientation is not calibrated.
    nominal_flange : several targets placed by the fit: the last link at the URDF's values, the
        difference in the targets (:func:`calib.model.flange.with_nominal_last_link`, the same
        poses); False: the model's own (a simulation's true robot). No effect without targets.

    Returns the frames the output records (:class:`calib.io.urdf.document.RecordedFrames`): in the output,
    Pinocchio's pose of ``tool_frame`` in ``base_frame`` is ``robot.T_meas_tool(q)`` (4x4,
    metres) for every configuration q (radians / metres), to 1e-12 m / rad. The base frame
    keeps its name; the tool frame too, except when it is the child link of the last joint: a
    link ``tool`` (or ``tool_calibrated``) is then added (see the module docstring).
    :func:`calib.load_robot` of the output uses these frames by default. Only the origins of the
    chain's joints and of at most one fixed joint on each side change; everything else of the
    input is kept.

    A model built in code (no URDF source, :meth:`calib.RobotModel.from_mdh`) is written as a
    minimal URDF of its kinematics (:func:`calib.io.urdf.minimal.minimal_urdf`).

    Raises :class:`~calib.errors.CalibError` (or a subclass): output = input, ``nominal`` incompatible with ``robot`` or not describing the URDF.
    """
    text, frames = calibrated_urdf_text(robot, nominal=nominal, estimated=estimated, T_meas_base=T_meas_base, _path=path,
                                        meas_covariance=meas_covariance, measurement_link=measurement_link,
                                        orientation_measured=orientation_measured, nominal_flange=nominal_flange)
    atomic_write_text(path, text)
    return frames


def calibrated_urdf_text(robot: RobotModel, *, nominal: RobotModel | None = None, estimated: Sequence[str] = (),
                         T_meas_base: np.ndarray | None = None, meas_covariance: np.ndarray | None = None,
                         measurement_link: str | None = None, orientation_measured: bool = True,
                         nominal_flange: bool = False, _path=...) -> tuple[str, RecordedFrames]:
    """(the text :func:`write_calibrated_urdf` writes, the frames it records), without a file
    (``calib calibrate`` stages its outputs in memory, then writes them as a set)."""
    from calib.checks import check_names, check_path
    from calib.model.robot import check_robot

    check_robot(robot)
    if nominal is not None:
        check_robot(nominal, "nominal")
    estimated = check_names(estimated, "estimated")
    if _path is not ...:       # (write_calibrated_urdf's output, checked in its turn)
        check_not_input(check_path(_path, "path"), [robot.urdf_path] if robot.urdf_path is not None else [])
    measurement = _check_measurement(T_meas_base, meas_covariance, measurement_link)
    for name, flag in (("orientation_measured", orientation_measured), ("nominal_flange", nominal_flange)):
        if not isinstance(flag, bool):
            raise CalibError(f"{name} must be True or False, got {flag!r}")
    if robot.source is None:      # a model built in code: a minimal URDF of its kinematics
        from calib.io.urdf.minimal import minimal_urdf

        if nominal is not None:
            check_compatible(robot, nominal)
            if nominal_flange and robot.targets:
                from calib.model.flange import with_nominal_last_link

                robot = with_nominal_last_link(robot, nominal.geometry())
        if measurement_link:
            raise CalibError("measurement_link needs a model read from a URDF (this one was built in code)")
        text, frames = minimal_urdf(robot, estimated=tuple(e for e in estimated if measurement is None
                                                           or e != "measurement->base"))
        if measurement is not None or not orientation_measured:
            frames = replace(frames, **(measurement or {}), orientation_measured=orientation_measured)
            text = _minimal_with_record(text, frames)
        return text, frames
    doc, plan = _prepare(robot, nominal, nominal_flange)
    estimated = tuple(estimated)
    f = plan.frames     # (a calibrated input's record kept: see _prepare)
    meas_estimated = f.measurement_estimated or "measurement->base" in estimated
    if measurement is not None:      # the base frame is the robot's; the instrument's is recorded
        meas_estimated = False
    # (the targets' frames are estimated, not the tool frame, which stays the URDF's)
    tool_estimated = "flange->tool" in estimated if robot.targets else \
        any(e.startswith("flange->") for e in estimated)
    plan = replace(plan, frames=replace(
        f, measurement_estimated=meas_estimated,
        tool_estimated=f.tool_estimated or tool_estimated,
        orientation_measured=orientation_measured,
        **(measurement or {"T_meas_base": (), "meas_covariance": (), "measurement_link": ""})))
    if measurement_link:
        plan = _plan_measurement_link(doc, plan, robot.base_frame, measurement_link)
    return doc.render(plan), plan.frames


def _check_measurement(T, cov, link) -> dict | None:
    """The RecordedFrames fields of a measurement->base transform (or None without one)."""
    if T is None:
        if cov is not None or link is not None:
            raise CalibError("meas_covariance and measurement_link need T_meas_base")
        return None
    try:
        T = np.array(T, float)
        cov = np.zeros((6, 6)) if cov is None else np.array(cov, float)
    except (TypeError, ValueError):
        raise CalibError("T_meas_base must be a (4, 4) transform and meas_covariance (6, 6)") from None
    if T.shape != (4, 4) or cov.shape != (6, 6) or not (np.isfinite(T).all() and np.isfinite(cov).all()) \
            or np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-9:
        raise CalibError("T_meas_base must be a finite (4, 4) rigid transform and meas_covariance (6, 6)")
    if link is not None and (not isinstance(link, str) or not link.strip() or any(c.isspace() for c in link)):
        raise CalibError(f"measurement link name must be a non-empty name without spaces, got {link!r}")
    return {"T_meas_base": tuple(T.reshape(-1).tolist()), "meas_covariance": tuple(cov.reshape(-1).tolist()),
            "measurement_link": link or ""}


def _minimal_with_record(text: str, frames: RecordedFrames) -> str:
    """A minimal URDF's text with its ``<calib:frames>`` element replaced by ``frames``'."""
    tree = etree.ElementTree(etree.fromstring(text.encode()))
    root = tree.getroot()
    old = root.find(FRAMES_TAG)
    new = frames.element()
    new.tail = old.tail
    root.replace(old, new)
    return _serialize(tree)


def _plan_measurement_link(doc: "_UrdfDocument", plan: "_Plan", base_frame: str, link: str) -> "_Plan":
    """``plan`` with a new root link ``link`` (the measurement frame) and a fixed joint to the
    URDF's root link at T_meas_root = T_meas_base . T_base_root (the base frame must sit on the
    root through fixed joints, whose origins the plan keeps)."""
    if link in doc.links:
        raise CalibError(f"{doc.path}: --measurement-link {link!r} is a link of the URDF already; "
                         f"choose a new name")
    root = doc.root_link
    base_link = doc.link_of(base_frame)
    T_root_base = np.eye(4)
    if base_link != root:
        path = doc.fixed_path(root, base_link)
        if not path:
            raise CalibError(f"{doc.path}: the base frame {base_link!r} is not fixed to the root link "
                             f"{root!r}: a measurement link above the root would move with joints")
        for j, down in path:
            O = _joint_origin(doc, j.name, plan)
            T_root_base = T_root_base @ (O if down else inverse(O))
    T = plan.frames.measurement_transform @ inverse(T_root_base)
    joint = _unique_name(f"{link}_to_{root}", set(doc.joints))
    return replace(plan, new_root=(link, joint, root, T))


def _joint_origin(doc, name: str, plan) -> np.ndarray:
    """(4, 4) origin of joint ``name`` in the output: the plan's, else the input's."""
    if name in plan.origins:
        return plan.origins[name]
    el = next(e for e in doc.tree.getroot().findall("joint") if e.get("name") == name)
    o = el.find("origin")
    xyz = _parse_triple(o.get("xyz")) if o is not None else None
    rpy = _parse_triple(o.get("rpy")) if o is not None else None
    T = np.eye(4)
    if xyz is not None:
        T[:3, 3] = xyz
    if rpy is not None:
        T[:3, :3] = pin.rpy.rpyToMatrix(*rpy)
    return T


def check_writable(robot: RobotModel) -> RecordedFrames:
    """Check, before a fit, that a calibration of ``robot`` (a model from :func:`calib.load_robot`)
    can be written into its URDF; returns the frames the output will record. Raises what
    :func:`write_calibrated_urdf` would raise for this URDF and these frames."""
    from calib.model.robot import check_robot

    if check_robot(robot).source is None:     # (a model built in code)
        from calib.io.urdf.minimal import minimal_urdf
        return minimal_urdf(robot)[1]
    return _prepare(robot, None)[1].frames


def _prepare(robot: RobotModel, nominal: RobotModel | None, nominal_flange: bool = False):
    from calib.checks import check_instance
    from calib.model.robot import check_robot

    check_robot(robot)
    check_instance(nominal, "nominal", RobotModel, "from calib.load_robot", allow_none=True)
    if robot.targets:      # the tool frame on the chain as one model, then a link per target
        return _prepare_targets(robot, nominal, nominal_flange)
    chain = robot.source      # the URDF as the loader parsed it: no file is read again
    if chain is None:
        raise CalibError("the robot model was not read from a URDF (it carries no URDF source): "
                         "there is no URDF to write calibrated kinematics into")
    if (chain.base_frame, chain.tool_frame) != (robot.base_frame, robot.tool_frame):
        raise CalibError(f"{chain.path}: the robot model's frames {robot.base_frame!r} -> "
                         f"{robot.tool_frame!r} are not those of the chain it was read with "
                         f"({chain.base_frame!r} -> {chain.tool_frame!r}); load it with these frames")
    if nominal is None:
        nominal = robot_from_chain(chain, robot.parallel_threshold, targets=False)
    check_compatible(robot, nominal)
    doc = _UrdfDocument(chain.document.path, chain.document.tree)
    return doc, _plan_edits(robot, nominal, chain, doc, checked_nominal_poses(nominal, chain))


# ====================================================================== checks
def check_compatible(robot: RobotModel, nominal: RobotModel) -> None:
    if nominal.names != robot.names:
        missing = [n for n in nominal.names if n not in robot.names]
        extra = [n for n in robot.names if n not in nominal.names]
        raise CalibError(
            "the nominal model and the calibrated model have different parameters "
            f"(only in the nominal model: {', '.join(missing) or 'none'}; only in the calibrated "
            f"model: {', '.join(extra) or 'none'}{'; same names in another order' if not (missing or extra) else ''}); "
            "load the nominal model with the same URDF, frames and parallel threshold")
    if nominal.joint_names != robot.joint_names:
        raise CalibError(f"the nominal model's joints {list(nominal.joint_names)} differ from the "
                         f"calibrated model's {list(robot.joint_names)}")
    for label, a, b in (("base", nominal.base_frame, robot.base_frame),
                        ("tool", nominal.tool_frame, robot.tool_frame)):
        if a != b:
            raise CalibError(f"the nominal model's {label} frame {a!r} differs from the calibrated "
                             f"model's {b!r}")


# ====================================================================== the URDF document
class _UrdfDocument(UrdfDocument):
    """The shared URDF document (:class:`calib.io.urdf.document.UrdfDocument`) with the writer's render."""

    def render(self, plan: "_Plan") -> str:
        """The output document as text: ``plan`` applied to a copy of the input tree."""
        tree = copy.deepcopy(self.tree)   # keeps the comments around the root element too
        root = tree.getroot()
        indent = _child_indent(root)
        unit = indent.lstrip("\n") or "  "
        by_name = {el.get("name"): el for el in root.findall("joint")}
        for name, T in plan.origins.items():
            _set_origin(by_name[name], T, indent + unit)
        new = [(link, joint, parent, link, T) for link, joint, parent, T in plan.new_links]
        if plan.new_root is not None:      # (link, joint, child, T): the measurement frame's link
            link, joint, child, T = plan.new_root
            new.append((link, joint, link, child, T))
        for link, joint, parent, child, T in new:
            closing = root[-1].tail
            root[-1].tail = indent
            els = _new_fixed_link(link, joint, parent=parent, child=child, T=T, indent=indent, unit=unit)
            for el in els:
                root.append(el)
            els[-1].tail = closing
        for old in root.findall(FRAMES_TAG):       # a calibrated input: its record is replaced
            _remove_keeping_tail(old)
        frames = plan.frames.element()
        frames.tail = root.text if root.text is not None and not root.text.strip() else indent
        root.text = indent
        root.insert(0, frames)
        comment = etree.Comment(_sanitize_comment(plan.summary()))
        comment.tail = indent
        root.insert(0, comment)
        return _serialize(tree)


def _remove_keeping_tail(el: etree._Element) -> None:
    parent = el.getparent()
    prev = el.getprevious()
    if prev is not None:
        prev.tail = el.tail
    else:
        parent.text = el.tail
    parent.remove(el)


def _serialize(tree: etree._ElementTree) -> str:
    """The document as text with an XML declaration (UTF-8), its doctype, and the comments and
    processing instructions around the root element each on their own line."""
    root = tree.getroot()
    parts = ['<?xml version="1.0" encoding="utf-8"?>']
    if tree.docinfo.doctype:
        parts.append(tree.docinfo.doctype)
    parts += [etree.tostring(n, encoding="unicode") for n in reversed(list(root.itersiblings(preceding=True)))]
    parts.append(etree.tostring(root, encoding="unicode", with_tail=False))
    parts += [etree.tostring(n, encoding="unicode") for n in root.itersiblings()]
    return "\n".join(parts) + "\n"


def _child_indent(root: etree._Element) -> str:
    """The whitespace before the children of ``root`` ("\\n  " if none can be seen)."""
    if root.text is not None and root.text.strip() == "" and "\n" in root.text:
        return "\n" + root.text.rsplit("\n", 1)[1]
    return "\n  "


def _parse_triple(text: str | None) -> np.ndarray | None:
    try:
        v = np.array([float(t) for t in (text or "").split()])
    except ValueError:
        return None
    return v if v.shape == (3,) and np.all(np.isfinite(v)) else None


def _set_origin(joint: etree._Element, T: np.ndarray, indent: str) -> None:
    origin = joint.find("origin")
    reference = _parse_triple(origin.get("rpy")) if origin is not None else None
    attrib = _origin_attrib(T, reference)
    if origin is None:            # no <origin> (identity): add one after <child>
        origin = etree.Element("origin")
        child = joint.find("child")
        child.addnext(origin)
        origin.tail, child.tail = child.tail, indent
    origin.set("xyz", attrib["xyz"])
    origin.set("rpy", attrib["rpy"])


def _new_fixed_link(link: str, joint: str, *, parent: str, child: str, T: np.ndarray, indent: str,
                    unit: str) -> list[etree._Element]:
    """A new ``<link>`` (named ``link``) and a fixed ``<joint>`` from ``parent`` to ``child``."""
    link_el = etree.Element("link", name=link)
    link_el.tail = indent
    joint_el = etree.Element("joint", name=joint, type="fixed")
    joint_el.text = indent + unit
    for tag, attrib in (("parent", {"link": parent}), ("child", {"link": child}),
                        ("origin", _origin_attrib(T))):
        el = etree.SubElement(joint_el, tag, attrib)
        el.tail = indent + unit
    el.tail = indent
    joint_el.tail = indent
    return [link_el, joint_el]


def _sanitize_comment(text: str) -> str:
    while "--" in text:
        text = text.replace("--", "- -")
    return f" {text} "


# ====================================================================== the kinematics
@dataclass(frozen=True, eq=False, repr=False)     # (internal; a dict field: nothing compares or prints it)
class _Plan:
    """What to change in the document: new joint origins (joint name -> 4x4 ``T_parent_child``
    at q = 0), the tool link to add (with its fixed joint), and the frames to record."""

    source: str
    origins: dict
    frames: RecordedFrames
    new_tool: tuple | None = None      # (link, joint, parent link, T_parent_link)
    new_targets: tuple = ()            # the same for each new target link
    new_root: tuple | None = None      # (link, joint, child = the old root, T_link_child)

    @property
    def new_links(self) -> tuple:
        return ((self.new_tool,) if self.new_tool is not None else ()) + tuple(self.new_targets)

    def summary(self) -> str:
        parts = [f"Kinematics calibrated by calib from {self.source}.",
                 "Recomputed joint origins: " + (", ".join(self.origins) or "none") + "."]
        if self.new_tool is not None:
            parts.append(f"Added tool link {self.new_tool[0]!r} with fixed joint {self.new_tool[1]!r}.")
        if self.new_root is not None:
            parts.append(f"Added measurement-frame link {self.new_root[0]!r} (the new root) with fixed "
                         f"joint {self.new_root[1]!r} to {self.new_root[2]!r}.")
        if self.frames.targets:
            parts.append("Target links: " + ", ".join(f"{link!r} (target {t!r})" for t, link in self.frames.targets)
                         + ".")
        parts.append(f"Calibrated kinematics: tool frame {self.frames.tool_frame!r} in base frame "
                     f"{self.frames.base_frame!r} (recorded in calib:frames).")
        return " ".join(parts)


def _plan_edits(robot: RobotModel, nominal: RobotModel, chain, doc: _UrdfDocument, nom: dict) -> _Plan:
    """The new origins, from the nominal URDF poses and the two models' MDH frames at q = 0."""
    model = chain.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, chain.configuration(np.zeros(robot.n_joints)))
    body = {f.name: k for k, f in enumerate(model.frames) if f.type == pin.FrameType.BODY}
    oMb = data.oMf[chain.base_frame_id]

    def T_nom(link: str) -> np.ndarray:
        """Nominal pose of a URDF link in the meas (base) frame at q = 0."""
        return oMb.actInv(data.oMf[body[link]]).homogeneous

    cal = nom if robot is nominal else mdh_poses(robot)    # (check_writable: the nominal itself)
    base_link = doc.link_of(robot.base_frame)
    tool_link = doc.link_of(robot.tool_frame)
    chain_joints = [doc.joints[j.name] for j in robot.joints]
    origins: dict[str, np.ndarray] = {}
    new_tool = None

    # ---- base side: the robot base moves by K relative to the meas frame; a fixed joint
    # between the base frame and the first joint carries K, else the first joint's origin does
    K = robot.T_meas_base() @ inverse(nominal.T_meas_base())
    P1 = chain_joints[0].parent
    path = doc.fixed_path(base_link, P1)
    if path:
        j, down = path[0]
        O = inverse(T_nom(j.parent)) @ T_nom(j.child)
        origins[j.name] = K @ O if down else O @ inverse(K)
        W_P1 = K @ T_nom(P1)
    else:
        W_P1 = T_nom(P1)

    # ---- chain joints: each URDF link keeps its offset C_i from the MDH moving frame
    W_prev = None
    for i, j in enumerate(chain_joints):
        C = inverse(nom["X"][i]) @ T_nom(j.child)
        W_L = cal["X"][i] @ C
        if i == 0:
            W_P = W_P1
        else:   # P_i rides on L_{i-1} with its nominal offset
            W_P = W_prev @ inverse(T_nom(chain_joints[i - 1].child)) @ T_nom(j.parent)
        origins[j.name] = inverse(W_P) @ W_L
        W_prev = W_L
    W_Ln, Ln = W_prev, chain_joints[-1].child

    # ---- tool side; links between L_n and the tool ride on the MDH flange
    tool_cal = cal["tool"]
    flange_motion = cal["flange"] @ inverse(nom["flange"])   # in meas coordinates
    path = doc.fixed_path(Ln, tool_link)
    out_tool = tool_link
    if not path:
        out_tool = _unique_name("tool", set(doc.links))
        new_tool = (out_tool, _unique_name(f"{Ln}_to_{out_tool}", set(doc.joints)), Ln,
                    inverse(W_Ln) @ tool_cal)
    elif len(path) == 1:
        origins[path[0][0].name] = inverse(W_Ln) @ tool_cal
    else:
        first, last = path[0][0], path[-1][0]
        origins[first.name] = inverse(W_Ln) @ flange_motion @ T_nom(first.child)
        origins[last.name] = inverse(flange_motion @ T_nom(last.parent)) @ tool_cal

    # keep the text of origins that do not change
    for name in list(origins):
        j = doc.joints[name]
        if np.abs(origins[name] - inverse(T_nom(j.parent)) @ T_nom(j.child)).max() < _UNCHANGED_TOL:
            del origins[name]

    rec = doc.frames      # a calibrated input: its frames stand for the same nominal frames
    nominal_base, nominal_tool = robot.base_frame, robot.tool_frame
    # (and a frame an earlier calibration estimated from the data stays the instrument's / the
    # measured point's in a recalibration of that URDF)
    meas_estimated = tool_estimated = False
    if rec is not None and base_link == rec.base_frame:
        nominal_base, meas_estimated = rec.nominal_base_frame, rec.measurement_estimated
    if rec is not None and tool_link == rec.tool_frame:
        nominal_tool, tool_estimated = rec.nominal_tool_frame, rec.tool_estimated
    frames = RecordedFrames(base_frame=base_link, tool_frame=out_tool,
                            nominal_base_frame=nominal_base, nominal_tool_frame=nominal_tool,
                            source=(rec.source if rec is not None and rec.source else doc.path.name),
                            measurement_estimated=meas_estimated, tool_estimated=tool_estimated)
    return _Plan(source=doc.path.name, origins=origins, frames=frames, new_tool=new_tool)


def _prepare_targets(robot: RobotModel, nominal: RobotModel | None, nominal_flange: bool):
    """(document, plan) of a model of several targets: the tool frame of the URDF on the
    calibrated chain (:func:`calib.model.flange.flange_robot`, the nominal flange->tool of the
    URDF's tool frame), then a link per target (:func:`_plan_targets`)."""
    from calib.io.urdf.reader import recorded_targets
    from calib.model.flange import flange_robot, with_nominal_last_link

    chain = robot.source
    if chain is None:
        raise CalibError("the robot model was not read from a URDF (it carries no URDF source): "
                         "there is no URDF to write calibrated kinematics into")
    rec = chain.document.frames
    if rec is not None and not rec.tool_kept and recorded_targets(chain):
        raise CalibError(f"{chain.path}: written by an earlier version of calib, whose tool frame "
                         f"{rec.tool_frame!r} is the first target ({rec.targets[0][0]!r}), not the flange: "
                         f"calibrate from the nominal URDF ({rec.source or 'the one it was made from'})")
    if nominal is not None:
        check_compatible(robot, nominal)
    tool = robot_from_chain(chain, robot.parallel_threshold, targets=False)    # the URDF's tool frame
    geo = with_nominal_last_link(robot, tool) if nominal_flange else robot
    flange = flange_robot(geo, tool.T_flange_tool_ref)
    doc, plan = _prepare(flange, tool)
    return doc, _plan_targets(geo, doc, plan, flange.T_flange_tool())


def _plan_targets(robot: RobotModel, doc: _UrdfDocument, plan: _Plan, T_flange_tool: np.ndarray) -> _Plan:
    """The plan of the tool frame's model (``T_flange_tool`` (4, 4): the tool frame on the MDH
    flange) with one fixed link ``tool_<id>`` per target under the tool frame, at
    ``T_tool_target = T_flange_tool^-1 T_flange_tool(target)``. A calibrated input that has the
    link already (a fixed child of the tool frame) gets its origin changed instead."""
    tool = plan.frames.tool_frame
    origins = dict(plan.origins)
    taken_links = set(doc.links) | {link for link, *_ in plan.new_links}
    taken_joints = set(doc.joints) | {joint for _, joint, *_ in plan.new_links}
    new, recorded = [], []
    for k, target in enumerate(robot.targets):
        T = inverse(T_flange_tool) @ robot.T_flange_tool(k)
        wanted = _target_link_name(target)
        existing = doc.parent_joint.get(wanted)
        if existing is not None and existing.kind == "fixed" and existing.parent == tool:
            origins[existing.name] = T
            link = wanted
        else:
            link = _unique_name(wanted, taken_links)
            joint = _unique_name(f"{tool}_to_{link}", taken_joints)
            taken_links.add(link)
            taken_joints.add(joint)
            new.append((link, joint, tool, T))
        recorded.append((target, link))
    frames = replace(plan.frames, targets=tuple(recorded), tool_kept=True)
    return replace(plan, origins=origins, frames=frames, new_targets=tuple(new))
