"""Write a calibrated robot model back into its URDF.

:func:`write_calibrated_urdf` copies the URDF a :class:`~calib.robot.RobotModel` was read from
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
  q_i) Trans(z, d_i)`` (Pinocchio's ``oMi`` of :class:`calib.kinematics.ChainKinematics`). The
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
  frame is ``P_1`` itself and is the root link, a new root link ``meas`` (``meas_calibrated``
  if that name is taken) is added with a fixed joint to the old root that carries ``K``: the
  output's base frame is then that new link. Otherwise a :class:`~calib.errors.ChainError` is
  raised.
* Tool side: on the fixed path ``L_n -> F_1 -> ... -> F_k = tool``, with k >= 2 the first joint
  takes the change of the MDH flange frame relative to ``L_n`` (``F_1 .. F_{k-1}`` move with the
  flange) and the last the change of flange -> tool; with k = 1 that joint takes both; with
  k = 0 (the tool frame is ``L_n``) a link ``tool`` (``tool_calibrated`` if taken) is added with
  a fixed joint from ``L_n``: the output's tool frame is then that new link.

Origins that do not change (to 1e-13 m / rad) keep their original text.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from lxml import etree

from .errors import CalibError, ChainError, URDFError
from .fileio import atomic_write_text, check_not_input
from .kinematics import ChainKinematics
from .robot import RobotModel, chain_axes, load_robot, read_urdf_chain
from .spatial import inverse

__all__ = ["write_calibrated_urdf"]

#: Tolerance (metres, radians) for the check that a ``nominal`` model describes the URDF's joint
#: axes and tool frame. A model derived by :func:`calib.load_robot` matches to rounding (1e-15).
NOMINAL_MATCH_TOL = 1e-9

#: Origins whose entries change by less than this (metres; rotation-matrix entries) are left as
#: written in the input file.
_UNCHANGED_TOL = 1e-13


# ====================================================================== public API
def write_calibrated_urdf(robot: RobotModel, path: str | Path, *,
                          nominal: RobotModel | None = None) -> None:
    """Write a copy of ``robot.urdf_path`` whose kinematics are exactly ``robot``'s.

    Parameters
    ----------
    robot : the calibrated model; it must have been read from a URDF (``robot.urdf_path``).
    path : output file; written atomically; must not be the input URDF.
    nominal : the model derived from the input URDF, with the same parameter names, joints and
        base/tool frames as ``robot``. Default:
        ``load_robot(robot.urdf_path, robot.base_frame, robot.tool_frame,
        robot.parallel_threshold)``.

    In the output, Pinocchio's pose of the tool frame in the base frame is ``robot.T_meas_tool(q)``
    (4x4, metres) for every configuration q (radians / metres), to rounding. The base and tool
    frames keep their names (``robot.base_frame``, ``robot.tool_frame``) except where the writer
    has to add a frame (see the module docstring): a new root link ``meas`` (or
    ``meas_calibrated``) when the base frame is the root link and is the parent of the first
    joint, and a link ``tool`` (or ``tool_calibrated``) when the tool frame is the child link of
    the last joint. Only the origins of the chain's joints and of one fixed joint on each side
    change; everything else of the input is kept.

    Raises :class:`~calib.errors.CalibError` (or a subclass): no URDF to start from, output =
    input, ``nominal`` incompatible with ``robot`` or not describing the URDF, or a base frame
    that is neither the root nor separated from the first joint by a fixed joint.
    """
    if robot.urdf_path is None:
        raise CalibError("the robot model was not read from a URDF (urdf_path is None): there is no "
                         "URDF to write calibrated kinematics into")
    src = Path(robot.urdf_path)
    check_not_input(path, [src])
    if nominal is None:
        nominal = load_robot(src, robot.base_frame, robot.tool_frame, robot.parallel_threshold)
    _check_compatible(robot, nominal)

    doc = _UrdfDocument.read(src)
    chain = read_urdf_chain(src, robot.base_frame, robot.tool_frame)
    _check_nominal_matches_urdf(nominal, chain)
    plan = _plan_edits(robot, nominal, chain, doc)
    atomic_write_text(path, doc.render(plan))


# ====================================================================== checks
def _check_compatible(robot: RobotModel, nominal: RobotModel) -> None:
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


def _check_nominal_matches_urdf(nominal: RobotModel, chain) -> None:
    """The nominal MDH z axes must be the URDF joint axes, and the tool frames equal, at q = 0."""
    pts, dirs, T_meas_tool = chain_axes(chain)
    X = _mdh_poses(nominal)["X"]
    worst = 0.0
    for i, joint in enumerate(nominal.joints):
        z, o = X[i][:3, 2], X[i][:3, 3]
        err = float(np.linalg.norm(z - dirs[i]))
        if not joint.is_prismatic:
            w = o - pts[i]
            err = max(err, float(np.linalg.norm(w - (w @ dirs[i]) * dirs[i])))
        worst = max(worst, err)
        if err > NOMINAL_MATCH_TOL:
            raise CalibError(f"{chain.path}: the nominal model's axis of joint {joint.name!r} is "
                             f"{err:.3g} (m or rad) away from the URDF's; pass the model derived from "
                             f"this URDF (calib.load_robot) as nominal")
    T_nom = nominal.T_meas_tool(np.zeros(nominal.n_joints))
    err = max(float(np.abs(T_nom[:3, 3] - T_meas_tool[:3, 3]).max()),
              float(np.abs(T_nom[:3, :3] - T_meas_tool[:3, :3]).max()))
    if err > NOMINAL_MATCH_TOL:
        raise CalibError(f"{chain.path}: the nominal model's tool pose at q = 0 differs from the "
                         f"URDF's by {err:.3g} (m or rad); pass the model derived from this URDF "
                         f"(calib.load_robot) as nominal")


# ====================================================================== the URDF document
@dataclass(frozen=True)
class _Joint:
    name: str
    kind: str
    parent: str
    child: str


class _UrdfDocument:
    """The input URDF as an lxml tree (comments, namespaces and unknown tags kept) plus its
    joint tree. Edits go through :meth:`render`, which works on a copy."""

    def __init__(self, path: Path, tree: etree._ElementTree):
        self.path = path
        self.tree = tree
        root = tree.getroot()
        self.links = [el.get("name") for el in root.findall("link")]
        self.joints: dict[str, _Joint] = {}
        for el in root.findall("joint"):
            parent, child = el.find("parent"), el.find("child")
            self.joints[el.get("name")] = _Joint(el.get("name"), el.get("type"), parent.get("link"),
                                                 child.get("link"))
        self.parent_joint = {j.child: j for j in self.joints.values()}
        roots = [l for l in self.links if l not in self.parent_joint]
        self.root_link = roots[0]

    @classmethod
    def read(cls, path: Path) -> "_UrdfDocument":
        parser = etree.XMLParser(remove_blank_text=False, remove_comments=False,
                                 resolve_entities=False)
        try:
            tree = etree.parse(str(path), parser)
        except (OSError, etree.XMLSyntaxError) as exc:
            raise URDFError(path, f"cannot be parsed: {exc}") from None
        return cls(path, tree)

    def link_of_frame(self, name: str) -> str:
        """The link a frame name denotes: a link, or the child link of a joint of that name."""
        if name in self.links:
            return name
        return self.joints[name].child

    def fixed_path(self, start: str, end: str) -> list[tuple[_Joint, bool]]:
        """Joints on the tree path from link ``start`` to link ``end``, each with ``True`` when
        it is traversed from parent to child. All must be fixed (Pinocchio merged them)."""
        def up(link):
            out = []
            while link in self.parent_joint:
                j = self.parent_joint[link]
                out.append(j)
                link = j.parent
            return out
        up_s, up_e = up(start), up(end)
        ancestors_e = [end] + [j.parent for j in up_e]
        ancestors_s = [start] + [j.parent for j in up_s]
        common = next(l for l in ancestors_s if l in ancestors_e)
        path = [(j, False) for j in up_s[:ancestors_s.index(common)]]
        path += [(j, True) for j in reversed(up_e[:ancestors_e.index(common)])]
        for j, _ in path:
            if j.kind != "fixed":
                raise ChainError(self.path, f"joint {j.name!r} of type {j.kind!r} lies between links "
                                            f"{start!r} and {end!r} where a fixed joint was expected")
        return path

    def render(self, plan: "_Plan") -> str:
        """The output document as text: ``plan`` applied to a copy of the input tree."""
        tree = copy.deepcopy(self.tree)   # keeps the comments around the root element too
        root = tree.getroot()
        indent = _child_indent(root)
        unit = indent.lstrip("\n") or "  "
        by_name = {el.get("name"): el for el in root.findall("joint")}
        for name, T in plan.origins.items():
            _set_origin(by_name[name], T, indent + unit)
        if plan.new_root is not None:
            link, joint, T = plan.new_root
            pos = list(root).index(root.find("link"))
            for k, el in enumerate(_new_fixed_link(link, joint, parent=link, child=self.root_link,
                                                   T=T, indent=indent, unit=unit)):
                root.insert(pos + k, el)
        if plan.new_tool is not None:
            link, joint, parent, T = plan.new_tool
            closing = root[-1].tail
            root[-1].tail = indent
            els = _new_fixed_link(link, joint, parent=parent, child=link, T=T, indent=indent, unit=unit)
            for el in els:
                root.append(el)
            els[-1].tail = closing
        comment = etree.Comment(_sanitize_comment(plan.summary()))
        comment.tail = root.text if root.text is not None and not root.text.strip() else indent
        root.text = indent
        root.insert(0, comment)
        return _serialize(tree)


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


def _unique_name(wanted: str, taken) -> str:
    """``wanted``, or ``wanted_calibrated`` (``..._calibrated2``, ...) if that name is taken."""
    name, k = wanted, 1
    while name in taken:
        name = f"{wanted}_calibrated" if k == 1 else f"{wanted}_calibrated{k}"
        k += 1
    return name


def _child_indent(root: etree._Element) -> str:
    """The whitespace before the children of ``root`` ("\\n  " if none can be seen)."""
    if root.text is not None and root.text.strip() == "" and "\n" in root.text:
        return "\n" + root.text.rsplit("\n", 1)[1]
    return "\n  "


def _fmt(x: float) -> str:
    """Shortest text that reads back as the same float; rounding noise below 1e-15 is zero."""
    if abs(x) < 1e-15:
        return "0"
    return repr(float(x))


def _origin_attrib(T: np.ndarray) -> dict[str, str]:
    return {"xyz": " ".join(_fmt(v) for v in T[:3, 3]),
            "rpy": " ".join(_fmt(v) for v in pin.rpy.matrixToRpy(T[:3, :3]))}   # URDF's convention


def _set_origin(joint: etree._Element, T: np.ndarray, indent: str) -> None:
    origin = joint.find("origin")
    attrib = _origin_attrib(T)
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
def _mdh_poses(robot: RobotModel) -> dict:
    """MDH frames of a model at q = 0 in the meas frame: moving frames X_i (list of 4x4),
    the flange and the tool (4x4)."""
    kin = ChainKinematics(robot)
    pin.forwardKinematics(kin.model, kin.data, np.zeros(kin.model.nq))
    pin.updateFramePlacements(kin.model, kin.data)
    X = [kin.data.oMi[i].homogeneous for i in range(1, robot.n_joints + 1)]
    return {"X": X, "flange": kin.data.oMf[kin.flange_frame_id].homogeneous,
            "tool": kin.data.oMf[kin.tool_frame_id].homogeneous,
            "base": kin.data.oMf[kin.base_frame_id].homogeneous}


@dataclass(frozen=True)
class _Plan:
    """What to change in the document: new joint origins (joint name -> 4x4 ``T_parent_child``
    at q = 0) and the links to add (with their fixed joints)."""

    source: str
    origins: dict
    new_root: tuple | None = None      # (link, joint, T_link_oldroot)
    new_tool: tuple | None = None      # (link, joint, parent link, T_parent_link)

    def summary(self) -> str:
        parts = [f"Kinematics calibrated by calib from {self.source}.",
                 "Recomputed joint origins: " + (", ".join(self.origins) or "none") + "."]
        if self.new_root is not None:
            parts.append(f"Added root link {self.new_root[0]!r} (the measurement frame) "
                         f"with fixed joint {self.new_root[1]!r}.")
        if self.new_tool is not None:
            parts.append(f"Added tool link {self.new_tool[0]!r} with fixed joint {self.new_tool[1]!r}.")
        return " ".join(parts)


def _plan_edits(robot: RobotModel, nominal: RobotModel, chain, doc: _UrdfDocument) -> _Plan:
    """The new origins, from the nominal URDF poses and the two models' MDH frames at q = 0."""
    model = chain.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, chain.configuration(np.zeros(robot.n_joints)))
    body = {f.name: k for k, f in enumerate(model.frames) if f.type == pin.FrameType.BODY}
    oMb = data.oMf[chain.base_frame_id]

    def T_nom(link: str) -> np.ndarray:
        """Nominal pose of a URDF link in the meas (base) frame at q = 0."""
        return oMb.actInv(data.oMf[body[link]]).homogeneous

    nom, cal = _mdh_poses(nominal), _mdh_poses(robot)
    base_link = doc.link_of_frame(robot.base_frame)
    tool_link = doc.link_of_frame(robot.tool_frame)
    chain_joints = [doc.joints[j.name] for j in robot.joints]
    origins: dict[str, np.ndarray] = {}
    new_root = new_tool = None

    # ---- base side: the robot base moves by K relative to the meas frame
    K = robot.T_meas_base() @ inverse(nominal.T_meas_base())
    P1 = chain_joints[0].parent
    path = doc.fixed_path(base_link, P1)
    if path:
        j, down = path[0]
        O = inverse(T_nom(j.parent)) @ T_nom(j.child)
        origins[j.name] = K @ O if down else O @ inverse(K)
    elif base_link == doc.root_link:
        link = _unique_name("meas", set(doc.links))
        new_root = (link, _unique_name(f"{link}_to_{base_link}", set(doc.joints)), K)
    else:
        raise ChainError(doc.path, f"base frame {robot.base_frame!r} is the parent link of the first "
                                   f"joint {chain_joints[0].name!r} and not the root link: there is "
                                   f"no fixed joint to carry the identified meas->base transform. "
                                   f"Use the root link as base frame, or add a fixed link between "
                                   f"{robot.base_frame!r} and the first joint")
    W_P1 = K @ T_nom(P1)

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
    if not path:
        link = _unique_name("tool", set(doc.links))
        new_tool = (link, _unique_name(f"{Ln}_to_{link}", set(doc.joints)), Ln, inverse(W_Ln) @ tool_cal)
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
    return _Plan(source=doc.path.name, origins=origins, new_root=new_root, new_tool=new_tool)
