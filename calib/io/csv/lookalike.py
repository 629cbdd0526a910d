"""Columns that look like an orientation calib does not read: refused, never a position-only fit.

A tracker export often carries the orientation of a 6-DoF probe under the instrument's own names
(Leica's ``Q0;Q1;Q2;Q3``, ``q_w``, ``orientation.x``, ``Rot X [deg]``, ``R(1,1)``, KUKA's ``A, B,
C`` under another convention, ...). Read by calib's rules such columns are unknown names, ignored
with a note, and the calibration would run on the positions alone with exit 0: a wrong answer.
:func:`unread_orientation` finds, among the columns a header check ignored, a complete group of
names that looks like an orientation, and says what it looks like and which option reads it;
:class:`calib.io.csv.header.Header` refuses such a file (one line naming the file, the header row,
the columns and the option) when it reads a position and no orientation. A group dropped on
purpose (``--rename 'Q0=,Q1=,Q2=,Q3='``) is not looked at: that is how a position-only fit is
asked for.

The names are compared squashed: lower case, a unit in brackets or after an underscore removed
(``Rot X [deg]`` and ``rot_x_deg`` are both ``rotx``), blanks and ``_ . - ( ) [ ] , :`` removed
(``R(1,1)`` is ``r11``).
"""
from __future__ import annotations

import re

from dataclasses import dataclass

__all__ = ["Lookalike", "unread_orientation", "unread_group"]

_UNIT_IN_BRACKETS = re.compile(r"^(.*?)\s*[\(\[]\s*([A-Za-z]+)\s*[\)\]]$")
#: Unit suffixes removed before the comparison (angles; the quaternion and matrix take none).
_UNITS = {"deg", "rad", "degree", "degrees", "grad", "gon", "mrad", "urad"}
_SEPARATORS = re.compile(r"[\s_.\-()\[\],:;/]+")


@dataclass(frozen=True, eq=False, repr=False)     # (a family's constants: nothing compares or prints them)
class _Family:
    """Names that together make one orientation: ``pattern`` (full match of the squashed name)
    gives the group ``p`` (a prefix shared by the group's names) and ``k`` (which member);
    ``members``: the keys that make the group whole (any one of the tuples)."""

    pattern: str
    members: tuple
    what: str
    how: str


#: The families looked for, in this order (the first whole group is named).
_FAMILIES = (
    _Family(r"(?P<p>dquaternion|quaternion|quat|q)(?P<k>[0-4])", (("0", "1", "2", "3"), ("1", "2", "3", "4")),
            "a quaternion", "quaternion_index"),
    _Family(r"(?P<p>.*orientation|quaternion|quat|q)(?P<k>[wxyz])", (("w", "x", "y", "z"),),
            "a quaternion", "quaternion_letters"),
    _Family(r"(?P<p>rotationmatrix|rotmat|rotation|rot|matrix|r|m)(?P<k>[0-3][0-3])",
            (tuple(f"{i}{j}" for i in "123" for j in "123"), tuple(f"{i}{j}" for i in "012" for j in "012")),
            "a rotation matrix", "matrix"),
    _Family(r"(?P<p>rotationvector|rotvec|rvec|rv|axisangle)(?P<k>[xyz])", (("x", "y", "z"),),
            "a rotation vector", "rotvec"),
    _Family(r"(?P<p>(?:actual|target)tcppose)(?P<k>[345])", (("3", "4", "5"),),
            "the orientation of UR's RTDE TCP pose (a rotation vector)", "ur"),
    _Family(r"(?P<p>drotationangle|rotationangle|rotation|rot|angle|euler|r|o)(?P<k>[xyz])", (("x", "y", "z"),),
            "rotation angles", "angles"),
    _Family(r"(?P<p>euler|e)(?P<k>[123])", (("1", "2", "3"),), "Euler angles", "angles"),
    _Family(r"(?P<p>)(?P<k>roll|pitch|yaw)", (("roll", "pitch", "yaw"),), "roll, pitch and yaw angles",
            "angles"),
    _Family(r"(?P<p>)(?P<k>alpha|beta|gamma)", (("alpha", "beta", "gamma"),), "rotation angles", "angles"),
    _Family(r"(?P<p>)(?P<k>[abc])", (("a", "b", "c"),), "KUKA's A, B, C angles", "kuka"),
    _Family(r"(?P<p>)(?P<k>[wpr])", (("w", "p", "r"),), "FANUC's W, P, R angles", "fanuc"),
)


@dataclass(frozen=True, eq=False)
class Lookalike:
    """A group of ignored columns that looks like an orientation.

    columns : the names as written, in the group's order. message : the one-line reason
    (what they look like, the option that reads them, how to drop them).
    """

    columns: tuple[str, ...]
    message: str


def _squash(name: str) -> str:
    m = _UNIT_IN_BRACKETS.match(name.strip())
    low = (m.group(1) if m and m.group(1) and m.group(2).lower() in _UNITS else name.strip()).lower()
    base, sep, suffix = low.rpartition("_")
    if sep and base and suffix in _UNITS:
        low = base
    return _SEPARATORS.sub("", low)


def _how(kind: str, pairs: list[tuple[str, str]], instruments: dict) -> str:
    """The options that read the group ``pairs`` ((name as written, member key), file order)."""
    def rename(targets: dict):
        return "--rename '" + ",".join(f"{w}={targets[k]}" for w, k in pairs) + "'"

    written = [w for w, _ in pairs]
    if kind == "quaternion_index":
        first = dict((k, w) for w, k in pairs)[min(k for _, k in pairs)]
        presets = [name for name, names in instruments.items() if names and {n.lower() for n in written} <= names]
        preset = f"--instrument {'|'.join(presets)} ({first} the scalar), or " if presets else ""
        keys = sorted(k for _, k in pairs)
        return (f"{preset}{rename(dict(zip(keys, ('qw', 'qx', 'qy', 'qz'))))} if {first} is the scalar (w) or "
                f"{rename(dict(zip(keys, ('qx', 'qy', 'qz', 'qw'))))} if it is x")
    if kind == "quaternion_letters":
        return rename({k: f"q{k}" for k in "wxyz"})
    if kind == "matrix":
        base = min(int(k[0]) for _, k in pairs)
        return rename({k: f"r{int(k[0]) - base + 1}{int(k[1]) - base + 1}" for _, k in pairs}) \
            + " (rij: row i, column j)"
    if kind == "rotvec":
        return rename({k: f"rv{k}_rad" for k in "xyz"}) + " (or _deg)"
    if kind in ("ur", "kuka", "fanuc"):
        return f"--convention {kind}"
    return ("the --convention that states them (calib formats lists them), or --rename to calib's ZYX "
            "angles rz_deg, ry_deg, rx_deg or to e1_deg, e2_deg, e3_deg with --euler SEQ")


def unread_orientation(ignored) -> Lookalike | None:
    """The first whole group of names among ``ignored`` (header names as written, of columns the
    header check did not read and that were not dropped on purpose) that looks like an
    orientation, or None. The message names the instrument preset that reads the group
    (:data:`calib.io.csv.instruments.INSTRUMENTS`), if one does."""
    from calib.io.csv.instruments import INSTRUMENTS

    names = [n for n in ignored if n and n.strip()]
    if not names:
        return None
    instruments = {i.name: {a.lower() for a, b in i.columns if b in ("qw", "qx", "qy", "qz")}
                   for i in INSTRUMENTS.values()}
    squashed = [(n, _squash(n)) for n in names]
    order = {n: i for i, n in reversed(list(enumerate(names)))}
    for family in _FAMILIES:
        groups: dict[str, dict[str, str]] = {}
        for written, s in squashed:
            m = re.fullmatch(family.pattern, s)
            if m is not None:
                groups.setdefault(m.group("p"), {}).setdefault(m.group("k"), written)
        for found in groups.values():
            for keys in family.members:
                if all(k in found for k in keys):
                    pairs = sorted(((found[k], k) for k in keys), key=lambda p: order[p[0]])
                    written = [w for w, _ in pairs]
                    shown = ", ".join(written)
                    drop = "--rename '" + ",".join(f"{w}=" for w in written) + "'"
                    how = _how(family.how, pairs, instruments)
                    return Lookalike(tuple(written), (
                        f"columns {shown} look like {family.what}, which calib does not read as written: "
                        f"the calibration would use the positions alone. Read them with {how}; or drop "
                        f"them with {drop} to calibrate positions only"))
    return None


def unread_group(names: list[str], classify) -> set[str]:
    """The names of a group among ``names`` (a header's, after renames) that looks like an
    orientation and that calib's names do not read, each unknown or an error by itself
    (``classify(index, name)``: the header check's reading of one name, None when unknown), else
    an empty set: such a group is one unread group, not joints q1..q3 missing a suffix nor a
    misspelt name."""
    from calib.errors import MeasurementFormatError

    unread = []
    for index, name in enumerate(names):
        try:
            if name and classify(index, name) is None:
                unread.append(name)
        except MeasurementFormatError:
            unread.append(name)
    found = unread_orientation(unread)
    return set() if found is None else set(found.columns)
