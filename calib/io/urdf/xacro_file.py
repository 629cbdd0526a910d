"""A robot description kept as a xacro (a ROS description package's ``*.urdf.xacro``), expanded
into the URDF calib reads (:func:`expand_xacro`) without a ROS installation.

The expansion is ROS's own ``xacro`` (the package ``xacro`` on PyPI, published by its
maintainers from github.com/ros/xacro; pure Python, needing only PyYAML): macros, properties,
``$(arg)``, includes, ``xacro.load_yaml`` and ``$(find NAME)`` behave as in ROS. Chosen over
``xacrodoc``, which wraps the same xacro but replaces its package look-up by patching the xacro
module when it is imported (process-wide, in the caller's process) and rewrites ``package://``
mesh paths to absolute ``file://`` paths, where calib keeps them as written. xacro itself keeps
its state in module globals and adds its unit tags to PyYAML's ``SafeLoader``, so it runs in a
child process (:mod:`calib.io.urdf.xacro_worker`), with ``$(find NAME)`` answered from the
package table of :class:`calib.io.urdf.packages.RosPackages` (``--package NAME=DIR``, the
description's own package, ``ROS_PACKAGE_PATH``, ``AMENT_PREFIX_PATH``).

``package://NAME/...`` and ``file://...`` mesh (and texture) paths of the expanded URDF are
resolved with the same table: an unknown package is an error, a missing file a note; the paths
are kept as written in the URDF calib reads, and so in the calibrated URDF it writes.

The URDF is a :class:`XacroText` (a :class:`calib.io.urdf.reader.UrdfText`: read by
:func:`calib.load_robot` and the exports as a URDF file is), which also lists every file the
expansion read; :meth:`XacroText.kinematics_file` finds among them a parameter file the
description takes its kinematics from, in a format calib writes (a UR kinematics YAML:
ur_description's ``config/<type>/default_kinematics.yaml``, read by ``ur_macro.xacro``).
"""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping
from urllib.parse import unquote, urlparse

from lxml import etree

from calib.checks import check_path
from calib.errors import CalibError, ParameterError, URDFError
from calib.io.urdf.packages import RosPackages
from calib.io.urdf.reader import UrdfText

__all__ = ["XacroText", "expand_xacro", "is_xacro_path", "parse_xacro_arg", "XACRO_TIMEOUT_S", "FORMAT_HELP"]

#: What ``calib formats`` says of xacros.
FORMAT_HELP = """\
Robot descriptions as xacros (ROBOT.urdf.xacro wherever a URDF is taken; no ROS installation:
pip install 'calib[ros]'):
Expansion: ROS's own xacro (PyPI 'xacro'), as `xacro ROBOT.urdf.xacro NAME:=VALUE ...` expands
  it in ROS: --xacro-arg NAME:=VALUE (repeatable) gives its arguments.
Packages: $(find NAME) and package://NAME/... are the folder of --package NAME=DIR (repeatable),
  else of the package holding the xacro (the nearest package.xml above it), else of
  ROS_PACKAGE_PATH (ROS 1, crawled as rospack does), else of AMENT_PREFIX_PATH (ROS 2, the ament
  index: PREFIX/share/NAME). An unknown package is an error; a missing mesh file a note.
Mesh paths: package:// and file:// paths are kept as written, in the calibrated URDF too.
Output: calibrate writes the calibrated URDF; when the xacro takes its kinematics from a UR
  kinematics YAML (ur_description's config/<type>/default_kinematics.yaml, through
  xacro.load_yaml), also CALIBRATED.kinematics.yaml, the calibrated file in that format, to
  expand the xacro with in its place (kinematics_params:=CALIBRATED.kinematics.yaml).
"""

#: Seconds the expansion may take before it is stopped (a description expands in well under one).
XACRO_TIMEOUT_S = 120.0
_WORKER = Path(__file__).with_name("xacro_worker.py")


def is_xacro_path(path) -> bool:
    """Whether ``path`` names a xacro: its suffix is ``.xacro`` (``robot.urdf.xacro``,
    ``robot.xacro``; any case)."""
    return isinstance(path, (str, Path)) and Path(path).suffix.lower() == ".xacro"


def parse_xacro_arg(text: str) -> tuple[str, str]:
    """``name:=value`` (as ``xacro`` and ``ros2 launch`` take it) as (name, value);
    :class:`ParameterError` otherwise. The value may be empty."""
    name, sep, value = str(text).partition(":=")
    name = name.strip()
    if not sep or not name or any(c.isspace() for c in name):
        raise ParameterError(f"--xacro-arg {text!r}: expected NAME:=VALUE (as xacro takes it, e.g. ur_type:=ur5e)")
    return name, value


@dataclass(frozen=True, repr=False)
class XacroText(UrdfText):
    """The URDF a xacro expands to (:func:`expand_xacro`).

    path : the xacro file (named in messages; an input no output may overwrite).
    text : the URDF (XML text), mesh paths as the xacro wrote them.
    args : ((name, value), ...) the xacro arguments it was expanded with.
    files : every other file the expansion read (included xacros, YAML parameter files), as
        absolute paths, in the order xacro read them.
    notes : one-line remarks (mesh files not found), for the caller to show.
    """

    args: tuple[tuple[str, str], ...] = ()
    files: tuple[Path, ...] = ()
    notes: tuple[str, ...] = ()

    def __repr__(self) -> str:
        return (f"XacroText(path={str(self.path)!r}, args={dict(self.args)!r}, {len(self.files)} files read, "
                f"text=<{len(self.text)} characters>)")

    def kinematics_file(self) -> Path | None:
        """The parameter file this description takes its kinematics from, when it is one calib
        writes: the first YAML the expansion read that is a UR kinematics file
        (:func:`calib.io.urdf.ur_description.read_ur_kinematics` reads it); else None."""
        from calib.io.urdf.ur_description import read_ur_kinematics

        for f in self.files:
            if f.suffix.lower() in (".yaml", ".yml"):
                try:
                    read_ur_kinematics(f)
                except CalibError:
                    continue
                return f
        return None


def _args(args) -> tuple[tuple[str, str], ...]:
    if args is None:
        return ()
    if isinstance(args, Mapping):
        items = [(str(k), str(v)) for k, v in args.items()]
        for k, _ in items:
            parse_xacro_arg(f"{k}:=")
        return tuple(items)
    if isinstance(args, (str, bytes)) or not isinstance(args, Iterable):
        raise ParameterError(f"args must be a mapping name -> value or NAME:=VALUE texts, got {args!r:.60}")
    return tuple(parse_xacro_arg(t) for t in args)


def expand_xacro(path: str | Path, args: Mapping[str, str] | Iterable[str] | None = None,
                 packages: RosPackages | Mapping[str, str | Path] | Iterable[str] | None = None) -> XacroText:
    """Expand the xacro ``path`` into a URDF, as ``xacro path name:=value ...`` does in ROS.

    Parameters
    ----------
    path : the xacro file.
    args : its arguments: a mapping name -> value, or ``NAME:=VALUE`` texts (``--xacro-arg``).
    packages : where ``$(find NAME)`` and ``package://NAME`` are: a :class:`RosPackages`, or a
        mapping name -> folder / ``NAME=DIR`` texts (``--package``), to which
        ``ROS_PACKAGE_PATH`` and ``AMENT_PREFIX_PATH`` are added (the environment is read,
        never changed).

    Returns a :class:`XacroText` for :func:`calib.load_robot` and the exports. Raises
    :class:`calib.URDFError` naming the file for a xacro that does not expand (the innermost
    file and xacro's own message), an unknown package (its name and where it was looked for) or
    a mesh path of an unknown package; :class:`calib.CalibError` naming the ``ros`` extra when
    xacro is not installed.
    """
    path = check_path(path, "path")
    if not path.is_file():
        raise URDFError(path, "is a folder, expected a xacro file" if path.is_dir() else "file not found")
    args = _args(args)
    if not isinstance(packages, RosPackages):
        packages = RosPackages.from_options(packages)
    table = packages.table(path)
    request = {"file": str(path.resolve()), "args": dict(args), "packages": {k: str(v) for k, v in table.items()}}
    try:
        run = subprocess.run([sys.executable, str(_WORKER)], input=json.dumps(request), capture_output=True,
                             text=True, timeout=XACRO_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise URDFError(path, f"xacro did not finish expanding it within {XACRO_TIMEOUT_S:g} s (a macro that "
                              f"calls itself without end?)") from None
    try:
        answer = json.loads(run.stdout)
    except ValueError:
        said = [line for line in run.stderr.splitlines() if line.strip()]
        raise URDFError(path, f"xacro's process failed (exit code {run.returncode})"
                              f"{': ' + said[-1].strip() if said else ''}") from None
    if "error" in answer:
        _raise(path, answer, packages)
    text = answer["urdf"]
    notes = _check_mesh_paths(path, text, table, packages)
    files = tuple(Path(f) for f in answer["files"])
    return XacroText(path=path, text=text, args=args, files=files, notes=notes)


def _raise(path: Path, answer: dict, packages: RosPackages):
    if answer.get("missing"):
        from calib.io.urdf.packages import ros_extra

        ros_extra("xacro", f"{path}: expanding a xacro")
    where = answer.get("file")
    inner = f" (in {where})" if where and Path(where) != path.resolve() else ""
    if answer.get("package"):
        name = answer["package"]
        raise URDFError(path, f"unknown package {name!r} ($(find {name}){inner}): give its folder with "
                              f"--package {name}=DIR (looked in: {packages.searched()})")
    raise URDFError(path, f"xacro cannot expand it{inner}: {answer['error']}")


def resolve_uri(uri: str, table: Mapping[str, Path], relative_to: Path) -> Path | None:
    """The file a URDF resource path names: ``package://NAME/rest`` in the package table,
    ``file://`` an absolute path, anything else relative to ``relative_to`` (a folder). None
    for a ``package://`` of a package the table does not have."""
    if uri.startswith("package://"):
        name, _, rest = uri[len("package://"):].partition("/")
        folder = table.get(name)
        return None if folder is None else Path(folder) / unquote(rest)
    if uri.startswith("file://"):
        return Path(unquote(urlparse(uri).path))
    return relative_to / uri


def _check_mesh_paths(path: Path, text: str, table: Mapping[str, Path], packages: RosPackages) -> tuple[str, ...]:
    """Notes for mesh and texture files that are not there; URDFError for a ``package://`` of
    an unknown package (naming the link)."""
    try:
        root = etree.fromstring(text.encode(), etree.XMLParser(resolve_entities=False))
    except etree.XMLSyntaxError as exc:
        raise URDFError(path, f"the URDF xacro made from it is malformed XML: {exc.msg}") from None
    missing = []
    for el in root.iter("mesh", "texture"):
        uri = (el.get("filename") or "").strip()
        if not uri:
            continue
        link = next((a.get("name") for a in el.iterancestors("link")), None)
        file = resolve_uri(uri, table, path.parent)
        if file is None:
            name = uri[len("package://"):].partition("/")[0]
            raise URDFError(path, f"unknown package {name!r} (the {el.tag} {uri}"
                                  f"{f' of link {link!r}' if link else ''}): give its folder with --package "
                                  f"{name}=DIR (looked in: {packages.searched()})")
        if not file.is_file():
            missing.append(uri)
    if not missing:
        return ()
    more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
    return (f"{path}: mesh file {missing[0]}{more} not found (kept as written: calib's kinematics do not "
            f"use meshes)",)

