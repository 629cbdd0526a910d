"""The outside artefacts of the UR tests: the published kinematics of ur_description and the URDF
its ``urdf/ur_macro.xacro`` makes from them, built here from the xacro's own lines (quoted below),
independently of calib's reading of them (calib.io.urdf.ur_description, calib.io.exports.ur).

Source: Universal_Robots_ROS2_Description 2.4.5, ``urdf/ur_macro.xacro`` (the same lines in
earlier versions and in ROS 1's universal_robot ur_description; links and joints prefixed
``${tf_prefix}``, empty here)::

    <joint name="${tf_prefix}base_link-base_link_inertia" type="fixed">
      <parent link="${tf_prefix}base_link" />
      <child link="${tf_prefix}base_link_inertia" />
      <origin xyz="0 0 0" rpy="0 0 ${pi}" />
    </joint>
    <joint name="${tf_prefix}shoulder_pan_joint" type="revolute">
      <parent link="${tf_prefix}base_link_inertia" />
      <child link="${tf_prefix}shoulder_link" />
      <origin xyz="${shoulder_x} ${shoulder_y} ${shoulder_z}" rpy="${shoulder_roll} ${shoulder_pitch} ${shoulder_yaw}" />
      <axis xyz="0 0 1" />
    <joint name="${tf_prefix}shoulder_lift_joint" type="revolute">
      <parent link="${tf_prefix}shoulder_link" />
      <child link="${tf_prefix}upper_arm_link" />
      <origin xyz="${upper_arm_x} ${upper_arm_y} ${upper_arm_z}" rpy="${upper_arm_roll} ${upper_arm_pitch} ${upper_arm_yaw}" />
    <joint name="${tf_prefix}elbow_joint" type="revolute">
      <parent link="${tf_prefix}upper_arm_link" />
      <child link="${tf_prefix}forearm_link" />
      <origin xyz="${forearm_x} ${forearm_y} ${forearm_z}" rpy="${forearm_roll} ${forearm_pitch} ${forearm_yaw}" />
    <joint name="${tf_prefix}wrist_1_joint" type="revolute">
      <parent link="${tf_prefix}forearm_link" />
      <child link="${tf_prefix}wrist_1_link" />
      <origin xyz="${wrist_1_x} ${wrist_1_y} ${wrist_1_z}" rpy="${wrist_1_roll} ${wrist_1_pitch} ${wrist_1_yaw}" />
    <joint name="${tf_prefix}wrist_2_joint" type="revolute">
      <parent link="${tf_prefix}wrist_1_link" />
      <child link="${tf_prefix}wrist_2_link" />
      <origin xyz="${wrist_2_x} ${wrist_2_y} ${wrist_2_z}" rpy="${wrist_2_roll} ${wrist_2_pitch} ${wrist_2_yaw}" />
    <joint name="${tf_prefix}wrist_3_joint" type="${wrist_3_joint_type}">
      <parent link="${tf_prefix}wrist_2_link" />
      <child link="${tf_prefix}wrist_3_link" />
      <origin xyz="${wrist_3_x} ${wrist_3_y} ${wrist_3_z}" rpy="${wrist_3_roll} ${wrist_3_pitch} ${wrist_3_yaw}" />
      <axis xyz="0 0 1" />
    <joint name="${tf_prefix}base_link-base_fixed_joint" type="fixed">
      <origin xyz="0 0 0" rpy="0 0 ${pi}"/>
      <parent link="${tf_prefix}base_link"/>
      <child link="${tf_prefix}base"/>
    </joint>
    <joint name="${tf_prefix}wrist_3-flange" type="fixed">
      <parent link="${tf_prefix}wrist_3_link" />
      <child link="${tf_prefix}flange" />
      <origin xyz="0 0 0" rpy="0 ${-pi/2.0} ${-pi/2.0}" />
    </joint>
    <joint name="${tf_prefix}flange-tool0" type="fixed">
      <!-- default toolframe - X+ left, Y+ up, Z+ front -->
      <origin xyz="0 0 0" rpy="${pi/2.0} 0 ${pi/2.0}"/>
      <parent link="${tf_prefix}flange"/>
      <child link="${tf_prefix}tool0"/>
    </joint>

and ``urdf/inc/ur_common.xacro``: ``<xacro:property name="shoulder_x"
value="${sec_kinematics['shoulder']['x']}" .../>`` (``sec_kinematics`` the file's ``kinematics``).
xacro evaluates ``${pi}`` as Python's math.pi and substitutes the YAML's numbers as Python
writes them (repr), which is what :func:`xacro_urdf` does.

The published numbers: ``config/<type>/default_kinematics.yaml`` of the same release, read in
place from the vendor folder (``$CALIB_VENDOR_DIR/ur_description``, default
/work/shared/vendor) when it is there, else from tests/data/ur_default_kinematics_2.4.5.yaml,
which holds the same numbers (checked against the files when both are present).
"""
from __future__ import annotations

import math
import os
from functools import lru_cache
from pathlib import Path

import yaml

VENDOR_UR = Path(os.environ.get("CALIB_VENDOR_DIR", "/work/shared/vendor")) / "ur_description"
FIXTURE = Path(__file__).resolve().parent / "data" / "ur_default_kinematics_2.4.5.yaml"
#: The types whose published kinematics the fixture holds.
PUBLISHED_TYPES = ("ur5", "ur5e", "ur10", "ur10e")
SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint")
LINKS = ("base_link_inertia", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
         "wrist_2_link", "wrist_3_link")


def vendor_file(ur_type: str) -> Path:
    return VENDOR_UR / f"{ur_type}_default_kinematics.yaml"


@lru_cache(maxsize=None)
def _fixture() -> dict:
    return yaml.safe_load(FIXTURE.read_text())


def published_kinematics(ur_type: str) -> dict:
    """The ``kinematics`` mapping of the published default_kinematics.yaml of ``ur_type``: the
    vendor file when present, else the fixture."""
    path = vendor_file(ur_type)
    if path.is_file():
        return yaml.safe_load(path.read_text())["kinematics"]
    return _fixture()[ur_type]["kinematics"]


def published_file(ur_type: str, folder: Path) -> Path:
    """A file holding the published default_kinematics.yaml of ``ur_type``: the vendor file
    itself when present, else the fixture's numbers written into ``folder`` in its layout."""
    path = vendor_file(ur_type)
    if path.is_file():
        return path
    out = Path(folder) / f"{ur_type}_default_kinematics.yaml"
    out.write_text(yaml.safe_dump({"kinematics": _fixture()[ur_type]["kinematics"]}, sort_keys=False))
    return out


def xacro_urdf(kinematics: dict, *, name: str = "ur") -> str:
    """The kinematic skeleton ur_macro.xacro makes from ``kinematics`` (the YAML's mapping), by
    the lines quoted in the module docstring (joint limits: +-2 pi, which do not change the
    kinematics)."""
    pi = math.pi
    xml = [f'<robot name="{name}">'] + [f'<link name="{n}"/>' for n in ("base_link",) + LINKS
                                        + ("base", "flange", "tool0")]
    xml.append(f'<joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>'
               f'<child link="base_link_inertia"/><origin xyz="0 0 0" rpy="0 0 {pi!r}"/></joint>')
    for k, (seg, joint) in enumerate(zip(SEGMENTS, JOINTS)):
        e = kinematics[seg]
        xml.append(f'<joint name="{joint}" type="revolute"><parent link="{LINKS[k]}"/>'
                   f'<child link="{LINKS[k + 1]}"/>'
                   f'<origin xyz="{e["x"]!r} {e["y"]!r} {e["z"]!r}" rpy="{e["roll"]!r} {e["pitch"]!r} {e["yaw"]!r}"/>'
                   f'<axis xyz="0 0 1"/><limit lower="{-2 * pi!r}" upper="{2 * pi!r}" effort="1" velocity="1"/></joint>')
    xml.append(f'<joint name="base_link-base_fixed_joint" type="fixed"><origin xyz="0 0 0" rpy="0 0 {pi!r}"/>'
               f'<parent link="base_link"/><child link="base"/></joint>')
    xml.append(f'<joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/><child link="flange"/>'
               f'<origin xyz="0 0 0" rpy="0 {-pi / 2.0!r} {-pi / 2.0!r}"/></joint>')
    xml.append(f'<joint name="flange-tool0" type="fixed">'
               f'<origin xyz="0 0 0" rpy="{pi / 2.0!r} 0 {pi / 2.0!r}"/>'
               f'<parent link="flange"/><child link="tool0"/></joint>')
    return "".join(xml + ["</robot>"])
