"""Universal Robots' ``ur_description`` template: a UR's kinematics YAML read
(:func:`read_ur_kinematics`) and the URDF that ``urdf/ur_macro.xacro`` builds from it
(:func:`ur_description_urdf`), which calib then reads as it reads any URDF
(:func:`ur_description` gives a :class:`calib.io.urdf.reader.UrdfText`, for
:func:`calib.load_robot` and the exports).

A kinematics YAML is what ``ur_robot_driver`` takes as ``kinematics_params_file``: the
published nominal ``config/<type>/default_kinematics.yaml`` of ur_description, or a robot's own
factory calibration, extracted from its controller by ``ur_calibration``
(``calibration_correction``, ``target_filename:=my_robot_calibration.yaml``)::

    kinematics:
      shoulder:  {x: 0, y: 0, z: 0.1625, roll: 0, pitch: 0, yaw: 0}
      upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: 0}
      forearm:   {...}
      wrist_1:   {...}
      wrist_2:   {...}
      wrist_3:   {...}
      hash: calib_12788084448423163542

The template, quoted from ``urdf/ur_macro.xacro`` of Universal_Robots_ROS2_Description 2.4.5
(the same lines in earlier versions and in ROS 1's universal_robot ur_description; links and
joints carry the prefix ``${tf_prefix}``, left out here)::

    <joint name="base_link-base_link_inertia" type="fixed">
      <parent link="base_link" />
      <child link="base_link_inertia" />
      <origin xyz="0 0 0" rpy="0 0 ${pi}" />
    </joint>
    <joint name="shoulder_pan_joint" type="revolute">
      <parent link="base_link_inertia" />
      <child link="shoulder_link" />
      <origin xyz="${shoulder_x} ${shoulder_y} ${shoulder_z}" rpy="${shoulder_roll} ${shoulder_pitch} ${shoulder_yaw}" />
      <axis xyz="0 0 1" />
      <limit lower="${shoulder_pan_lower_limit}" upper="${shoulder_pan_upper_limit}"
        effort="${shoulder_pan_effort_limit}" velocity="${shoulder_pan_velocity_limit}"/>
    </joint>
    (shoulder_lift_joint: shoulder_link -> upper_arm_link, ${upper_arm_x} ...;
     elbow_joint: upper_arm_link -> forearm_link, ${forearm_x} ...;
     wrist_1_joint: forearm_link -> wrist_1_link, ${wrist_1_x} ...;
     wrist_2_joint: wrist_1_link -> wrist_2_link, ${wrist_2_x} ...;
     wrist_3_joint: wrist_2_link -> wrist_3_link, ${wrist_3_x} ...; all with axis 0 0 1)
    <joint name="base_link-base_fixed_joint" type="fixed">
      <origin xyz="0 0 0" rpy="0 0 ${pi}"/>
      <parent link="base_link"/>
      <child link="base"/>
    </joint>
    <joint name="wrist_3-flange" type="fixed">
      <parent link="wrist_3_link" />
      <child link="flange" />
      <origin xyz="0 0 0" rpy="0 ${-pi/2.0} ${-pi/2.0}" />
    </joint>
    <joint name="flange-tool0" type="fixed">
      <!-- default toolframe - X+ left, Y+ up, Z+ front -->
      <origin xyz="0 0 0" rpy="${pi/2.0} 0 ${pi/2.0}"/>
      <parent link="flange"/>
      <child link="tool0"/>
    </joint>

with ``urdf/inc/ur_common.xacro`` (``read_model_data``) taking ``shoulder_x`` as
``${sec_kinematics['shoulder']['x']}`` and so on, the limits as
``${sec_limits['shoulder_pan_joint']['min_position']}`` ... from ``config/<type>/joint_limits.yaml``,
and ``kinematics_hash`` as ``${sec_kinematics['hash']}`` (the driver's ``hash_kinematics``).
wrist_3-flange and flange-tool0 together are the identity: tool0 is wrist_3_link. ``base``
(ROS-Industrial's, the controller's Base frame) is base_link turned pi about z.

The URDF built here has those links and joints, named as ur_description names them (no
``tf_prefix``), with the limits of :data:`JOINT_LIMITS` for the UR type, and no geometry or
inertia (kinematics only: the xacro's meshes and masses come from other files). Read by
:func:`calib.load_robot`, its base frame is base_link (the root) and its tool frame tool0.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from lxml import etree

from calib.checks import check_choice, check_path
from calib.choices import UR_TYPES
from dataclasses import dataclass
from calib.errors import CalibError, URDFError
from calib.io.urdf.reader import UrdfText

__all__ = ["UR_SEGMENTS", "UR_FIELDS", "UR_JOINTS", "UR_LINKS", "UR_FIXED_JOINTS", "JOINT_LIMITS",
           "UrKinematicsFile", "read_ur_kinematics", "ur_description_urdf", "ur_description",
           "is_ur_kinematics_path"]

#: The entries of ``kinematics``, in chain order (shoulder = the origin of shoulder_pan_joint, ...).
UR_SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
#: The numbers of each entry: metres, then radians (URDF ``rpy``: R = Rz(yaw) Ry(pitch) Rx(roll)).
UR_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
#: The template's revolute joints, one per entry of :data:`UR_SEGMENTS`.
UR_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint")
#: The links of the main chain: the parent of the first joint, then each joint's child.
UR_LINKS = ("base_link_inertia", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
            "wrist_2_link", "wrist_3_link")
#: The template's fixed joints (name, parent, child, rpy in rad; xyz 0 0 0), as quoted in the
#: module docstring.
UR_FIXED_JOINTS = (("base_link-base_link_inertia", "base_link", "base_link_inertia", (0.0, 0.0, math.pi)),
                   ("base_link-base_fixed_joint", "base_link", "base", (0.0, 0.0, math.pi)),
                   ("wrist_3-flange", "wrist_3_link", "flange", (0.0, -math.pi / 2.0, -math.pi / 2.0)),
                   ("flange-tool0", "flange", "tool0", (math.pi / 2.0, 0.0, math.pi / 2.0)))

# Joint limits: config/<type>/joint_limits.yaml of Universal_Robots_ROS2_Description (as stored
# at commits 352a35c (ur3), 8ef39b3 (ur3e, ur5, ur10, ur10e), 1c32d8f (ur5e), 8ecc89e (ur16e),
# 77bdad0 (ur20), 3e14e7a (ur30)): per joint, in UR_JOINTS order, (min_position, max_position,
# max_velocity) as written there in degrees (``!degrees``, which xacro turns into radians) and
# max_effort in N m. None: ``has_position_limits: false`` (ur3's wrist_3: a continuous joint).
_S, _E = (-360.0, 360.0), (-180.0, 180.0)      # shoulder / wrist joints, elbow_joint
_LIMITS_DEG = {
    "ur3": ((*_S, 180.0, 56.0), (*_S, 180.0, 56.0), (*_E, 180.0, 28.0), (*_S, 360.0, 12.0), (*_S, 360.0, 12.0),
            (None, None, 360.0, 12.0)),
    "ur3e": ((*_S, 180.0, 56.0), (*_S, 180.0, 56.0), (*_E, 180.0, 28.0), (*_S, 360.0, 12.0), (*_S, 360.0, 12.0),
             (*_S, 360.0, 12.0)),
    "ur5": ((*_S, 180.0, 150.0), (*_S, 180.0, 150.0), (*_E, 180.0, 150.0), (*_S, 180.0, 28.0), (*_S, 180.0, 28.0),
            (*_S, 180.0, 28.0)),
    "ur5e": ((*_S, 180.0, 150.0), (*_S, 180.0, 150.0), (*_E, 180.0, 150.0), (*_S, 180.0, 28.0), (*_S, 180.0, 28.0),
             (*_S, 180.0, 28.0)),
    "ur10": ((*_S, 120.0, 330.0), (*_S, 120.0, 330.0), (*_E, 180.0, 150.0), (*_S, 180.0, 56.0), (*_S, 180.0, 56.0),
             (*_S, 180.0, 56.0)),
    "ur10e": ((*_S, 120.0, 330.0), (*_S, 120.0, 330.0), (*_E, 180.0, 150.0), (*_S, 180.0, 56.0), (*_S, 180.0, 56.0),
              (*_S, 180.0, 56.0)),
    "ur16e": ((*_S, 120.0, 330.0), (*_S, 120.0, 330.0), (*_E, 180.0, 150.0), (*_S, 180.0, 54.0), (*_S, 180.0, 54.0),
              (*_S, 180.0, 54.0)),
    "ur20": ((*_S, 120.0, 738.0), (*_S, 120.0, 738.0), (*_E, 150.0, 433.0), (*_S, 210.0, 107.0), (*_S, 210.0, 107.0),
             (*_S, 210.0, 107.0)),
    "ur30": ((*_S, 120.0, 730.0), (*_S, 120.0, 730.0), (*_E, 150.0, 430.0), (*_S, 210.0, 100.0), (*_S, 210.0, 100.0),
             (*_S, 210.0, 100.0)),
}


def _radians(v):
    return None if v is None else math.radians(v)


#: type -> per joint (UR_JOINTS order) (lower rad or None, upper rad or None, velocity rad/s,
#: effort N m), from the published joint_limits.yaml (see the source comment above).
JOINT_LIMITS = {t: tuple((_radians(lo), _radians(hi), math.radians(vel), eff) for lo, hi, vel, eff in rows)
                for t, rows in _LIMITS_DEG.items()}


@dataclass(frozen=True, eq=False)
class UrKinematicsFile:
    """A UR kinematics YAML as read (:func:`read_ur_kinematics`).

    path : the file.
    origins : (6, 6) float, read-only: x, y, z (metres), roll, pitch, yaw (radians, URDF rpy) of
        the entries shoulder .. wrist_3 (:data:`UR_SEGMENTS` order).
    hash : ``kinematics.hash`` (the driver's ``hash_kinematics``), or None when the file has none.
    """

    path: Path
    origins: np.ndarray
    hash: str | None


def is_ur_kinematics_path(path) -> bool:
    """Whether ``path`` names a UR kinematics YAML rather than a URDF: by its suffix, ``.yaml``
    or ``.yml`` (any case)."""
    return isinstance(path, (str, Path)) and Path(path).suffix.lower() in (".yaml", ".yml")


def _yaml():
    try:
        import yaml
    except ImportError:        # a dependency (pyproject.toml), but may be missing from an environment
        raise CalibError("reading a UR kinematics YAML needs PyYAML: pip install pyyaml") from None
    return yaml


def _line(node, keys) -> int | None:
    """1-based line of the entry ``keys`` (a path of mapping keys) in the composed YAML ``node``,
    or of the deepest entry of that path that exists."""
    line = None
    for key in keys:
        if node is None or not hasattr(node, "value") or not isinstance(node.value, list):
            break
        found = None
        for item in node.value:
            if isinstance(item, tuple) and getattr(item[0], "value", None) == key:
                found = item
        if found is None:
            break
        line, node = found[0].start_mark.line + 1, found[1]
    return line


def read_ur_kinematics(path: str | Path) -> UrKinematicsFile:
    """Read a UR kinematics YAML (see the module docstring).

    Every entry shoulder .. wrist_3 must hold the six numbers x, y, z, roll, pitch, yaw (finite;
    YAML integers or floats); ``hash``, when present, a string or an integer; other keys are
    ignored, as the xacro ignores them. Raises :class:`calib.URDFError`, one line naming the file,
    the line and the entry (``kinematics.wrist_2.roll: expected a number, got 'abc'``).
    """
    path = check_path(path, "path")
    yaml = _yaml()
    if not path.is_file():
        raise URDFError(path, "is a directory, expected a UR kinematics YAML" if path.is_dir() else "file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise URDFError(path, "is not UTF-8 text: expected a UR kinematics YAML") from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise URDFError(path, f"not readable as YAML: {where}{' '.join(str(getattr(exc, 'problem', '') or exc).split())}") from None

    def fail(keys, reason):
        line = _line(root, keys)
        where = f"line {line}: " if line is not None else ""
        raise URDFError(path, f"{where}{'.'.join(keys)}: {reason}")

    kin = data.get("kinematics") if isinstance(data, dict) else None
    if not isinstance(kin, dict):
        fail(("kinematics",), "missing, or not a mapping: a UR kinematics YAML (ur_description's "
                              "config/<type>/default_kinematics.yaml, or ur_calibration's output) holds "
                              f"kinematics: {', '.join(UR_SEGMENTS)}, each with {', '.join(UR_FIELDS)}")
    origins = np.empty((6, 6))
    for i, seg in enumerate(UR_SEGMENTS):
        entry = kin.get(seg)
        if not isinstance(entry, dict):
            fail(("kinematics", seg), ("missing" if entry is None else f"expected a mapping, got {entry!r:.40}")
                 + f" (expected {', '.join(UR_FIELDS)})")
        for k, name in enumerate(UR_FIELDS):
            if name not in entry:
                fail(("kinematics", seg, name), f"missing ({'metres' if k < 3 else 'radians'})")
            v = entry[name]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                fail(("kinematics", seg, name), f"expected a number ({'metres' if k < 3 else 'radians'}), "
                                                f"got {v!r:.40}")
            if not math.isfinite(v):
                fail(("kinematics", seg, name), f"expected a finite number, got {v!r}")
            origins[i, k] = float(v)
    h = kin.get("hash")
    if h is not None and (isinstance(h, bool) or not isinstance(h, (str, int))):
        fail(("kinematics", "hash"), f"expected a text (calib_12788084448423163542), got {h!r:.40}")
    origins.setflags(write=False)
    return UrKinematicsFile(path=path, origins=origins, hash=None if h is None else str(h))


def _number(v: float) -> str:
    """A number as the URDF's text: full double precision (repr), so the file's values are kept
    exactly."""
    return repr(float(v))


def ur_description_urdf(kinematics: UrKinematicsFile, ur_type: str) -> str:
    """The URDF text ur_description's ``ur_macro.xacro`` makes from ``kinematics`` for a UR of
    type ``ur_type`` (one of :data:`calib.choices.UR_TYPES`): the links and joints quoted in the
    module docstring, the joint origins the file's numbers (exactly), the limits of
    :data:`JOINT_LIMITS`; no geometry or inertia."""
    check_choice(ur_type, "ur_type", UR_TYPES)
    origins = np.asarray(kinematics.origins, float)
    root = etree.Element("robot", name=ur_type)
    hash_text = f"; kinematics.hash {kinematics.hash}" if kinematics.hash is not None else ""
    root.append(etree.Comment(
        f" {ur_type} kinematics from {kinematics.path.name}{hash_text}, built by calib as ur_description's "
        f"urdf/ur_macro.xacro (2.4.5) builds it; kinematics only: no geometry, no inertia "))
    for link in ("base_link",) + UR_LINKS + ("base", "flange", "tool0"):
        etree.SubElement(root, "link", name=link)

    def joint(name, kind, parent, child, xyz, rpy):
        el = etree.SubElement(root, "joint", name=name, type=kind)
        etree.SubElement(el, "parent", link=parent)
        etree.SubElement(el, "child", link=child)
        etree.SubElement(el, "origin", xyz=" ".join(map(_number, xyz)), rpy=" ".join(map(_number, rpy)))
        return el

    fixed = {name: (parent, child, rpy) for name, parent, child, rpy in UR_FIXED_JOINTS}
    joint("base_link-base_link_inertia", "fixed", *fixed["base_link-base_link_inertia"][:2], (0, 0, 0),
          fixed["base_link-base_link_inertia"][2])
    for k, (name, (lower, upper, velocity, effort)) in enumerate(zip(UR_JOINTS, JOINT_LIMITS[ur_type])):
        kind = "continuous" if lower is None else "revolute"
        el = joint(name, kind, UR_LINKS[k], UR_LINKS[k + 1], origins[k, :3], origins[k, 3:])
        etree.SubElement(el, "axis", xyz="0 0 1")
        limit = {} if lower is None else {"lower": _number(lower), "upper": _number(upper)}
        etree.SubElement(el, "limit", **limit, effort=_number(effort), velocity=_number(velocity))
    for name in ("base_link-base_fixed_joint", "wrist_3-flange", "flange-tool0"):
        parent, child, rpy = fixed[name]
        joint(name, "fixed", parent, child, (0, 0, 0), rpy)
    text = etree.tostring(root, encoding="unicode", pretty_print=True)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + text


def ur_description(path: str | Path, ur_type: str) -> UrdfText:
    """The UR kinematics YAML ``path`` as the URDF ur_description builds from it for a UR of type
    ``ur_type`` (:func:`read_ur_kinematics`, :func:`ur_description_urdf`), for
    :func:`calib.load_robot`, :func:`calib.export_calibration` and the other readers of a URDF::

        robot = calib.load_robot(ur_description("my_robot_calibration.yaml", "ur5e"))

    Raises :class:`calib.URDFError` (the file, the line and the entry) for a file that is not
    one, :class:`calib.ParameterError` for an unknown type.
    """
    check_choice(ur_type, "ur_type", UR_TYPES)
    kinematics = read_ur_kinematics(path)
    return UrdfText(path=kinematics.path, text=ur_description_urdf(kinematics, ur_type))
