"""The frame pose targets are written in, placed in the robot's base frame: a controller's own base
frame (``--convention``), or any link of the nominal URDF fixed to the base.

A robot program or a teach pendant gives tool poses in the controller's base frame, which need not
be the URDF's base link: ur_description places the UR controller's *Base* at ``base``, pi about z
from ``base_link``; ROS-Industrial's support packages name every controller's frame ``base``
(:class:`calib.io.csv.conventions.ControllerBase` quotes the published lines). :func:`targets_frame`
finds that frame in the nominal URDF (the link ``base`` when the URDF has it, else the vendor's
published placement from ``base_link``) and says in one line which frame it is.
"""
from __future__ import annotations

import math

import numpy as np

from dataclasses import dataclass
from calib.errors import CalibError, ChainError, FrameNotFound

__all__ = ["TargetsFrame", "targets_frame", "describe_transform"]


@dataclass(frozen=True, eq=False)
class TargetsFrame:
    """A frame of pose targets.

    T_base_frame : (4, 4) float, metres: the frame in the robot's base frame (the nominal model's
        ``base_frame``), read-only; the identity for the base frame itself.
    link : the URDF link that is the frame, or None (the base frame; a placement from the
        vendor's documentation with no link of its own).
    text : one line for the user: which frame, from where.
    """

    T_base_frame: np.ndarray
    link: str | None
    text: str


def describe_transform(T: np.ndarray) -> str:
    """A placement in words: "the same frame", or its rotation (angle in degrees about an axis,
    named x, y or z when it is one) and its offset in millimetres."""
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    angle = float(np.linalg.norm(rv))
    parts = []
    if angle > 1e-9:
        axis = rv / angle
        named = [n for n, e in zip("xyz", np.eye(3)) if abs(abs(axis @ e) - 1) < 1e-9]
        if named:
            sign = 1.0 if axis @ np.eye(3)["xyz".index(named[0])] > 0 else -1.0
            deg = sign * math.degrees(angle)
            about = f"about {named[0]}"
        else:
            deg = math.degrees(angle)
            about = "about (" + ", ".join(f"{v:.4g}" for v in axis) + ")"
        parts.append(f"rotated {deg:.6g} deg {about}")
    if np.linalg.norm(T[:3, 3]) > 1e-12:
        parts.append("offset (" + ", ".join(f"{v * 1e3:.6g}" for v in T[:3, 3]) + ") mm")
    return " and ".join(parts) if parts else "the same frame"


def _frame_in_base(nominal, link: str) -> np.ndarray | None:
    """(4, 4) T_base_link of a link (or joint) of the nominal URDF fixed to the base frame, None
    when the URDF has no such frame; ChainError when a moving joint lies between them."""
    chain = nominal.source
    model = chain.model
    name = chain.document.link_of(link) if chain.document is not None else link
    ids = [k for k, f in enumerate(model.frames) if f.name == name]
    if not ids:
        return None
    import pinocchio as pin

    k = next((i for i in ids if model.frames[i].type == pin.FrameType.BODY), ids[0])
    base = model.frames[chain.base_frame_id]
    frame = model.frames[k]
    if frame.parentJoint != base.parentJoint:
        raise ChainError(chain.path, f"frame {link!r} moves with joint {model.names[frame.parentJoint]!r} "
                                     f"relative to the base frame {chain.base_frame!r}: targets are given in a "
                                     f"frame fixed to the robot's base")
    return base.placement.actInv(frame.placement).homogeneous


def targets_frame(nominal, *, convention: str | None = None, link: str | None = None) -> TargetsFrame:
    """The frame of pose targets in the nominal model's base frame.

    nominal : the nominal model, read from its URDF (:func:`calib.load_robot`).
    link : a link (or joint) of that URDF fixed to its base frame: the targets' frame; or
    convention : a ``--convention`` name (:data:`calib.io.csv.conventions.CONVENTIONS`): that
        controller's base frame, the URDF's link ``base`` (ROS-Industrial's name for it) when the
        URDF has one, else the vendor's published placement from ``base_link``; refused
        (:class:`calib.CalibError`) when the vendor publishes none for every model (FANUC: the
        height of J2's zero plane) and the URDF has no ``base``.
    Neither: the base frame itself.
    """
    from calib.io.csv.conventions import CONVENTIONS

    if nominal.source is None:
        raise CalibError("the nominal model was not read from a URDF: it has no frames to give targets in")
    chain = nominal.source
    base = chain.base_frame
    if link is not None:
        T = _frame_in_base(nominal, link)
        if T is None:
            import pinocchio as pin

            raise FrameNotFound(link, [f.name for f in chain.model.frames if f.type == pin.FrameType.BODY],
                                chain.path)
        return _frame(T, link, f"targets in frame {link!r} of {chain.path.name} ({_relative(T, base)})")
    c = CONVENTIONS[convention].controller if convention is not None else None
    if c is None:
        return _frame(np.eye(4), None, f"targets in the base frame {base!r} of {chain.path.name}")
    T = _frame_in_base(nominal, c.link)
    if T is not None:
        return _frame(T, c.link, f"targets in {c.what} (--convention {convention}): link {c.link!r} of "
                                 f"{chain.path.name}, {_relative(T, base)}")
    T_parent = _frame_in_base(nominal, c.parent)
    if c.rpy is None or T_parent is None:
        raise CalibError(f"{chain.path}: no link {c.link!r}, the ROS-Industrial frame of {c.what} "
                         f"(--convention {convention}), whose place in the robot "
                         f"{'depends on the model' if c.rpy is None else f'is given from {c.parent!r}, also absent'}"
                         f": give the frame of the targets with --targets-link LINK (a link of the URDF), or "
                         f"--targets-frame base for the URDF's {base!r}")
    import pinocchio as pin

    D = np.eye(4)
    D[:3, :3] = pin.rpy.rpyToMatrix(*c.rpy)
    D[:3, 3] = c.xyz
    T = T_parent @ D
    return _frame(T, None, f"targets in {c.what} (--convention {convention}): {chain.path.name} has no link "
                           f"{c.link!r}; the vendor's placement from {c.parent!r}, {_relative(T, base)}")


def _relative(T: np.ndarray, base: str) -> str:
    text = describe_transform(T)
    return f"{text} as the base frame {base!r}" if text == "the same frame" else f"{text} from the base frame {base!r}"


def _frame(T: np.ndarray, link: str | None, text: str) -> TargetsFrame:
    T = np.array(T, dtype=float)
    T.setflags(write=False)
    return TargetsFrame(T_base_frame=T, link=link, text=text)
