"""The header of a CSV file, matched against a column :class:`calib.io.csv.layer.Spec` and a robot.

The column names say the quantity and its unit (``joint1_deg``, ``x_mm``; ``X (mm)`` and ``X [mm]``
read as ``x_mm``), matched case-insensitively after :attr:`ReadOptions.rename`; the orientation is
one of the column groups of :data:`ORIENTATIONS`. :class:`Header` checks a header once and says
which column holds what (:class:`Column`, with the factor to SI units); what it refuses is a
:class:`calib.MeasurementFormatError` naming the file, the header row and the column, with a "did
you mean" for near-misses of a known name and a hint for joint names the chain does not hold.
Used by :func:`calib.io.csv.layer.read_table`; the rest of the text of a file lives there.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from calib.errors import MeasurementFormatError
from calib.io.csv.cells import read_cell

if TYPE_CHECKING:
    from calib.io.csv.options import ReadOptions, Spec

__all__ = ["ANGLE_UNITS", "LENGTH_UNITS", "POSITION_COLUMNS", "ORIENTATIONS", "Column", "Header"]

#: Multiply a value in the unit of the suffix by this to get SI (radians, metres).
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
#: Optional per-row columns a measurement file may carry for the report (drift during the
#: measurement), with their units: time in seconds, temperature in degrees Celsius.
EXTRA_UNITS = {"time": {"s": 1.0, "min": 60.0, "h": 3600.0}, "temperature": {"c": 1.0, "degc": 1.0}}
POSITION_COLUMNS = ("x", "y", "z")

#: Orientation column groups: kind -> (column base names, units (None: no suffix), label).
ORIENTATIONS = {
    "quaternion": (("qw", "qx", "qy", "qz"), None, "a quaternion (qw, qx, qy, qz)", "quaternion"),
    "zyx": (("rz", "ry", "rx"), ANGLE_UNITS, "ZYX angles (rz, ry, rx)", "ZYX angle"),
    "euler": (("e1", "e2", "e3"), ANGLE_UNITS, "Euler angles (e1, e2, e3)", "Euler angle"),
    "rotvec": (("rvx", "rvy", "rvz"), ANGLE_UNITS, "a rotation vector (rvx, rvy, rvz)",
               "rotation vector"),
    "matrix": (tuple(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)), None,
               "a rotation matrix (r11 ... r33)", "rotation matrix"),
}

_NEAR_MISS_CUTOFF = 0.75
#: Unit suffixes calib does not take but that are units, not typos (no "did you mean").
_OTHER_UNITS = {"cm", "dm", "um", "km", "in", "ft", "mrad", "urad", "grad", "gon", "rev", "turn"}


@dataclass(frozen=True, eq=False, repr=False)     # (the header parser's records: nothing compares or prints them)
class Column:
    """One column of a CSV header: its index (from 0), name, what it holds and the factor to SI units."""

    index: int
    name: str             # as written (after a rename)
    quantity: object      # joint index, "x", "qw", "rz", "e1", "r11", a label name
    scale: float = 1.0    # value * scale is in rad or m
    unit: str = ""
    style: str = ""       # joint naming style
    vendor: bool = False  # named by the vendor convention of ReadOptions.convention


_UNIT_IN_BRACKETS = re.compile(r"^(.*?)\s*[\(\[]\s*([A-Za-z]+)\s*[\)\]]$")
_STYLE_TEXT = {"urdf": "URDF joint names", "q": "q1..q{n}", "j": "J1..J{n}", "a": "A1..A{n}"}


def _unit_text(units) -> str:
    return " or ".join(f"_{u}" for u in units)


#: Labels read from a column of another name: ``name`` (the row's name, kept and shown in reports
#: and outputs) from a column ``point``, ``name`` or ``waypoint`` (a point name in a tracker export,
#: a UR waypoint log); in a touch file ``point`` is the feature touched instead.
LABEL_ALIASES = {"name": ("point", "waypoint")}
#: Names of the columns that hold a whole pose or all joints as one literal (URScript, RAPID).
POSE_LITERAL_NAMES = ("pose", "tcp_pose", "robtarget")
JOINT_LITERAL_NAMES = ("joints", "q", "jointtarget")
_UNIT_TABLE = {"deg": ANGLE_UNITS, "rad": ANGLE_UNITS, "mm": LENGTH_UNITS, "m": LENGTH_UNITS}


def _close(word: str, candidates: list, cutoff: float) -> list:
    """The closest of ``candidates`` to ``word`` (a list of at most one), for error hints
    (difflib is loaded by a failing header only)."""
    import difflib

    return difflib.get_close_matches(word, candidates, n=1, cutoff=cutoff)


def _conv_style(pattern) -> str:
    if isinstance(pattern, tuple):
        return "named"
    return {"A{i}": "a", "J{i}": "j"}.get(pattern, pattern)


class Vocabulary:
    """The column names a spec takes for a robot under the read options: base name (lower
    case) -> (quantity, units or None for no suffix, style), with the default unit of the names
    a vendor convention writes without a suffix."""

    def __init__(self, spec: Spec, robot, options: ReadOptions):
        from calib.io.csv.conventions import CONVENTIONS

        self.spec, self.robot, self.options = spec, robot, options
        joints = robot.joints if spec.joints != "none" else ()
        n = robot.n_joints
        self.joint_units = [LENGTH_UNITS if j.is_prismatic else ANGLE_UNITS for j in robot.joints]
        suffixed: dict[str, tuple] = {}
        plain: dict[str, tuple] = {}
        if spec.position != "none":
            for k in POSITION_COLUMNS:
                suffixed[k] = (k, LENGTH_UNITS, "")
            for k in POSE_LITERAL_NAMES:
                plain[k] = ("pose_literal", None, "")
        if spec.orientation:
            for kind, (cols, units, _, _) in ORIENTATIONS.items():
                for c in cols:
                    (suffixed if units else plain)[c] = (c, units, "")
        for label in spec.labels:
            plain[label] = (label, None, "")
            for alias in LABEL_ALIASES.get(label, ()):
                plain.setdefault(alias, (label, None, ""))
        for k in spec.lengths:
            suffixed[k] = (k, LENGTH_UNITS, "")
        # extras: read only with a unit of theirs (a bare "time" column stays ignored, as before)
        self.extras = {k: EXTRA_UNITS[k] for k in spec.extras}
        self.key = None
        if spec.keyed:
            self.key = str(spec.key or options.key).strip()
            plain[self.key.lower()] = (self.key, None, "")
        if joints:
            for k in JOINT_LITERAL_NAMES:
                plain.setdefault(k, ("joint_literal", None, ""))
        for i, j in enumerate(joints):
            if j.name.lower() not in plain:
                suffixed.setdefault(j.name.lower(), (i, self.joint_units[i], "urdf"))
        if joints:
            for style in ("q", "j", "a"):
                for i in range(n):
                    if f"{style}{i + 1}" not in plain:
                        suffixed.setdefault(f"{style}{i + 1}", (i, self.joint_units[i], style))
        self.convention = CONVENTIONS.get(options.convention) if options.convention else None
        #: lower-case name -> unit key read when the name has no suffix (vendor conventions)
        self.default: dict[str, str] = {}
        #: lower-case names that a vendor convention maps
        self.vendor: set[str] = set()
        self.euler = options.euler
        conv = self.convention
        if conv is not None:
            self.euler = options.euler or conv.euler
            if joints:
                unit = conv.joints[1]
                for pattern in conv.joints[0]:
                    style = _conv_style(pattern)
                    for name, i in _one(pattern, n):
                        plain.pop(name, None)
                        suffixed[name] = (i, self.joint_units[i], style)
                        self.default[name] = ({"deg": "mm", "rad": "m"}[unit] if joints[i].is_prismatic
                                              else unit)
                        self.vendor.add(name)
            for name, quantity, unit in conv.columns:
                low = name.lower()
                if quantity in POSITION_COLUMNS and spec.position == "none":
                    continue
                if quantity not in POSITION_COLUMNS and not spec.orientation:
                    continue
                if unit:
                    plain.pop(low, None)
                    suffixed[low] = (quantity, _UNIT_TABLE[unit], "")
                    self.default[low] = unit
                else:
                    suffixed.pop(low, None)
                    plain[low] = (quantity, None, "")
                self.vendor.add(low)
        if options.instrument is not None or options.length_unit is not None:
            from calib.io.csv.instruments import apply_to_vocabulary

            apply_to_vocabulary(self, options, plain)
        self.suffixed, self.plain = suffixed, plain
        self.valid = [f"{b}_{u}" for b, (_, units, _) in suffixed.items() for u in units] + list(plain)

    def known(self, written: str) -> bool:
        """Whether a header name (as written) names one of these columns, even with a wrong or
        missing unit suffix (used to find the header line after a preamble)."""
        name = read_cell(written.strip())
        m = _UNIT_IN_BRACKETS.match(name)
        low = (f"{m.group(1)}_{m.group(2)}" if m and m.group(1) else name).lower()
        if low in self.plain or low in self.suffixed:
            return True
        base, sep, _ = low.rpartition("_")
        return bool(sep) and (base in self.suffixed or base in self.plain)


def _one(pattern, n: int) -> list[tuple[str, int]]:
    if isinstance(pattern, tuple):
        return [(pattern[i].lower(), i) for i in range(min(n, len(pattern)))]
    return [(pattern.format(i=i + 1, i0=i).lower(), i) for i in range(n)]


class Header:
    """A header checked against a spec and a robot."""

    def __init__(self, path: Path, row: int | None, names: list[str], spec: Spec, robot,
                 options: ReadOptions, vocabulary: Vocabulary | None = None, named_by: str = ""):
        self.path, self.row, self.spec, self.robot, self.options = path, row, spec, robot, options
        #: the option that gave the names of a file without a header line (row None), else ""
        self.named_by = named_by
        self.names = [n.strip() for n in names]
        voc = vocabulary or Vocabulary(spec, robot, options)
        self.vocabulary = voc
        self.joint_units = voc.joint_units
        self.suffixed, self.plain, self.valid, self.key = voc.suffixed, voc.plain, voc.valid, voc.key
        self.default, self.vendor, self.euler = voc.default, voc.vendor, voc.euler
        self.convention, self.extras = voc.convention, voc.extras

        renames = {old.lower(): new for old, new in options.rename}
        if self.convention is None and spec.orientation:
            self._vendor_orientation([renames.get(r.strip().lower(), r.strip()) for r in names])
        self.renamed: list[str] = []
        #: (message, column) when the orientation columns are ambiguous (rx, ry, rz in that order)
        self.ambiguous: tuple[str, str] | None = None
        self.columns: dict[object, Column] = {}
        self.ignored: list[str] = []
        #: the ignored columns dropped on purpose (a rename to nothing)
        self.dropped: list[str] = []
        styles: dict[str, str] = {}
        # a group that looks like an orientation and that calib's names do not read (Leica's Q0..Q3,
        # q_w..q_z) is one unread group, not joints q1..q3 missing a suffix nor a misspelt 'q'
        lookalike = set()
        if spec.orientation:
            from calib.io.csv.lookalike import unread_group

            lookalike = unread_group([renames.get(r.strip().lower(), r.strip()) for r in names], self._classify)
        for index, raw in enumerate(names):
            # (a name as calib writes it for spreadsheets, a quote before a formula lead, read
            # back: calib.io.csv.cells; blanks around it dropped, a name's own kept)
            name = read_cell(raw.strip())
            if name.lower() in renames:
                self.renamed.append(name.lower())
                name = renames[name.lower()]
                if not name:
                    self.ignored.append(raw.strip())
                    self.dropped.append(raw.strip())
                    continue
            if name in lookalike:
                self.ignored.append(name)
                continue
            col = self._classify(index, name)
            if col is None:
                self.ignored.append(name)
                continue
            if col.quantity in self.columns:
                prev = self.columns[col.quantity]
                what = (f"joint {robot.joints[col.quantity].name}" if isinstance(col.quantity, int)
                        else col.quantity)
                if prev.name.lower() == name.lower():
                    reason = (f"duplicated column: {name!r} appears in columns {prev.index + 1} "
                              f"and {index + 1}")
                else:
                    reason = (f"duplicated column: {what} is given twice, by {prev.name!r} (column "
                              f"{prev.index + 1}) and {name!r} (column {index + 1}); give each once")
                self.fail(reason, name)
            if col.style:
                other = next((s for s in styles if s != col.style), None)
                if other is not None:
                    self.fail(f"mixes joint naming styles: {styles[other]!r} uses "
                              f"{self._style_text(other)} but {name!r} uses "
                              f"{self._style_text(col.style)}; use one style for all joints", name)
                styles.setdefault(col.style, name)
            self.columns[col.quantity] = col
        self.orientation = self._check_complete()
        if spec.orientation and self.orientation == "none" and "x" in self.columns:
            self._unread_orientation()

    # -------------------------------------------------------------- helpers
    def fail(self, reason: str, column: str | None = None):
        if self.row is None and self.named_by:
            reason = f"{reason} (the column names of {self.named_by})"
        raise MeasurementFormatError(self.path, reason, row=self.row, column=column)

    def _style_text(self, style: str) -> str:
        n = self.robot.n_joints
        if style in _STYLE_TEXT:
            return _STYLE_TEXT[style].format(n=n)
        conv = self.convention
        pattern = next((p for p in (conv.joints[0] if conv else ()) if _conv_style(p) == style), None)
        if isinstance(pattern, tuple):
            return ", ".join(pattern[:n])
        if pattern is not None:
            return f"{pattern.format(i=1, i0=0)}..{pattern.format(i=n, i0=n - 1)}"
        return style

    def accepted(self) -> str:
        spec, robot = self.spec, self.robot
        parts = []
        if spec.joints != "none":
            prism = [j.name for j in robot.joints if j.is_prismatic]
            junits = "_rad or _deg"
            if prism:
                junits += (f" (_m or _mm for the prismatic joint{'s' if len(prism) > 1 else ''} "
                           f"{', '.join(prism)})")
            n = robot.n_joints
            parts.append(f"one per joint, named {', '.join(robot.joint_names)} or q1..q{n}, "
                         f"J1..J{n}, A1..A{n}, with suffix {junits}")
        if spec.position != "none":
            parts.append("x, y, z with _m or _mm")
        if spec.orientation:
            parts.append("optionally qw, qx, qy, qz; rz, ry, rx; e1, e2, e3 (with --euler); "
                         "rvx, rvy, rvz (these with _rad or _deg); or r11 ... r33")
        if spec.labels:
            parts.append("optionally " + ", ".join(spec.labels))
        if spec.lengths:
            parts.append("optionally " + ", ".join(f"{k} with _m or _mm" for k in spec.lengths))
        if spec.extras:
            parts.append("optionally " + ", ".join(f"{k} with {_unit_text(EXTRA_UNITS[k])}" for k in spec.extras))
        if self.key:
            parts.append(f"the key column {self.key}")
        parts.append("or a vendor's names with --convention (calib formats lists every rule)")
        return f"{spec.kind} file columns: " + "; ".join(parts)

    def _classify(self, index: int, written: str) -> Column | None:
        if not written:
            self.fail(f"column {index + 1} of the header has an empty name (a stray delimiter?); "
                      f"{self.accepted()}")
        m = _UNIT_IN_BRACKETS.match(written)
        name = f"{m.group(1)}_{m.group(2)}" if m and m.group(1) else written
        low = name.lower()
        base, sep, suffix = low.rpartition("_")
        if sep and base in self.extras and suffix in self.extras[base]:
            return Column(index, written, base, self.extras[base][suffix], suffix, "")
        if low in self.plain:
            q, _, _ = self.plain[low]
            return Column(index, written, q)
        if low in self.suffixed:
            quantity, units, style = self.suffixed[low]
            if low in self.default:
                unit = self.default[low]
                return Column(index, written, quantity, units[unit], unit, style, vendor=True)
            length = "; or give their unit: --length-unit mm|m" if quantity in POSITION_COLUMNS else ""
            self.fail(f"missing unit suffix: expected a unit suffix {_unit_text(units)} "
                      f"(e.g. {name}_{list(units)[-1]}){length}{self._convention_hint(low)}", written)
        base, sep, suffix = low.rpartition("_")
        if sep and base in self.suffixed:
            quantity, units, style = self.suffixed[base]
            if suffix not in units:
                hint = ""
                if suffix not in _OTHER_UNITS:  # a typo (_mn, _dg), not another unit (_cm)
                    typo = [u for u in units if len(u) == len(suffix)
                            and sum(a != b for a, b in zip(u, suffix)) == 1]
                    close = typo or _close(suffix, list(units), 0.5)
                    hint = f"; did you mean '{name[:len(base)]}_{close[0]}'?" if close else ""
                self.fail(f"wrong unit suffix _{suffix}: {base} takes {_unit_text(units)}{hint}",
                          written)
            return Column(index, written, quantity, units[suffix], suffix, style,
                          vendor=base in self.vendor)
        if sep and base in self.plain:
            group = next((label for cols, u, _, label in ORIENTATIONS.values() if base in cols),
                         base)
            self.fail(f"{group} components take no unit suffix: expected {base!r}", written)
        n = self.robot.n_joints
        if self.spec.joints != "none" and sep and re.fullmatch(r"[qja]\d+", base) \
                and suffix in ANGLE_UNITS.keys() | LENGTH_UNITS.keys():
            self.fail(f"too many joint columns: the robot has {n} joints "
                      f"({', '.join(self.robot.joint_names)}), so joint columns run q1..q{n}", written)
        if self.spec.joints != "none" and sep and suffix in ANGLE_UNITS.keys() | LENGTH_UNITS.keys() \
                and base in self._joints_outside_chain():
            self.fail(f"joint {name[:len(base)]!r} of the URDF is not in the chain calibrated here "
                      f"({', '.join(self.robot.joint_names)}, from base frame {self.robot.base_frame!r} to "
                      f"tool frame {self.robot.tool_frame!r}): choose --base-frame / --tool-frame to take "
                      f"it in, or drop the column with --rename '{written}='", written)
        if self.convention is not None and self.convention.others and \
                re.fullmatch(self.convention.others, low):
            return None         # one of the vendor's other columns, not a misspelt name
        close = _close(low, self.valid, _NEAR_MISS_CUTOFF)
        if close:
            self.fail(f"unknown column: did you mean {self._spelling(close[0])!r}? (rename it with "
                      f"--rename '{written}=NEW', or drop it with --rename '{written}=')", written)
        return None

    def _style_name(self, style: str, i: int) -> str:
        """The name of joint i (from 0) in a vendor convention's naming style."""
        conv = self.convention
        pattern = next((p for p in (conv.joints[0] if conv else ()) if _conv_style(p) == style), None)
        if isinstance(pattern, tuple):
            return pattern[i] if i < len(pattern) else f"joint {i + 1}"
        return pattern.format(i=i + 1, i0=i) if pattern else f"joint {i + 1}"

    def _convention_hint(self, low: str) -> str:
        """"; or ... --convention NAME" when a vendor convention names this column (without a
        suffix), "" otherwise or when a convention is given."""
        from calib.io.csv.conventions import CONVENTIONS

        if self.convention is not None:
            return ""
        n = self.robot.n_joints
        found = [c for c in CONVENTIONS.values()
                 if low in {nm for p in c.joints[0] for nm, _ in _one(p, n)}
                 or low in {nm.lower() for nm, _, _ in c.columns}]
        if not found:
            return ""
        return (f"; or, for a file written with a vendor's names, give --convention "
                f"{'|'.join(c.name for c in found)} (calib formats lists them)")

    def _joint_convention_hint(self) -> str:
        """"; columns ... are the joint names of the NAME convention: give --convention NAME"
        when columns the header check ignored (with or without a unit suffix) are a vendor
        convention's joint names (:data:`calib.io.csv.conventions.CONVENTIONS`: base..wrist3 and
        actual_q_0.. of UR, rax_1.. of ABB, ...) other than the one given; "" otherwise."""
        from calib.io.csv.conventions import CONVENTIONS

        units = ANGLE_UNITS.keys() | LENGTH_UNITS.keys()

        def bare(name: str) -> str:
            m = _UNIT_IN_BRACKETS.match(name)
            low = (f"{m.group(1)}_{m.group(2)}" if m and m.group(1) else name).lower()
            base, sep, suffix = low.rpartition("_")
            return base if sep and suffix in units else low

        n = self.robot.n_joints
        found = []
        for c in CONVENTIONS.values():
            joints = dict(c.joint_names(n))
            hits = [w for w in self.ignored if bare(w) in joints]
            if hits and c is not self.convention:
                found.append((c, hits))
        if not found:
            return ""
        hits = found[0][1]
        shown = ", ".join(hits[:3]) + (", ..." if len(hits) > 3 else "")
        names = "|".join(c.name for c, _ in found)
        return (f"; columns {shown} are joint names of the {names} convention: give --convention "
                f"{names} (calib formats lists the conventions)")

    def _vendor_orientation(self, names: list[str]) -> None:
        """Refuse a header (no convention given) whose columns are the whole orientation group
        of a vendor convention written without unit suffixes (KUKA A, B, C; ABB q1..q4; Fanuc
        W, P, R; rx, ry, rz): read by calib's own rules they would be ignored or taken for joint
        angles. Names the convention(s) and, for rx, ry, rz, every reading they can have."""
        from calib.io.csv.conventions import CONVENTIONS, ambiguous_candidates

        present = {n.lower() for n in names}
        found = []
        for c in CONVENTIONS.values():
            entries = [(n.lower(), q) for n, q, _ in c.columns if q not in POSITION_COLUMNS]
            while entries:
                size = 4 if entries[0][1] == "qw" else 3
                group, entries = [n for n, _ in entries[:size]], entries[size:]
                if not all(g in present for g in group):
                    continue
                # q1..q4 followed by q5: joint columns of calib's q style, not a quaternion
                m = re.fullmatch(r"(.*?)(\d+)", group[-1])
                if m and f"{m.group(1)}{int(m.group(2)) + 1}" in present:
                    continue
                found.append((c, group))
        if not found:
            return
        written = [next(n for n in names if n.lower() == g) for g in found[0][1]]
        shown = ", ".join(written)
        if {g for _, gr in found for g in gr} == {"rx", "ry", "rz"}:
            self.fail(f"orientation columns {shown} without a stated convention are ambiguous; "
                      f"they may be {ambiguous_candidates()} (calib formats lists them)", written[0])
        c = found[0][0]
        self.fail(f"columns {shown} look like the {c.name} convention's orientation "
                  f"({c.orientation}), which calib's own names do not take: give --convention "
                  f"{'|'.join(c.name for c, _ in found)} (calib formats lists the conventions), or "
                  f"drop them with --rename '{','.join(w + '=' for w in written)}' if they are not",
                  written[0])

    def _unread_orientation(self) -> None:
        """Refuse a header that reads a position and no orientation while columns it ignored
        look like one (:mod:`calib.io.csv.lookalike`): never a silent position-only fit."""
        from calib.io.csv.lookalike import unread_orientation

        found = unread_orientation([n for n in self.ignored if n not in self.dropped])
        if found is not None:
            self.fail(found.message, found.columns[0])

    def _urdf_joints(self) -> dict:
        """The joints of the robot's URDF (name -> :class:`calib.io.urdf.document.UrdfJoint`), from the
        document the model carries (only on an error path); empty for a model built in code."""
        if getattr(self, "_joints", None) is None:
            self._joints = {}
            source = getattr(self.robot, "source", None)    # the URDF as it was parsed
            if source is not None and source.document is not None:
                self._joints = source.document.joints
        return self._joints

    def _joints_outside_chain(self) -> set[str]:
        """Lower-case names of the URDF's moving joints that are not in the robot's chain."""
        inside = {n.lower() for n in self.robot.joint_names}
        return {n.lower() for n, j in self._urdf_joints().items() if j.kind != "fixed"} - inside

    def _trailing_hint(self, missing: list[int]) -> str:
        """When the joints without a column end the chain (a gripper joint taken as the arm's
        last axis), how to leave them out: a tool frame before the first of them (no hint
        without a URDF to name the link: a model built in code)."""
        robot = self.robot
        if not missing or missing != list(range(missing[0], robot.n_joints)) or missing[0] == 0:
            return ""
        joint = self._urdf_joints().get(robot.joints[missing[0]].name)
        if joint is None:
            return ""
        names = ", ".join(robot.joints[i].name for i in missing)
        return (f"; if {names} {'is a gripper' if len(missing) == 1 else 'are a gripper'}, not an axis of the "
                f"measured arm, choose a tool frame before it: --tool-frame {joint.parent} (the link it is "
                f"attached to) or a frame fixed to that link")

    def _spelling(self, valid_lower: str) -> str:
        base, sep, suffix = valid_lower.rpartition("_")
        for j in self.robot.joints:
            if j.name.lower() == base:
                return f"{j.name}_{suffix}"
        return self.key if self.key and valid_lower == self.key.lower() else valid_lower

    def _check_complete(self) -> str:
        robot, spec, cols = self.robot, self.spec, self.columns
        present = [c for c in cols.values() if isinstance(c.quantity, int)]
        literal = cols.get("joint_literal")
        if literal is not None and present:
            self.fail(f"joints given twice: by the literal column {literal.name!r} and by "
                      f"{present[0].name!r}; give one", present[0].name)
        if literal is None and (spec.joints == "required" or (spec.joints == "optional" and present)):
            style = present[0].style if present else "urdf"
            missing = [i for i in range(robot.n_joints) if i not in cols]
            if missing:
                def expected(i):
                    base = robot.joints[i].name if style == "urdf" else \
                        f"{style.upper() if style != 'q' else 'q'}{i + 1}" if style in _STYLE_TEXT \
                        else self._style_name(style, i)
                    return " or ".join(f"{base}_{u}" for u in self.joint_units[i])
                self.fail(f"missing joint column{'s' if len(missing) > 1 else ''}: the header has "
                          f"{len(present)} joint columns but the robot has {robot.n_joints} joints "
                          f"({', '.join(robot.joint_names)}); expected "
                          f"{'; '.join(expected(i) for i in missing)}{self._trailing_hint(missing)}"
                          f"{self._joint_convention_hint()}")
        have_pos = [k for k in POSITION_COLUMNS if k in cols]
        pose = cols.get("pose_literal")
        if pose is not None:
            other = [c.name for k, c in cols.items() if k in POSITION_COLUMNS or
                     any(k in g for g, _, _, _ in ORIENTATIONS.values())]
            if other:
                self.fail(f"the pose is given twice: by the literal column {pose.name!r} and by "
                          f"{other[0]!r}; give one", other[0])
            have_pos = ["pose_literal"]
        elif spec.position == "required" or have_pos:
            for k in POSITION_COLUMNS:
                if k not in cols:
                    self.fail(f"missing column {k}: expected {k}_m or {k}_mm (the position x, y, z "
                              f"is required{' with an orientation' if spec.position != 'required' else ''})")
        kinds = []
        for kind, (group, _, _, label) in ORIENTATIONS.items():
            have = [k for k in group if k in cols]
            if have and len(have) < len(group):
                lack = [k for k in group if k not in cols]
                self.fail(f"incomplete {label} columns: found {', '.join(have)} but not "
                          f"{', '.join(lack)}; give all of {', '.join(group)} or none")
            if have:
                kinds.append(kind)
        if len(kinds) > 1:
            a, b = (ORIENTATIONS[k][2] for k in kinds[:2])
            self.fail(f"both {a} and {b} are given; give one orientation or none")
        orientation = "literal" if pose is not None else kinds[0] if kinds else "none"
        if orientation == "zyx" and (self.convention is None or self.convention.name != "calib"):
            rx, rz = cols["rx"], cols["rz"]
            if not rx.vendor and rx.index < rz.index:
                from calib.io.csv.conventions import ambiguous_candidates

                shown = ", ".join(c.name for c in sorted((cols["rx"], cols["ry"], rz),
                                                         key=lambda c: c.index))
                stated = ("without a stated convention" if self.convention is None else
                          f"(not named by the {self.convention.name} convention)")
                # decided by the rows where they can (calib.io.csv.orientation), else refused
                self.ambiguous = (f"orientation columns {shown} {stated} are "
                                  f"ambiguous (calib's ZYX angles are written rz, ry, rx); they may be "
                                  f"{ambiguous_candidates()} (calib formats lists them)", rx.name)
        if orientation != "none" and not have_pos:
            self.fail("an orientation without a position: give x, y, z with _m or _mm too")
        if orientation == "euler" and self.euler is None:
            self.fail("Euler angle columns e1, e2, e3 need their sequence: give --euler SEQ in "
                      "scipy's notation (ZYX intrinsic, xyz extrinsic, ...)", cols["e1"].name)
        if self.key is not None and self.key not in cols:
            close = _close(self.key.lower(), [c.strip().lower() for c in self.ignored], 0.6)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            given = "" if self.key == self.options.key else f" {self.options.key!r}"
            self.fail(f"no key column {self.key!r} (given by --key{given}){hint}")
        if spec.joints == "optional" and spec.position != "none" and not present and literal is None \
                and not have_pos:
            self.fail(f"no {spec.kind}: give joint columns or a position x, y, z"
                      f"{self._joint_convention_hint()}; {self.accepted()}")
        return orientation

