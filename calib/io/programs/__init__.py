"""Robot program files in and out: the targets a program holds, a corrected copy of it, and a new
program moving through given joint configurations. One module per vendor:

* :mod:`calib.io.programs.kuka`: KRL ``.dat`` (``E6AXIS``/``AXIS`` and ``E6POS``/``POS``
  declarations); new programs as a ``.src`` and its ``.dat``;
* :mod:`calib.io.programs.abb`: RAPID ``.mod`` (``robtarget`` and ``jointtarget`` literals);
* :mod:`calib.io.programs.urscript`: URScript (``movej``/``movel``/``movep``/``servoj`` with a
  ``p[...]`` pose or a ``[...]`` joint list, and Polyscope's ``Waypoint_n_p``/``_q`` variables);
* :mod:`calib.io.programs.fanuc`: FANUC ``.LS`` (the ``/POS`` section's ``P[n]{ ... }``).

A program is read once into :class:`Program`: its text as it is and its :class:`ProgramTarget`
list, each with the character spans of its numbers. A corrected copy (:func:`corrected_text`)
replaces those numbers only: comments, line endings, spacing and everything else stay byte for
byte. Joint values are SI (rad, m) in the robot's (URDF's) joints; poses are (4, 4) metres in the
controller's base frame (:mod:`calib.io.urdf.controller_frame`). Errors are
:class:`calib.MeasurementFormatError` naming the file, line and what was expected.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from dataclasses import dataclass
from calib.errors import MeasurementFormatError, ParameterError

__all__ = ["Program", "ProgramTarget", "VENDOR_OF_SUFFIX", "vendor_of", "read_program", "corrected_text",
           "corrected_program", "write_corrected", "write_joint_program", "joint_program_texts", "NUMBER"]

#: The program file kinds by suffix (lower case) and the vendor (``--convention``) each belongs to.
VENDOR_OF_SUFFIX = {".dat": "kuka", ".mod": "abb", ".script": "ur", ".urscript": "ur", ".ls": "fanuc"}
#: A number as the controllers write them: -12.5, .002, -.000, 9E9, 2.12917962E-06, 1e+09.
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


@dataclass(frozen=True, eq=False)
class ProgramTarget:
    """One target of a program.

    name : its name in the program (a variable, ``P[3]``, or ``line 12`` for a literal in a
        motion instruction). line : 1-based line of its first number. kind : "joints" or "pose".
    q : (n,) rad / m, the robot's joints (joint targets), else None.
    T : (4, 4) metres, the tool pose in the controller's base frame (pose targets), else None.
    configuration : the vendor's configuration tuple
        (:func:`calib.compensation.configuration.vendor_configuration`) or None when the program
        gives none. fields : ((key, start, end, text), ...) the character spans (and text as
        written) of the numbers a corrected copy replaces. refused : why the target cannot be corrected ("" when it can),
        e.g. a user frame the program does not define.
    """

    name: str
    line: int
    kind: str
    q: np.ndarray | None
    T: np.ndarray | None
    configuration: tuple | None
    fields: tuple
    refused: str = ""


@dataclass(frozen=True, eq=False)
class Program:
    """A program file as read: ``path``, ``vendor``, the ``text`` (decoded with ``encoding``) and
    its ``targets``; ``notes``: one-line remarks (targets the reader leaves alone and why)."""

    path: Path
    vendor: str
    text: str
    encoding: str
    targets: tuple
    notes: tuple = ()


def _module(vendor: str):
    import importlib

    return importlib.import_module(f"calib.io.programs.{ {'ur': 'urscript'}.get(vendor, vendor)}")


def vendor_of(path: str | Path) -> str | None:
    """The vendor of a program file by its suffix, or None for a file that is no program."""
    return VENDOR_OF_SUFFIX.get(Path(path).suffix.lower())


def _decode(path: Path, data: bytes) -> tuple[str, str]:
    for encoding in ("utf-8", "cp1252"):
        try:
            return data.decode(encoding), encoding
        except UnicodeDecodeError:
            continue
    return data.decode("latin-1"), "latin-1"


def read_program(path: str | Path, robot, *, options: dict | None = None) -> Program:
    """Read the targets of a program file (vendor by suffix: :data:`VENDOR_OF_SUFFIX`) for
    ``robot`` (its joints: count, units, which are prismatic). ``options``: vendor options
    (FANUC: ``j23_factor``). Raises :class:`calib.MeasurementFormatError` naming the file, line
    and what was expected; a file with no target is refused too."""
    from calib.checks import check_path

    path = Path(check_path(path, "path"))
    vendor = vendor_of(path)
    if vendor is None:
        raise ParameterError(f"{path}: not a program file calib reads (suffixes: {', '.join(VENDOR_OF_SUFFIX)})")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeasurementFormatError(path, f"cannot be read: {exc.strerror or exc}") from None
    text, encoding = _decode(path, data)
    targets, notes = _module(vendor).parse(path, text, robot, **(options or {}))
    if not targets:
        raise MeasurementFormatError(path, f"holds no target calib reads: expected {_module(vendor).EXPECTED}")
    return Program(path=path, vendor=vendor, text=text, encoding=encoding, targets=tuple(targets),
                   notes=tuple(notes))


def corrected_text(program: Program, values: list[dict | None]) -> str:
    """The program's text with the numbers of each target replaced: ``values[k]`` maps the keys
    of target k's fields to their new text (None: the target unchanged)."""
    edits = []
    for target, new in zip(program.targets, values):
        if new is None:
            continue
        for key, start, end, *_ in target.fields:
            if key in new:
                edits.append((start, end, new[key]))
    out, last = [], 0
    for start, end, text in sorted(edits):
        out.append(program.text[last:start])
        out.append(text)
        last = end
    out.append(program.text[last:])
    return "".join(out)


def corrected_program(program: Program, robot, *, q: np.ndarray | None = None, T: np.ndarray | None = None,
                      configurations: list | None = None, options: dict | None = None) -> str:
    """The text of a corrected copy of ``program``: joint targets take ``q[k]`` (rad / m), pose
    targets ``T[k]`` ((4, 4) metres, controller base frame) with ``configurations[k]`` (the
    vendor's tuple, or None to keep the program's). Rows of NaN leave a target as it is."""
    mod = _module(program.vendor)
    values = []
    for k, target in enumerate(program.targets):
        if target.kind == "joints" and q is not None and not np.isnan(q[k]).any():
            values.append(mod.joint_fields(target, q[k], robot, **(options or {})))
        elif target.kind == "pose" and T is not None and not np.isnan(T[k]).any():
            values.append(mod.pose_fields(target, T[k], None if configurations is None else configurations[k]))
        else:
            values.append(None)
    return corrected_text(program, values)


def write_corrected(program: Program, path: str | Path, robot, **kwargs) -> str:
    """Write :func:`corrected_program` to ``path`` atomically, in the program's encoding; returns
    the text."""
    from calib.io.fileio import atomic_write_bytes

    text = corrected_program(program, robot, **kwargs)
    atomic_write_bytes(path, text.encode(program.encoding))
    return text


def write_joint_program(vendor: str, path: str | Path, robot, q: np.ndarray, *,
                        names: list[str] | None = None, options: dict | None = None) -> list[Path]:
    """Write a new program for ``vendor`` ("kuka", "abb", "ur", "fanuc") that moves through the
    joint configurations ``q`` (N, n) rad / m in order, with joint motions (KRL PTP to E6AXIS,
    RAPID MoveAbsJ, URScript movej, FANUC J P[n] of joints), atomically. ``path`` names the
    program file (KRL: the ``.src``; its ``.dat`` is written beside it). Returns the files
    written. Each reads back with :func:`read_program` to the same joints (to the digits the
    format keeps)."""
    from calib.io.fileio import OutputSet

    files = joint_program_texts(vendor, path, robot, q, names=names, options=options)
    out = OutputSet()
    for file, text in files.items():
        out.stage(file, text.encode("utf-8"))
    out.commit()
    return list(files)


def joint_program_texts(vendor: str, path: str | Path, robot, q: np.ndarray, *, names: list[str] | None = None,
                        options: dict | None = None) -> dict:
    """The files of :func:`write_joint_program`: path -> text."""
    if vendor not in ("kuka", "abb", "ur", "fanuc"):
        raise ParameterError(f"no program format for {vendor!r}: known are kuka, abb, ur, fanuc")
    q = np.atleast_2d(np.asarray(q, float))
    if q.ndim != 2 or q.shape[1] != robot.n_joints or not np.isfinite(q).all():
        raise ParameterError(f"q must be (N, {robot.n_joints}) finite joint values")
    names = names or [f"P{k + 1}" for k in range(len(q))]
    return _module(vendor).joint_program(Path(path), robot, q, list(names), **(options or {}))


def numbers(text: str, start: int, end: int) -> list[tuple[float, int, int]]:
    """(value, start, end) of each number in ``text[start:end]`` (absolute offsets)."""
    return [(float(m.group()), start + m.start(), start + m.end()) for m in re.finditer(NUMBER, text[start:end])]


def line_of(text: str, offset: int) -> int:
    """1-based line number of a character offset."""
    return text.count("\n", 0, offset) + 1
