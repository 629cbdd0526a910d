"""Reading a robot from a URDF: the serial chain between two frames, found with Pinocchio, and its
TM-MDH model (:func:`load_robot`).

The default tool frame follows the tree from the base frame past mobile-base wheels and heads
into the longest arm (:func:`_default_tool_frame`); a robot may also be named by its
example-robot-data name (:func:`robot_path`).
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin
from lxml import etree

from calib.checks import check_number, check_path
from calib.errors import CalibError, ChainError, FrameNotFound, ParameterError, URDFError
from calib.io.fileio import captured_c_output
from calib.memo import Memo
from calib.model.mdh import PARALLEL_THRESHOLD_RAD, derive_mdh
from calib.io.urdf.document import UrdfDocument, UrdfJoint
from calib.model.chain import JOINT_KINDS, ChainJoint
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.model.spatial import cross3

log = logging.getLogger(__name__)


# ====================================================================== URDF reading
@dataclass(frozen=True, repr=False)
class UrdfText:
    """A URDF made in memory from another robot description file, read as a URDF file is
    (:func:`read_urdf_chain`, :func:`calib.load_robot`, the exports): e.g. the URDF that
    ur_description's template builds from a UR kinematics YAML
    (:func:`calib.io.urdf.ur_description.ur_description`).

    path : the file it was made from: named in messages, the model's ``urdf_path``, an input
        that no output may overwrite; ``str()`` of a UrdfText is this path.
    text : the URDF (XML text).
    """

    path: Path
    text: str

    def __str__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"UrdfText(path={str(self.path)!r}, text=<{len(self.text)} characters>)"

    def document(self) -> UrdfDocument:
        """The text parsed as :meth:`UrdfDocument.read` parses a file (comments kept)."""
        parser = etree.XMLParser(remove_blank_text=False, remove_comments=False, resolve_entities=False)
        try:
            root = etree.fromstring(self.text.encode(), parser)
        except etree.XMLSyntaxError as exc:
            raise URDFError(self.path, f"the URDF made from it is malformed XML: {exc.msg}") from None
        return UrdfDocument(self.path, etree.ElementTree(root))


@dataclass(frozen=True, eq=False, repr=False)   # (Pinocchio's model, the XML tree: nothing compares or prints them)
class UrdfChain:
    """A serial chain found in a URDF, with the Pinocchio model of the whole file.

    ``model`` is Pinocchio's model of the URDF; ``joint_ids`` the Pinocchio ids of the chain's
    moving joints (base to tool); ``base_frame_id``/``tool_frame_id`` Pinocchio frame ids;
    ``document`` the URDF's XML document (:class:`calib.io.urdf.document.UrdfDocument`).
    """

    path: Path
    model: pin.Model
    joints: tuple[ChainJoint, ...]
    joint_ids: tuple[int, ...]
    base_frame: str
    tool_frame: str
    base_frame_id: int
    tool_frame_id: int
    document: UrdfDocument | None = None

    def __getstate__(self):
        """Pickled with its fields only: what is kept on it for reuse (the gravity models and
        their torque memos, :meth:`calib.model.compliance.GravityModel.from_chain`) stays behind."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @cached_property
    def link_masses(self) -> np.ndarray:
        """(n,) kg, read-only: the masses the URDF gives the chain's moving links (the model is
        never modified: computed once)."""
        m = np.array([self.model.inertias[j].mass for j in self.joint_ids], float)
        m.setflags(write=False)
        return m

    @cached_property
    def gravity_models(self) -> dict:
        """The gravity models made for this chain (payload and gravity -> model, with their torque
        caches: :mod:`calib.model.compliance`), kept with the chain so that they go with it."""
        return {}

    def configuration(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio configuration of the whole URDF model for chain joint values q (n,).

        Joints off the chain stay at their neutral value; continuous joints take (cos, sin).
        """
        qf = pin.neutral(self.model)
        for k, jid in enumerate(self.joint_ids):
            jm = self.model.joints[jid]
            if jm.nq == 2:
                qf[jm.idx_q], qf[jm.idx_q + 1] = math.cos(q[k]), math.sin(q[k])
            else:
                qf[jm.idx_q] = q[k]
        return qf

    def at_zero(self):
        """(data, oMb): Pinocchio's data of the model at the chain's zero configuration, its joint
        Jacobians and frame placements computed, and the base frame's placement there."""
        data = self.model.createData()
        pin.computeJointJacobians(self.model, data, self.configuration(np.zeros(len(self.joints))))
        pin.updateFramePlacements(self.model, data)
        return data, data.oMf[self.base_frame_id]

    def T_meas_tool(self, Q: np.ndarray) -> np.ndarray:
        """(N, 4, 4) pose of the tool frame in the base (meas) frame by Pinocchio, for Q (N, n)."""
        data = self.model.createData()
        out = np.empty((len(Q), 4, 4))
        for k, q in enumerate(np.atleast_2d(Q)):
            pin.framesForwardKinematics(self.model, data, self.configuration(q))
            out[k] = (data.oMf[self.base_frame_id].actInv(data.oMf[self.tool_frame_id])).homogeneous
        return out


def _moving(j: UrdfJoint) -> bool:
    return j.kind != "fixed" and not j.mimic


def _longest_moving(doc: UrdfDocument, j: UrdfJoint) -> int:
    """Moving joints on the longest path down from the parent of ``j`` through ``j``."""
    return _moving(j) + doc.moving_joints_below(j.child)


def _is_mechanism(doc: UrdfDocument, j: UrdfJoint) -> bool:
    """Whether anything moves (or mimics) in the branch that starts with joint ``j``."""
    return j.kind != "fixed" or j.mimic or any(_is_mechanism(doc, k) for k in doc.children(j.child))


def _default_tool_frame(doc: UrdfDocument, start: str) -> str:
    """The default tool frame: follow the tree down from link ``start``.

    At a link with one child, go on. At a link with several children, compare the branches by
    the moving joints on their longest path (mimic joints do not count):

    * nothing moves below: stop here;
    * other branches are mechanisms too (they move or mimic) and the longest branch has fewer
      moving joints than the chain already followed: an end effector (gripper fingers, a hand):
      stop here, at the last link before the branch;
    * one branch is the longest, and it has at least 2 moving joints or no other branch is a
      mechanism (a fixed sensor mount beside the next joint): go on into it (an arm past a
      mobile base's wheels, or past a head);
    * several branches are equally long with at least 2 moving joints (two arms of a humanoid)
      and the chain followed is shorter: :class:`ChainError` naming the candidates.
    """
    link, passed = start, 0
    while True:
        kids = doc.children(link)
        if not kids:
            return link
        if len(kids) == 1:
            passed += _moving(kids[0])
            link = kids[0].child
            continue
        counts = [_longest_moving(doc, j) for j in kids]
        best = max(counts)
        top = [j for j, c in zip(kids, counts) if c == best]
        others_move = [j for j, c in zip(kids, counts) if c < best and _is_mechanism(doc, j)]
        if best == 0 or ((others_move or len(top) > 1) and best < passed):
            return link
        if len(top) == 1 and (best >= 2 or not others_move):
            passed += _moving(top[0])
            link = top[0].child
            continue
        if len(top) > 1 and best >= 2:
            candidates = [_default_tool_frame(doc, j.child) for j in top]
            raise ChainError(doc.path, f"no default tool frame: the tree branches at link {link!r} "
                                       f"into {len(top)} arms of {best} moving joints; choose one "
                                       f"with --tool-frame (tool_frame=), e.g. "
                                       f"{', '.join(candidates)}")
        return link


def robot_path(robot: str | Path) -> Path:
    """The URDF file of ``robot``: a path, or a robot name example-robot-data knows (``ur5``,
    ``panda``, ``z1``, ...).

    A name is tried only when no file of that name exists and it has no folder or suffix; an
    unknown name raises :class:`URDFError` listing the known names.
    """
    path = check_path(robot, "robot")
    if path.exists() or path.suffix or len(path.parts) != 1:
        return path
    try:
        from example_robot_data.robots_loader import ROBOTS
        from example_robot_data.utils import getModelPath
    except ImportError:       # example-robot-data is a dependency, but may be broken
        return path
    name = str(robot)
    loader = ROBOTS.get(name)
    if loader is None or not getattr(loader, "urdf_filename", ""):
        known = sorted(k for k, v in ROBOTS.items() if getattr(v, "urdf_filename", ""))
        raise URDFError(path, f"file not found, and not a robot name example-robot-data knows "
                              f"({', '.join(known)})")
    sub = os.path.join(loader.path, loader.urdf_subpath, loader.urdf_filename)
    try:
        folder = loader.model_path or getModelPath(sub)
    except OSError as exc:
        raise URDFError(path, f"example-robot-data knows this robot but its URDF is missing: "
                              f"{exc}") from None
    return Path(os.path.normpath(os.path.join(folder, sub)))


#: Degrees of freedom of the whole URDF model beyond which it is refused: Pinocchio's workspace
#: grows with their square (a 1,000-joint chain took 18 GB and ended in a MemoryError); humanoids
#: and mobile manipulators have a few dozen.
MAX_MODEL_DOF = 256
#: Joint and link origins farther than this (metres) from their parent describe no robot: a
#: value such as 1e300 overflows the kinematics (a crash in the analysis, not an error message).
MAX_ORIGIN_M = 1e4


def _check_placements(path: Path, model) -> None:
    """Refuse a URDF whose joint or fixed-frame origins are not finite or farther than
    :data:`MAX_ORIGIN_M` from their parent, naming the joint."""
    placements = [(model.names[j], model.jointPlacements[j].translation) for j in range(1, model.njoints)]
    placements += [(f.name, f.placement.translation) for f in model.frames if f.type == pin.FrameType.FIXED_JOINT]
    for name, t in placements:
        if not (np.all(np.isfinite(t)) and np.max(np.abs(t)) <= MAX_ORIGIN_M):
            raise URDFError(path, f"joint {name!r}: origin xyz {' '.join(f'{v:g}' for v in t)} m is "
                                  f"more than {MAX_ORIGIN_M:g} m from its parent link along an axis: no robot is that "
                                  f"large (a unit or a typo in the URDF)")


def read_urdf_chain(urdf_path: str | Path | UrdfText, base_frame: str | None = None,
                    tool_frame: str | None = None, *,
                    document: UrdfDocument | None = None) -> UrdfChain:
    """Read a URDF and find the serial chain of moving joints between two of its frames.

    ``urdf_path`` is a file, a robot name of example-robot-data (:func:`robot_path`), or a
    :class:`UrdfText` (a URDF made in memory from another description file).
    ``base_frame`` defaults to the root link; ``tool_frame`` to the last link before the tree
    branches into an end effector (see :func:`_default_tool_frame`). A calibrated URDF written
    by calib records its frames, which are then the defaults (and requests for the nominal
    frames they stand for map to them; :meth:`calib.io.urdf.document.UrdfDocument.resolve_frames`). Frames
    may be link or joint names. Raises :class:`URDFError`, :class:`FrameNotFound` or
    :class:`ChainError`. ``document``: the file's document when the caller has already read it
    (it is then not read again).
    """
    text = urdf_path.text if isinstance(urdf_path, UrdfText) else None
    path = urdf_path.path if text is not None else robot_path(check_path(urdf_path, "urdf_path"))
    if text is None and path.suffix.lower() == ".xacro":
        raise URDFError(path, "is a xacro: expand it first, calib.expand_xacro(path, args={...}, packages={...}) "
                              "(the command line does it: --xacro-arg NAME:=VALUE, --package NAME=DIR)")
    for name, frame in (("base_frame", base_frame), ("tool_frame", tool_frame)):
        if frame is not None and not (isinstance(frame, str) and frame):
            raise ParameterError(f"{name} must be a frame name (a non-empty str) or None, got {frame!r}")
    if document is None:
        document = UrdfDocument.read(path) if text is None else urdf_path.document()
    doc = document
    model = _pinocchio_model(path, text)
    base_frame, tool_frame = doc.resolve_frames(base_frame, tool_frame)
    base_frame = base_frame or doc.root_link
    requested_tool = tool_frame
    frame_names = [f.name for f in model.frames]
    available = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
    if base_frame not in frame_names:
        raise FrameNotFound(base_frame, available, path)
    tool_frame = tool_frame or _default_tool_frame(doc, doc.link_of(base_frame))
    ids = {}
    for role, name in (("base", base_frame), ("tool", tool_frame)):
        if name not in frame_names:
            raise FrameNotFound(name, available, path)
        # prefer the body (link) frame when a joint of the same name exists
        cands = [k for k, f in enumerate(model.frames) if f.name == name]
        ids[role] = next((k for k in cands if model.frames[k].type == pin.FrameType.BODY), cands[0])
    chain = _chain_joint_ids(path, doc, model, ids, base_frame, tool_frame, requested_tool)
    cj = [_chain_joint(path, doc, model, jid, base_frame, tool_frame) for jid in chain]
    return UrdfChain(path=path, model=model, joints=tuple(cj), joint_ids=tuple(chain),
                     base_frame=base_frame, tool_frame=tool_frame,
                     base_frame_id=ids["base"], tool_frame_id=ids["tool"], document=doc)


def _pinocchio_model(path: Path, text: str | None):
    """Pinocchio's model of the URDF file ``path`` (or of the URDF ``text`` made from it),
    checked: its placements finite, at most MAX_MODEL_DOF moving degrees of freedom. The
    parser's own message, if it fails, as a :class:`URDFError`."""
    parser_output: list[str] = []
    try:
        with captured_c_output() as parser_output:   # Pinocchio's parser prints to C stderr
            model = pin.buildModelFromUrdf(str(path)) if text is None else pin.buildModelFromXML(text)
    except (RuntimeError, ValueError) as exc:
        said = [l.strip()[len("Error:"):].strip() for l in "".join(parser_output).splitlines()
                if l.strip().startswith("Error:")]
        msg = " ".join((said[0] if said else str(exc)).split())
        raise URDFError(path, f"Pinocchio cannot build a model: {msg}") from None
    if parser_output and parser_output[0].strip():
        log.debug("Pinocchio's URDF parser said: %s", " ".join(parser_output[0].split()))
    _check_placements(path, model)
    if model.nv > MAX_MODEL_DOF:
        raise URDFError(path, f"{model.nv} moving degrees of freedom: calib calibrates serial arms of up to "
                              f"{MAX_MODEL_DOF} (Pinocchio's workspace for this model alone would take "
                              f"gigabytes)")
    return model


def _chain_joint_ids(path: Path, doc: UrdfDocument, model, ids: dict, base_frame: str, tool_frame: str,
                     requested_tool: str | None) -> list[int]:
    """The Pinocchio ids of the moving joints from the base frame to the tool frame (``ids``: their
    frame ids), in chain order; :class:`ChainError` when they are not on one serial chain or no
    joint moves between them (naming end-effector tool frames to choose from)."""
    base_joint = model.frames[ids["base"]].parentJoint
    chain = []
    j = model.frames[ids["tool"]].parentJoint
    while j != base_joint:
        if j == 0:
            raise ChainError(path, f"base frame {base_frame!r} and tool frame {tool_frame!r} are not "
                                   f"on one serial chain: {base_frame!r} is not between the root "
                                   f"and {tool_frame!r}")
        chain.append(j)
        j = model.parents[j]
    chain.reverse()
    if not chain:
        hint = ""
        if requested_tool is None:
            stop = doc.link_of(tool_frame)
            cands = []
            for j in doc.children(stop):
                if _is_mechanism(doc, j):
                    try:
                        cands.append(_default_tool_frame(doc, j.child))
                    except ChainError:
                        pass
            hint = (f"; choose one with --tool-frame (tool_frame=), e.g. {', '.join(cands)}"
                    if cands else "")
        raise ChainError(path, f"no moving joint between base frame {base_frame!r} and tool frame "
                               f"{tool_frame!r}{hint}")
    return chain


def _chain_joint(path: Path, doc: UrdfDocument, model, jid: int, base_frame: str, tool_frame: str) -> ChainJoint:
    """The :class:`ChainJoint` of Pinocchio joint ``jid``: its kind and limits (none for a
    continuous joint or a URDF joint without limits); :class:`ChainError` for a mimic joint, an
    unsupported type or a joint that cannot move."""
    name = model.names[jid]
    rec = doc.joints.get(name)
    jtype = rec.kind if rec else model.joints[jid].shortname()
    if rec is not None and rec.mimic:
        raise ChainError(path, f"joint {name!r} between {base_frame!r} and {tool_frame!r} is a "
                               f"mimic joint: unsupported (it has no independent value)")
    if jtype not in JOINT_KINDS or model.joints[jid].nv != 1:
        raise ChainError(path, f"joint {name!r} between {base_frame!r} and {tool_frame!r} is of "
                               f"type {jtype!r}: unsupported (supported: revolute, continuous, "
                               f"prismatic)")
    if jtype == "continuous":
        lo, hi = -math.inf, math.inf
    else:
        jm = model.joints[jid]
        lo, hi = float(model.lowerPositionLimit[jm.idx_q]), float(model.upperPositionLimit[jm.idx_q])
        if rec is None or not rec.has_limits:
            lo, hi = -math.inf, math.inf
    if lo == hi:
        raise ChainError(path, f"joint {name!r} between {base_frame!r} and {tool_frame!r} has "
                               f"limits lower = upper = {lo:g}: it cannot move; make it a "
                               f"fixed joint or give it a range")
    return ChainJoint(name, jtype, lo, hi)


def chain_axes(chain: UrdfChain) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint axes of a URDF chain at q = 0, in the base (meas) frame.

    Returns (points (n, 3), directions (n, 3), T_meas_tool (4, 4)), from Pinocchio's joint
    Jacobians: a joint's twist gives its axis direction and, for a revolute joint, a point on it.
    """
    model = chain.model
    data, oMb = chain.at_zero()
    pts, dirs = [], []
    for jid, joint in zip(chain.joint_ids, chain.joints):
        col = pin.getJointJacobian(model, data, jid, pin.WORLD)[:, model.joints[jid].idx_v]
        v, w = col[:3], col[3:]
        if joint.is_prismatic:
            direction, point = v, data.oMi[jid].translation
        else:
            direction, point = w, cross3(w, v) / (w @ w)
        pts.append(oMb.actInv(point))
        dirs.append(oMb.rotation.T @ direction / np.linalg.norm(direction))
    T_meas_tool = oMb.actInv(data.oMf[chain.tool_frame_id]).homogeneous
    return np.array(pts), np.array(dirs), T_meas_tool


def load_robot(urdf_path: str | Path | UrdfText, base_frame: str | None = None, tool_frame: str | None = None,
               parallel_threshold: float = PARALLEL_THRESHOLD_RAD) -> RobotModel:
    """Load a serial arm from a URDF and derive its TM-MDH model.

    Parameters
    ----------
    urdf_path : the URDF file (or a robot name of example-robot-data, or a :class:`UrdfText`).
    base_frame : URDF frame (link) that plays the measurement frame; default: the root link.
    tool_frame : URDF frame (link) whose pose is measured; default: the last link before the
        tree branches (``tool`` for the bundled robot).
    parallel_threshold : radians; see :data:`calib.model.mdh.PARALLEL_THRESHOLD_RAD`.

    The model reproduces Pinocchio's forward kinematics of ``tool_frame`` in ``base_frame``
    exactly (to rounding), and carries what was parsed (``robot.source``, the :class:`UrdfChain`:
    the document and Pinocchio model), which the writer, compliance and messages use: the file
    is read and built once. Raises :class:`calib.CalibError` subclasses on bad input.
    """
    check_number(parallel_threshold, "parallel_threshold", minimum=0.0, maximum=math.pi / 2)
    return robot_from_chain(read_urdf_chain(urdf_path, base_frame, tool_frame), parallel_threshold)


#: (chain, model, model with the recorded targets) of the last :func:`robot_from_chain`, by the
#: chain and the parallel threshold: the writer derives the nominal model again from the chain the
#: loader read (check_writable, before a fit).
LAST_DERIVED = Memo("derived model", 1)


def robot_from_chain(chain: UrdfChain, parallel_threshold: float = PARALLEL_THRESHOLD_RAD, *,
                     targets: bool = True) -> RobotModel:
    """The TM-MDH model of a chain already read (:func:`read_urdf_chain`), carrying it as its
    ``source``: no file is read and nothing is rebuilt. See :func:`load_robot`. (The model of the
    last chain is kept: both are immutable.)

    targets : for a calibrated URDF of several targets read with its recorded tool frame, the
    model of the targets (one flange->target transform per target link the URDF records under
    the tool frame; the default), or with False the model of the tool frame itself (the flange,
    what compensation aims at)."""
    key = (id(chain), parallel_threshold)
    hit = LAST_DERIVED.get(key)
    if hit is None or hit[0] is not chain:
        robot = _derived(chain, parallel_threshold)
        hit = LAST_DERIVED.put(key, (chain, robot, _with_recorded_targets(chain, robot)))
    return hit[2] if targets else hit[1]


def recorded_targets(chain: UrdfChain) -> tuple[tuple[str, str], ...]:
    """(id, link) of the targets a calibrated URDF records under the tool frame ``chain`` was read
    with (two or more), else ()."""
    rec = chain.document.frames if chain.document is not None else None
    if rec is not None and len(rec.targets) > 1 and chain.tool_frame == rec.tool_frame:
        return rec.targets
    return ()


def nominal_tool_model(robot: RobotModel) -> RobotModel:
    """The nominal model of the tool frame ``robot`` stands for, without targets: for a model
    read from a URDF, the URDF's tool frame (:func:`robot_from_chain` with ``targets=False``;
    nothing is read); for a model built in code, which keeps no tool frame beside its targets,
    its chain with the flange (MDH frame n) as the tool frame
    (:func:`calib.model.flange.flange_robot`)."""
    if robot.source is None:
        from calib.model.flange import flange_robot

        return flange_robot(robot.geometry(), np.eye(4)) if robot.targets else robot
    return robot_from_chain(robot.source, robot.parallel_threshold, targets=False)


def _derived(chain: UrdfChain, parallel_threshold: float) -> RobotModel:
    pts, dirs, T_meas_tool = chain_axes(chain)
    geo = derive_mdh(pts, dirs, T_meas_tool, parallel_threshold)
    return RobotModel.from_mdh(
        chain.joints, geo.theta, geo.d, geo.a, geo.alpha,
        beta=np.where(geo.has_beta, geo.beta, np.nan),
        T_meas_base_ref=geo.T_meas_base_ref, T_flange_tool_ref=geo.T_flange_tool_ref,
        base_frame=chain.base_frame, tool_frame=chain.tool_frame, source=chain,
        parallel_threshold=parallel_threshold)


def _with_recorded_targets(chain: UrdfChain, robot: RobotModel) -> RobotModel:
    """``robot`` (the tool frame's model) with the targets the URDF records under its tool frame:
    one fixed link per target."""
    targets = recorded_targets(chain)
    if not targets:
        return robot
    data = chain.model.createData()
    pin.framesForwardKinematics(chain.model, data, chain.configuration(np.zeros(len(chain.joints))))
    oMt = data.oMf[chain.tool_frame_id]
    body = {f.name: k for k, f in enumerate(chain.model.frames) if f.type == pin.FrameType.BODY}
    refs = [robot.T_flange_tool_ref @ oMt.actInv(data.oMf[body[link]]).homogeneous for _, link in targets]
    return robot.with_targets([t for t, _ in targets], np.array(refs))


# ====================================================================== the nominal model against its URDF
#: Tolerance (metres, radians) for the check that a ``nominal`` model describes the URDF's joint
#: axes and tool frame. A model derived by :func:`calib.load_robot` matches to rounding (1e-15).
NOMINAL_MATCH_TOL = 1e-9


def mdh_poses(robot: RobotModel) -> dict:
    """MDH frames of a model at q = 0 in the meas frame: moving frames X_i (list of 4x4),
    the flange and the tool (4x4)."""
    kin = ChainKinematics(robot)
    pin.forwardKinematics(kin.model, kin.data, np.zeros(kin.model.nq))
    pin.updateFramePlacements(kin.model, kin.data)
    X = [kin.data.oMi[i].homogeneous for i in range(1, robot.n_joints + 1)]
    return {"X": X, "flange": kin.data.oMf[kin.flange_frame_id].homogeneous,
            "tool": kin.data.oMf[kin.tool_frame_id].homogeneous,
            "base": kin.data.oMf[kin.base_frame_id].homogeneous}


#: (nominal model, chain, its MDH frames at q = 0) of the last nominal checked against its URDF:
#: the writer's check before a fit (check_writable) and its write after it ask it of the same model.
LAST_NOMINAL = Memo("checked nominal", 1)


def checked_nominal_poses(nominal: RobotModel, chain: UrdfChain) -> dict:
    """:func:`mdh_poses` of ``nominal`` (one Pinocchio model of it), checked against the URDF of
    ``chain`` (the writer's nominal: its MDH z axes are the URDF joint axes, its tool frame the
    URDF's, at q = 0); CalibError otherwise. The last model's are kept (the same objects: both
    are immutable)."""
    key = (id(nominal), id(chain))
    hit = LAST_NOMINAL.get(key)
    if hit is not None and hit[0] is nominal and hit[1] is chain:
        return hit[2]
    nom = mdh_poses(nominal)
    _check_nominal_matches_urdf(nominal, chain, nom)
    for T in nom["X"] + [nom["flange"], nom["tool"], nom["base"]]:
        T.setflags(write=False)        # (kept: read, never written)
    LAST_NOMINAL.put(key, (nominal, chain, nom))
    return nom


def _check_nominal_matches_urdf(nominal: RobotModel, chain, nom: dict) -> None:
    """The nominal MDH z axes (``nom``: its mdh_poses) must be the URDF joint axes, the tool frames equal, at q = 0."""
    pts, dirs, T_meas_tool = chain_axes(chain)
    worst = 0.0
    for i, joint in enumerate(nominal.joints):
        z, o = nom["X"][i][:3, 2], nom["X"][i][:3, 3]
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
