"""A minimal URDF for a model built in code (:meth:`calib.RobotModel.from_mdh`, no URDF to start
from): one link per MDH frame, whose joint origins hold the model's kinematics exactly.

The chain, from the base frame (the meas frame, named ``robot.base_frame``) to the tool frame
(``robot.tool_frame``), all poses 4x4 in metres::

    meas --joint 1--> <joint1>_link --joint 2--> ... <jointn>_link --fixed--> tool

Joint i (revolute or prismatic about z of its child link, which is MDH moving frame i) has the
origin ``tail_{i-1} . Rot(z, theta_i) . Trans(z, d_i)``, with ``tail_0 = T_meas_base`` and
``tail_i = Trans(x, a_i) . Rot(x, alpha_i) . Rot(y, beta_i)`` the rest of the link transform of
Eq. (1) (theta_i + q_i and d_i + q_i split because rotations and translations along one axis
commute); the tool joint has ``tail_n . T_flange_tool``. A multi-target model, which keeps no
tool frame of its own beside its targets, gets the flange (MDH frame n) as its tool frame
(``tail_n``) and each target as a fixed link ``tool_<id>`` under it at ``T_flange_tool(k)``, as
:mod:`calib.io.urdf.writer` writes them (``tool_kept``). The
links have no geometry and no inertia (a model built in code has none), so such a URDF carries
kinematics only: :func:`calib.load_robot` of it gives back ``robot.T_meas_tool(q)``.

A revolute joint without limits (+-inf) is written ``continuous`` (URDF requires the limits of a
revolute joint); a prismatic joint needs finite limits.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from lxml import etree

from calib.errors import CalibError
from calib.io.urdf.document import RecordedFrames, origin_attributes, target_link_name, unique_name
from calib.model.robot import RobotModel
from calib.model.spatial import elementary

__all__ = ["minimal_urdf"]


def minimal_urdf(robot: RobotModel, *, estimated: tuple[str, ...] = (),
                 name: str = "calibrated") -> tuple[str, RecordedFrames]:
    """(URDF text, recorded frames) of a model with no URDF source (see the module docstring).

    estimated : the frames the calibration estimated (as for
    :func:`calib.io.urdf.writer.write_calibrated_urdf`). Raises :class:`CalibError` for a
    prismatic joint without finite limits.
    """
    geo = robot.geometry()
    table = geo.mdh_table()
    base, tool = geo.base_frame, geo.tool_frame
    taken = {base, tool} | set(geo.joint_names)
    root = etree.Element("robot", name=name)
    frames = RecordedFrames(base_frame=base, tool_frame=tool, nominal_base_frame=base,
                            nominal_tool_frame=tool, source="a model built in code",
                            measurement_estimated="measurement->base" in estimated,
                            tool_estimated=("flange->tool" in estimated if geo.targets else
                                            any(e.startswith("flange->") for e in estimated)),
                            tool_kept=bool(geo.targets))
    root.append(etree.Comment(" Kinematics of a model built in code, written by calib: links "
                              "without geometry or inertia (calib:frames records the frames). "))
    etree.SubElement(root, "link", name=base)

    def joint(jname: str, kind: str, parent: str, child: str, T: np.ndarray):
        el = etree.SubElement(root, "joint", name=jname, type=kind)
        etree.SubElement(el, "parent", link=parent)
        etree.SubElement(el, "child", link=child)
        etree.SubElement(el, "origin", origin_attributes(T))
        return el

    parent, tail = base, geo.T_meas_base()
    for i, j in enumerate(geo.joints):
        beta = 0.0 if np.isnan(table["beta"][i]) else table["beta"][i]
        limited = math.isfinite(j.lower) and math.isfinite(j.upper)
        if j.is_prismatic and not limited:
            raise CalibError(f"joint {j.name!r} is prismatic without finite limits: a URDF needs them "
                             f"(give the ChainJoint lower and upper limits)")
        kind = j.kind if limited or j.is_prismatic else "continuous"
        link = unique_name(f"{j.name}_link", taken)
        taken.add(link)
        el = joint(j.name, kind, parent, link,
                   tail @ elementary("rz", table["theta"][i]) @ elementary("tz", table["d"][i]))
        etree.SubElement(el, "axis", xyz="0 0 1")
        if kind != "continuous":
            etree.SubElement(el, "limit", lower=repr(float(j.lower)), upper=repr(float(j.upper)),
                             effort="0", velocity="0")
        etree.SubElement(root, "link", name=link)
        parent = link
        tail = (elementary("tx", table["a"][i]) @ elementary("rx", table["alpha"][i])
                @ elementary("ry", beta))
    etree.SubElement(root, "link", name=tool)
    tool_joint = unique_name(f"{tool}_joint", taken)
    taken.add(tool_joint)
    joint(tool_joint, "fixed", parent, tool, tail if geo.targets else tail @ geo.T_flange_tool(0))
    if geo.targets:
        recorded = []
        for k, target in enumerate(geo.targets):
            link = unique_name(target_link_name(target), taken)
            taken.add(link)
            etree.SubElement(root, "link", name=link)
            jname = unique_name(f"{tool}_to_{link}", taken)
            taken.add(jname)
            joint(jname, "fixed", tool, link, geo.T_flange_tool(k))
            recorded.append((target, link))
        frames = replace(frames, targets=tuple(recorded))
    root.insert(1, frames.element())
    text = etree.tostring(root, encoding="unicode", pretty_print=True)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + text, frames
