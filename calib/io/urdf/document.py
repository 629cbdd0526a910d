"""The one URDF document layer of calib: reading a URDF's tree and the frames a calibrated URDF
records, shared by the loader (:mod:`calib.model.robot`), the writer (:mod:`calib.io.urdf.writer`) and
compensation (:mod:`calib.compensation.compensate`).

The document is parsed with lxml (the parser yourdfpy uses), which keeps every element, comment
and namespace, so the writer can edit a copy without losing content; Pinocchio builds the
kinematic model from the same file. No other XML parser reads URDFs in calib.

Frames recorded in a calibrated URDF
------------------------------------
A calibrated URDF written by calib carries one extra top-level element in its own namespace::

    <calib:frames xmlns:calib="urn:calib:frames:1" base_frame="world" tool_frame="tool"
                  nominal_base_frame="world" nominal_tool_frame="wrist_3_link"
                  source="ur5.urdf"/>

``base_frame``/``tool_frame`` are the links of this file between which the calibrated
kinematics hold (the writer may have added a link ``tool``); ``nominal_base_frame`` and
``nominal_tool_frame`` the frames of the nominal URDF they stand for (the frames the measurements
and compensation targets are expressed in). A calibration of several targets (reflectors) keeps
the tool frame at the flange (``tool_kept="true"``: the nominal tool frame on the calibrated
chain, :mod:`calib.model.flange`) and adds one fixed link per target under it, at the target's
identified offset, recorded with its id::

    <calib:frames ... tool_frame="tool0" ... tool_kept="true">
      <calib:target id="A" link="tool_A"/>
      <calib:target id="B" link="tool_B"/>
    </calib:frames>

(URDFs written by calib before that put the tool frame at the first target and lack
``tool_kept``: their tool frame is a target, not the flange.)

The writers' shared pieces live here too: numbers written to 12 significant digits
(:func:`format_number`), the roll-pitch-yaw triple nearest a reference (:func:`rpy_nearest`),
``<origin>`` attributes, and the names of added links.

URDF consumers (urdfdom and so ROS, Pinocchio,
yourdfpy) read only ``link``, ``joint``, ``material``, ``transmission`` and ``gazebo``
elements and ignore a namespaced element, as they ignore ``xacro:`` leftovers.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from lxml import etree

from calib.errors import ChainError, URDFError

__all__ = ["FRAMES_NAMESPACE", "RecordedFrames", "UrdfDocument", "UrdfJoint"]

#: Namespace of the element that records a calibrated URDF's frames.
FRAMES_NAMESPACE = "urn:calib:frames:1"
FRAMES_TAG = f"{{{FRAMES_NAMESPACE}}}frames"
TARGET_TAG = f"{{{FRAMES_NAMESPACE}}}target"
MEASUREMENT_TAG = f"{{{FRAMES_NAMESPACE}}}measurement"


@dataclass(frozen=True, eq=False, repr=False)     # (the document's joints, by name: nothing compares or prints them)
class UrdfJoint:
    """A ``<joint>`` of a URDF: name, type, parent and child link, whether it has ``<mimic>``
    and ``<limit lower/upper>``."""

    name: str
    kind: str
    parent: str
    child: str
    mimic: bool = False
    has_limits: bool = False


@dataclass(frozen=True)
class RecordedFrames:
    """The frames a calibrated URDF records (see the module docstring); link names.

    targets : (id, link) of each target of a multi-target calibration, () otherwise.
    measurement_estimated, tool_estimated : whether the calibration estimated the measurement
    frame, or the tool (or target) frames, from the data because they were far from the nominal
    ones (attributes ``measurement_estimated="true"``, ``tool_estimated="true"``): the base
    frame is then the instrument's, the tool frame the measured point's, not the nominal ones.
    tool_kept : with targets, whether the tool frame is the nominal tool frame on the calibrated
    chain (the flange, attribute ``tool_kept="true"``), the targets fixed links under it; False
    in URDFs of several targets written by earlier versions, whose tool frame is the first target.
    orientation_measured : whether the calibration's rows measured the tool's orientation
    (attribute ``orientation_measured="false"`` when they did not: positions only, or touch
    rows): the tool orientation the model gives is then not calibrated (compensate says so).
    """

    base_frame: str
    tool_frame: str
    nominal_base_frame: str
    nominal_tool_frame: str
    source: str = ""
    targets: tuple[tuple[str, str], ...] = ()
    measurement_estimated: bool = False
    tool_estimated: bool = False
    orientation_measured: bool = True
    tool_kept: bool = False
    #: The measurement->base transform of a calibration that estimated the measurement frame
    #: and kept the URDF rooted at the robot's base: ``T_meas_base`` (4, 4) pose of ``base_frame``
    #: in the measurement frame as a 16-tuple (row-major, metres), its (6, 6) covariance as a
    #: 36-tuple (x, y, z m; rotation vector rad; in the meas frame), and the link added for the
    #: measurement frame (``--measurement-link``), or None / () / "" without.
    T_meas_base: tuple = ()
    meas_covariance: tuple = ()
    measurement_link: str = ""

    @property
    def measurement_transform(self):
        """(4, 4) T_meas_base recorded (see the attributes), or None."""
        return np.array(self.T_meas_base, float).reshape(4, 4) if self.T_meas_base else None

    @property
    def measurement_covariance(self):
        """(6, 6) covariance of the recorded T_meas_base, or None."""
        return np.array(self.meas_covariance, float).reshape(6, 6) if self.meas_covariance else None

    def _attributes(self) -> dict:
        out = {"base_frame": self.base_frame, "tool_frame": self.tool_frame,
               "nominal_base_frame": self.nominal_base_frame,
               "nominal_tool_frame": self.nominal_tool_frame, "source": self.source}
        for key in ("measurement_estimated", "tool_estimated", "tool_kept"):
            if getattr(self, key):
                out[key] = "true"
        if not self.orientation_measured:
            out["orientation_measured"] = "false"
        return out

    def to_dict(self) -> dict:
        out = self._attributes()
        if self.targets:
            out["targets"] = {t: link for t, link in self.targets}
        if self.T_meas_base:
            T = self.measurement_transform
            out["measurement"] = {"xyz": [float(x) for x in T[:3, 3]],
                                  "rpy": [float(x) for x in rpy_nearest(T[:3, :3])],
                                  "link": self.measurement_link or None}
        return out

    def element(self) -> etree._Element:
        """The ``<calib:frames>`` element (namespace declared on it)."""
        el = etree.Element(FRAMES_TAG, nsmap={"calib": FRAMES_NAMESPACE})
        for key, value in self._attributes().items():
            el.set(key, value)
        for target, link in self.targets:
            etree.SubElement(el, TARGET_TAG, {"id": target, "link": link})
        if self.T_meas_base:
            T = self.measurement_transform
            attrib = {"xyz": " ".join(format_number(x) for x in T[:3, 3]),
                      "rpy": " ".join(format_number(x) for x in rpy_nearest(T[:3, :3])),
                      "covariance": " ".join(repr(float(x)) for x in self.meas_covariance)}
            if self.measurement_link:
                attrib["link"] = self.measurement_link
            etree.SubElement(el, MEASUREMENT_TAG, attrib)
        return el


def _floats(text, count: int):
    """``count`` finite numbers from a space-separated attribute, else None."""
    try:
        v = [float(t) for t in (text or "").split()]
    except ValueError:
        return None
    return v if len(v) == count and all(math.isfinite(x) for x in v) else None


class UrdfDocument:
    """A URDF as an lxml tree (comments, namespaces and unknown tags kept) and its joint tree.

    Attributes: ``path``; ``tree`` (lxml ElementTree; do not modify, copy it); ``links`` (names
    in file order); ``joints`` (name -> :class:`UrdfJoint`, file order); ``root_link``;
    ``frames`` (:class:`RecordedFrames` of a calibrated URDF, or None).
    """

    def __init__(self, path: Path, tree: etree._ElementTree):
        self.path = path
        self.tree = tree
        root = tree.getroot()
        if root.tag != "robot":
            raise URDFError(path, f"root element is <{root.tag}>, expected <robot>")
        self.links = [el.get("name") for el in root.findall("link")]
        if not self.links:
            raise URDFError(path, "has no <link> element")
        self.joints: dict[str, UrdfJoint] = {}
        for el in root.findall("joint"):
            name, kind = el.get("name"), el.get("type")
            parent, child = el.find("parent"), el.find("child")
            if name is None or kind is None or parent is None or child is None:
                raise URDFError(path, f"joint {name!r} lacks a name, type, <parent> or <child>")
            lim = el.find("limit")
            self._check_numbers(el, name, kind)
            self.joints[name] = UrdfJoint(
                name, kind, parent.get("link"), child.get("link"), el.find("mimic") is not None,
                lim is not None and (lim.get("lower") is not None or lim.get("upper") is not None))
        self.parent_joint = {j.child: j for j in self.joints.values()}
        roots = [l for l in self.links if l not in self.parent_joint]
        if len(roots) != 1:
            raise URDFError(path, f"expected one root link, found {len(roots)}: {roots}")
        self.root_link = roots[0]
        self.frames = self._read_frames(root)

    def _check_numbers(self, el, name: str, kind: str) -> None:
        """The joint's origin, axis and limits are finite numbers; a moving joint's axis is not
        zero; lower <= upper. (Pinocchio would build a model of NaN or fail with a message that
        does not name the joint.)"""
        def numbers(child: str, attr: str, count: int):
            sub = el.find(child)
            text = None if sub is None else sub.get(attr)
            if text is None:
                return None
            try:
                values = [float(v) for v in text.split()]
            except ValueError:
                values = []
            if len(values) != count or not all(math.isfinite(v) for v in values):
                what = f"{count} finite numbers" if count > 1 else "a finite number"
                raise URDFError(self.path, f'joint {name!r}: <{child} {attr}="{text}"> is not {what}')
            return values
        numbers("origin", "xyz", 3)
        numbers("origin", "rpy", 3)
        axis = numbers("axis", "xyz", 3)
        if kind in ("revolute", "continuous", "prismatic") and axis is not None \
                and math.hypot(*axis) < 1e-9:
            raise URDFError(self.path, f"joint {name!r}: <axis xyz=\"{el.find('axis').get('xyz')}\"> is a "
                                       f"zero vector, expected the direction of the joint axis")
        lower, upper = numbers("limit", "lower", 1), numbers("limit", "upper", 1)
        if kind in ("revolute", "prismatic") and lower is not None and upper is not None \
                and lower[0] > upper[0]:
            raise URDFError(self.path, f"joint {name!r}: <limit lower=\"{lower[0]:g}\" upper=\"{upper[0]:g}\">"
                                       f" has lower > upper")

    def __reduce__(self):
        """Pickled as its path and XML text (an lxml tree cannot be pickled), so that a model
        carrying its document can go to another process."""
        return _document_from_text, (type(self), self.path, etree.tostring(self.tree))

    @classmethod
    def read(cls, path: str | Path) -> "UrdfDocument":
        """Parse a URDF file; :class:`URDFError` naming the file (and line) if it cannot be."""
        path = Path(path)
        if not path.exists():
            raise URDFError(path, "file not found")
        if path.is_dir():
            raise URDFError(path, "is a directory, expected a URDF file")
        parser = etree.XMLParser(remove_blank_text=False, remove_comments=False,
                                 resolve_entities=False)
        try:
            tree = etree.parse(str(path), parser)
        except etree.XMLSyntaxError as exc:
            line, col = exc.position
            raise URDFError(path, f"malformed XML at line {line}, column {col}: "
                                  f"{exc.msg.split(',')[0]}") from None
        except OSError as exc:
            raise URDFError(path, f"cannot be read: {exc}") from None
        return cls(path, tree)

    def _read_frames(self, root) -> RecordedFrames | None:
        el = root.find(FRAMES_TAG)
        if el is None:
            return None
        keys = ("base_frame", "tool_frame", "nominal_base_frame", "nominal_tool_frame")
        missing = [k for k in keys if not el.get(k)]
        if missing:
            raise URDFError(self.path, f"<calib:frames> lacks the attribute(s) {', '.join(missing)}")
        for k in ("base_frame", "tool_frame"):
            if el.get(k) not in self.links:
                raise URDFError(self.path, f"<calib:frames> {k}={el.get(k)!r} is not a link of "
                                           f"this file")
        targets = tuple((t.get("id"), t.get("link")) for t in el.findall(TARGET_TAG))
        for target, link in targets:
            if not target or link not in self.links:
                raise URDFError(self.path, f"<calib:target id={target!r} link={link!r}>: expected an id "
                                           f"and a link of this file")
        flags = {}
        for k in ("measurement_estimated", "tool_estimated", "tool_kept"):
            if el.get(k, "false") not in ("true", "false"):
                raise URDFError(self.path, f"<calib:frames> {k}={el.get(k)!r}: expected true or false")
            flags[k] = el.get(k) == "true"
        if el.get("orientation_measured", "true") not in ("true", "false"):
            raise URDFError(self.path, f"<calib:frames> orientation_measured="
                                       f"{el.get('orientation_measured')!r}: expected true or false")
        flags["orientation_measured"] = el.get("orientation_measured", "true") == "true"
        meas = el.find(MEASUREMENT_TAG)
        if meas is not None:
            xyz, rpy = (_floats(meas.get(a), 3) for a in ("xyz", "rpy"))
            cov = _floats(meas.get("covariance"), 36)
            link = meas.get("link", "")
            if xyz is None or rpy is None or cov is None or (link and link not in self.links):
                raise URDFError(self.path, "<calib:measurement>: expected xyz (3 numbers, m), rpy (3, rad), "
                                           "covariance (36 numbers) and an optional link of this file")
            T = pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array(xyz)).homogeneous
            flags.update(T_meas_base=tuple(T.reshape(-1)), meas_covariance=tuple(cov),
                         measurement_link=link)
        return RecordedFrames(*(el.get(k) for k in keys), source=el.get("source", ""), targets=targets,
                              **flags)

    # ------------------------------------------------------------------ tree queries
    def link_of(self, frame: str) -> str:
        """The link a frame name denotes: a link, or the child link of a joint of that name
        (the name itself if it is neither)."""
        if frame in self.links:
            return frame
        if frame in self.joints:
            return self.joints[frame].child
        return frame

    def children(self, link: str) -> list[UrdfJoint]:
        """The joints whose parent is ``link``, in file order."""
        return [j for j in self.joints.values() if j.parent == link]

    def fixed_path(self, start: str, end: str) -> list[tuple[UrdfJoint, bool]]:
        """Joints on the tree path from link ``start`` to link ``end``, each with ``True`` when
        it is traversed from parent to child. All must be fixed (else :class:`ChainError`)."""
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

    def moving_joints_below(self, link: str) -> int:
        """The largest number of moving (non-fixed, non-mimic) joints on a path down from
        ``link``."""
        best = 0
        for j in self.children(link):
            n = self.moving_joints_below(j.child) + (j.kind != "fixed" and not j.mimic)
            best = max(best, n)
        return best

    # ------------------------------------------------------------------ frames of a calibrated URDF
    def resolve_frames(self, base_frame: str | None,
                       tool_frame: str | None) -> tuple[str | None, str | None]:
        """The frames to use in this file for requested ``base_frame``/``tool_frame``.

        In a calibrated URDF (one that records its frames), None means the recorded frame, and
        a request for the nominal frame a recorded frame stands for gives the recorded frame
        (``--tool-frame wrist_3_link`` gives the link ``tool`` the writer added under it).
        Elsewhere the requests are returned as given.
        """
        rec = self.frames
        if rec is None:
            return base_frame, tool_frame
        if base_frame is None or base_frame == rec.nominal_base_frame:
            base_frame = rec.base_frame
        if tool_frame is None or tool_frame == rec.nominal_tool_frame:
            tool_frame = rec.tool_frame
        return base_frame, tool_frame


def _document_from_text(cls: type, path: Path, text: bytes) -> UrdfDocument:
    """The document of a pickled :class:`UrdfDocument` (see its ``__reduce__``)."""
    parser = etree.XMLParser(remove_blank_text=False, remove_comments=False, resolve_entities=False)
    return cls(path, etree.ElementTree(etree.fromstring(text, parser)))


# ====================================================================== writing: numbers and names
#: Largest error (metres, radians) a written number may have (:func:`format_number`).
ROUND_TRIP_TOL = 1e-12

#: Significant digits of written numbers where they keep the error within ROUND_TRIP_TOL.
SIGNIFICANT_DIGITS = 12


def format_number(x: float) -> str:
    """``x`` as short text for a URDF: 12 significant digits (``0.117``, not
    ``0.11700000000000006``), or 12 decimals where 12 significant digits would be off by more
    than :data:`ROUND_TRIP_TOL` (values of 1 and more: angles near pi); values below 5e-13 are
    ``0``. The text reads back within 5e-13 of ``x`` (< 1e-12 m or rad)."""
    x = float(x)
    if abs(x) < 5e-13:
        return "0"
    text = f"{x:.{SIGNIFICANT_DIGITS}g}"
    if abs(float(text) - x) > 5e-13:
        text = f"{x:.12f}".rstrip("0").rstrip(".")
    return text


def rpy_nearest(R: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """(3,) URDF roll, pitch, yaw (radians; ``R = Rz(yaw) Ry(pitch) Rx(roll)``) of the rotation
    matrix ``R`` (3, 3), chosen among the equivalent triples (the two branches, each angle
    shifted by multiples of 2 pi) as the nearest to ``reference`` (3,) (default: zeros, i.e.
    Pinocchio's principal triple). At pitch = +-pi/2 (roll and yaw then act about one axis), the
    roll is taken from ``reference``.
    """
    ref = np.zeros(3) if reference is None else np.asarray(reference, float)
    r, p, y = pin.rpy.matrixToRpy(R)
    if abs(math.cos(p)) < 1e-9:           # gimbal lock: only yaw -/+ roll is defined
        s = math.copysign(1.0, p)
        p = s * math.pi / 2
        r = ref[0]
        Rr = R @ pin.rpy.rpyToMatrix(r, p, 0.0).T   # R = Rz(y) Ry(p) Rx(r), so Rr = Rz(y)
        y = math.atan2(Rr[1, 0], Rr[0, 0])
        cands = [np.array([r, p, y])]
    else:
        cands = [np.array([r, p, y]),
                 np.array([r + math.pi, math.pi - p if p > 0 else -math.pi - p, y + math.pi])]
    best, best_d = None, math.inf
    for c in cands:
        c = c + 2 * math.pi * np.round((ref - c) / (2 * math.pi))   # nearest 2 pi shift per angle
        d = float(np.abs(c - ref).sum())
        if d < best_d:
            best, best_d = c, d
    return best


def origin_attributes(T: np.ndarray, rpy_reference=None) -> dict[str, str]:
    """The ``xyz`` and ``rpy`` attributes (text) of an ``<origin>`` for the pose T (4, 4),
    metres; the rpy triple nearest ``rpy_reference`` (3,) (:func:`rpy_nearest`)."""
    return {"xyz": " ".join(format_number(v) for v in T[:3, 3]),
            "rpy": " ".join(format_number(v) for v in rpy_nearest(T[:3, :3], rpy_reference))}


def unique_name(wanted: str, taken) -> str:
    """``wanted``, or ``wanted_calibrated`` (``..._calibrated2``, ...) if that name is taken."""
    name, k = wanted, 1
    while name in taken:
        name = f"{wanted}_calibrated" if k == 1 else f"{wanted}_calibrated{k}"
        k += 1
    return name


def target_link_name(target: str) -> str:
    """``tool_<id>`` with characters other than letters, digits, ``_``, ``-`` and ``.`` as ``_``."""
    return "tool_" + re.sub(r"[^A-Za-z0-9_.-]", "_", target)
