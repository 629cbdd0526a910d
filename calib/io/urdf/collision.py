"""The collision geometry of a robot's URDF: its links' ``<collision>`` elements as Pinocchio's
:class:`pinocchio.GeometryModel` (meshes loaded by coal, which ships with Pinocchio), for the
model the robot was read with (``robot.source.model``: the same joints and frames).

Meshes named ``package://NAME/...`` are looked up in the folders given (``package_dirs``), then
in the folders above the URDF file that hold a folder ``NAME`` (the URDF inside its package, as
ROS-Industrial's support packages and example-robot-data lay them out), then in
``ROS_PACKAGE_PATH`` (read, as ROS tools read it). Pinocchio resolves ``package://NAME/rest`` to
``DIR/NAME/rest`` for the first folder DIR where it exists.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

from calib.errors import ParameterError, URDFError
from calib.io.fileio import captured_c_output

__all__ = ["collision_geometry", "package_dirs_for"]

_PACKAGE = re.compile(r"package://([^/\"']+)/")


def package_dirs_for(urdf_path: Path, text: str, given=()) -> list[str]:
    """The folders meshes of the URDF ``text`` (read from ``urdf_path``) are looked up in: the
    ``given`` ones, then for each package the URDF names the first folder above the file that
    holds it, then ``ROS_PACKAGE_PATH``'s folders."""
    dirs = [str(Path(d)) for d in given]
    packages = sorted(set(_PACKAGE.findall(text)))
    for parent in Path(urdf_path).resolve().parents:
        if any((parent / name).is_dir() for name in packages) and str(parent) not in dirs:
            dirs.append(str(parent))
    for d in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if d and d not in dirs:
            dirs.append(d)
    return dirs


def collision_geometry(robot, package_dirs=()):
    """Pinocchio's GeometryModel of the collision geometry of the URDF ``robot`` was read from
    (:func:`calib.load_robot`; its ``source`` holds the URDF's Pinocchio model and document).

    package_dirs : folders to look up ``package://`` meshes in first (see the module docstring).
    Raises :class:`calib.URDFError` naming the URDF and the mesh not found, or when the URDF has
    no collision geometry; :class:`calib.ParameterError` for a model built in code (no URDF).
    """
    import pinocchio as pin

    source = getattr(robot, "source", None)
    if source is None or getattr(source, "document", None) is None:
        raise ParameterError("the robot has no URDF (a model built in code): collision geometry comes "
                             "from a URDF's <collision> elements")
    if isinstance(package_dirs, (str, os.PathLike)):
        package_dirs = [package_dirs]
    for d in package_dirs:
        if not Path(d).is_dir():
            raise ParameterError(f"--package-dir {d}: no such folder")
    path = Path(source.path)
    from lxml import etree

    text = etree.tostring(source.document.tree, encoding="unicode")
    from_file = path.suffix.lower() == ".urdf" and path.is_file()
    dirs = package_dirs_for(path, text, package_dirs)
    try:
        with captured_c_output():      # (assimp and the parser write to C stdout and stderr)
            if from_file:
                geom = pin.buildGeomFromUrdf(source.model, str(path), pin.GeometryType.COLLISION, package_dirs=dirs)
            else:
                geom = pin.buildGeomFromUrdfString(source.model, text, pin.GeometryType.COLLISION, package_dirs=dirs)
    except (ValueError, RuntimeError, OSError) as exc:
        msg = " ".join(str(exc).split())
        hint = f" (looked in {', '.join(dirs)}; --package-dir DIR adds a folder)" if "package://" in msg else ""
        raise URDFError(path, f"its collision geometry cannot be loaded: {msg}{hint}") from None
    if geom.ngeoms == 0:
        raise URDFError(path, "has no collision geometry (no <collision> element in its links): a plan checks "
                              "collisions with the links' collision shapes")
    return geom
