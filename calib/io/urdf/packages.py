"""Where the ROS packages a robot description names are: ``$(find NAME)`` in a xacro and
``package://NAME/...`` in its mesh paths, found without a ROS installation
(:class:`RosPackages`).

A package is a folder holding a ``package.xml`` whose ``<name>`` is the package's name (what
``$(find NAME)`` gives: the package's folder in a source workspace, its share folder once
installed). The places looked in, first match first:

1. the folders given by the user (``--package NAME=DIR``, ``packages={"NAME": DIR}``);
2. the package that holds the description file itself: the nearest folder above it with a
   ``package.xml`` (a xacro opened inside its own description package finds that package);
3. ``ROS_PACKAGE_PATH`` (ROS 1): each folder crawled for packages as ``rospack`` crawls it, by
   rospkg (``RosPack(ros_paths=...)``: a folder with a ``package.xml`` is a package and is not
   descended into, ``CATKIN_IGNORE`` stops a branch);
4. ``AMENT_PREFIX_PATH`` (ROS 2): the ament resource index of each prefix, as
   ``ament_index_python.get_package_share_directory`` reads it: a package ``NAME`` is installed
   in prefix ``P`` when the marker file ``P/share/ament_index/resource_index/packages/NAME``
   exists, and its share folder is ``P/share/NAME``; the first prefix holding it wins.

The environment is read, never changed; nothing is cached between calls.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

from calib.checks import check_path
from calib.errors import CalibError, ParameterError, URDFError

__all__ = ["RosPackages", "parse_package_option", "package_name_of", "ros_extra"]

#: The package-manifest file name (REP 127 / REP 140).
PACKAGE_XML = "package.xml"
#: The ament resource index of packages under a prefix (ament_index's layout).
AMENT_PACKAGES = Path("share", "ament_index", "resource_index", "packages")


def ros_extra(module: str, what: str):
    """Import ``module`` (a dependency of the optional ``ros`` extra), or a :class:`CalibError`
    naming the extra: ``what`` says what needs it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise CalibError(f"{what} needs the optional 'ros' dependencies (xacro, rospkg, rosbags): "
                         f"pip install 'calib[ros]'") from None


def parse_package_option(text: str) -> tuple[str, Path]:
    """``NAME=DIR`` of ``--package`` as (name, folder); :class:`ParameterError` otherwise (the
    folder must exist)."""
    name, sep, folder = str(text).partition("=")
    name, folder = name.strip(), folder.strip()
    if not sep or not name or not folder or any(c.isspace() or c in "/\\" for c in name):
        raise ParameterError(f"--package {text!r}: expected NAME=DIR (a ROS package name and its folder, "
                             f"e.g. ur_description=~/ws/src/ur_description)")
    path = Path(os.path.expanduser(folder))
    if not path.is_dir():
        raise ParameterError(f"--package {name}={folder}: no such folder")
    return name, path.resolve()


def package_name_of(folder: Path) -> str | None:
    """The ``<name>`` of ``folder/package.xml``, or None when the folder has none or it is not
    a readable manifest."""
    from lxml import etree

    try:
        root = etree.parse(str(folder / PACKAGE_XML), etree.XMLParser(resolve_entities=False)).getroot()
    except (OSError, etree.XMLSyntaxError):
        return None
    name = (root.findtext("name") or "").strip()
    return name or None


def _enclosing_package(path: Path) -> tuple[str, Path] | None:
    """(name, folder) of the nearest folder above ``path`` holding a package.xml, else None."""
    for folder in Path(path).resolve().parents:
        if (folder / PACKAGE_XML).is_file():
            name = package_name_of(folder)
            return None if name is None else (name, folder)
    return None


def _split_paths(value: str | None) -> tuple[Path, ...]:
    return tuple(Path(p) for p in (value or "").split(os.pathsep) if p.strip())


@dataclass(frozen=True)
class RosPackages:
    """The package locations a description is expanded with (see the module docstring).

    given : ((name, folder), ...) from the user, in the order given (a name given twice: the
        last wins, as in a dict).
    ros_package_path : the folders of ``ROS_PACKAGE_PATH`` (crawled when a name is looked up).
    ament_prefix_path : the prefixes of ``AMENT_PREFIX_PATH``.
    """

    given: tuple[tuple[str, Path], ...] = ()
    ros_package_path: tuple[Path, ...] = ()
    ament_prefix_path: tuple[Path, ...] = ()

    def __post_init__(self):
        for name in ("given", "ros_package_path", "ament_prefix_path"):
            value = getattr(self, name)
            pairs = name == "given"
            ok = isinstance(value, tuple) and all(
                isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], str) and isinstance(v[1], Path)
                if pairs else isinstance(v, Path) for v in value)
            if not ok:
                raise ParameterError(f"{name} must be a tuple of {'(name, Path) pairs' if pairs else 'Paths'} "
                                     f"(RosPackages.from_options makes one), got {value!r:.60}")

    @classmethod
    def from_options(cls, packages: Mapping[str, str | Path] | Iterable[str] | None = None, *,
                     environ: Mapping[str, str] | None = None) -> "RosPackages":
        """The locations of ``packages`` (a mapping name -> folder, or ``NAME=DIR`` texts) and of
        ``ROS_PACKAGE_PATH`` / ``AMENT_PREFIX_PATH`` in ``environ`` (default ``os.environ``,
        read only). :class:`ParameterError` for a malformed entry or a folder that does not
        exist."""
        if packages is None:
            given = []
        elif isinstance(packages, Mapping):
            given = [parse_package_option(f"{k}={v}") for k, v in packages.items()]
        elif isinstance(packages, (str, bytes)) or not isinstance(packages, Iterable):
            raise ParameterError(f"packages must be a mapping name -> folder or NAME=DIR texts, got {packages!r:.60}")
        else:
            given = [parse_package_option(t) for t in packages]
        if environ is not None and not isinstance(environ, Mapping):
            raise ParameterError(f"environ must be a mapping of environment variables, got {environ!r:.60}")
        env = os.environ if environ is None else environ
        for name in ("ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"):
            if not isinstance(env.get(name, ""), str):
                raise ParameterError(f"environ[{name!r}] must be a text of folders, got {env.get(name)!r:.60}")
        return cls(given=tuple(given), ros_package_path=_split_paths(env.get("ROS_PACKAGE_PATH")),
                   ament_prefix_path=_split_paths(env.get("AMENT_PREFIX_PATH")))

    def table(self, description: Path | None = None) -> dict[str, Path]:
        """Every package these locations know, name -> folder, first match winning (the module
        docstring's order); ``description``: the file whose own package is looked for."""
        if description is not None:
            description = check_path(description, "description")
        found: dict[str, Path] = {}
        for prefix in reversed(self.ament_prefix_path):        # (the first prefix wins)
            index = prefix / AMENT_PACKAGES
            if index.is_dir():
                found.update({m.name: prefix / "share" / m.name for m in index.iterdir() if m.is_file()})
        if self.ros_package_path:
            rospkg = ros_extra("rospkg", "finding packages on ROS_PACKAGE_PATH")
            rospack = rospkg.RosPack(ros_paths=[str(p) for p in self.ros_package_path if p.is_dir()])
            try:
                found.update({name: Path(rospack.get_path(name)) for name in rospack.list()})
            except rospkg.common.ResourceNotFound:      # (listed, so found)
                pass
            except rospkg.InvalidManifest as exc:
                raise URDFError(None, f"ROS_PACKAGE_PATH: {' '.join(str(exc).split())}") from None
        if description is not None:
            own = _enclosing_package(description)
            if own is not None:
                found[own[0]] = own[1]
        found.update(dict(self.given))
        return found

    def searched(self) -> str:
        """Where :meth:`table` looked, for a message."""
        parts = [f"--package {', '.join(n for n, _ in self.given)}" if self.given else "no --package",
                 "the description's own package"]
        parts.append(f"ROS_PACKAGE_PATH ({os.pathsep.join(map(str, self.ros_package_path))})"
                     if self.ros_package_path else "no ROS_PACKAGE_PATH")
        parts.append(f"AMENT_PREFIX_PATH ({os.pathsep.join(map(str, self.ament_prefix_path))})"
                     if self.ament_prefix_path else "no AMENT_PREFIX_PATH")
        return "; ".join(parts)
