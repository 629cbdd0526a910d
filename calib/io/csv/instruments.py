"""Instrument presets: how a measuring instrument's software writes its exports, as data.

:data:`INSTRUMENTS` is the one table, as :data:`calib.io.csv.conventions.CONVENTIONS` is for the
controllers: for each ``--instrument`` name, the columns of its export read as calib's
(``Q0`` -> ``qw``), the column names of an export written without a header line, the line
prefixes of its comment lines, and what its orientation columns are. A preset applies to the
instrument's file: the tracker file of a join (``--tracker``), or the measurement file read on
its own; calib's own names stay valid. :func:`check_file_options` checks the fields of
:class:`calib.ReadOptions` that describe such a file (``instrument``, ``columns`` for any file
without a header line, ``length_unit`` for positions named without a unit). ``calib formats``
lists the presets (:func:`format_help`).

What each preset follows, and where it is documented:

- ``leica``: Leica Geosystems AT9xx laser trackers with a T-Mac 6-DoF probe, exported by the
  tracker software. Leica's emScon TPI header ``ES_C_API_Def.h`` (TPI/SDK V3.6, (C) Leica
  Geosystems AG 2001..2011) gives a 6-DoF result as ``dPosition1..3`` and ``dQuaternion0..3``
  beside ``dRotationAngleX..Z``; programs reading it build the rotation with Q0 the scalar
  (``R00 = q0*q0+q1*q1-q2*q2-q3*q3``, ``R01 = 2*(q1*q2-q0*q3)``). The export's header, ``Point;Time
  [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3`` (``;`` separated, units in brackets, decimal commas in
  European locales), is the one issue 37 quotes: no published export file was found.
- ``spatialanalyzer``: New River Kinematics SpatialAnalyzer's ASCII point export. Its user manual
  ("Exporting ASCII Formatted Points"): the point name exported as "Collection Group target",
  "Group target", "target" or none, "exporting using Collection Group target exports in the
  format CollectionName GroupName TargetName x y z"; "Data can be delimited by spaces or commas";
  the SA version, frame and axis comments "preceded by // to denote that the line is a comment";
  points "always exported in the working coordinate frame", in the job's units, which the file
  does not state (``--length-unit``). Other name options are read with ``--columns``.

This module imports nothing heavy: the command line builds its ``--instrument`` choices from it.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Instrument", "INSTRUMENTS", "INSTRUMENT_NAMES", "LENGTH_UNIT_NAMES", "check_file_options",
           "parse_columns", "format_help"]

#: The units ``--length-unit`` takes (calib's length suffixes).
LENGTH_UNIT_NAMES = ("mm", "m")


@dataclass(frozen=True, eq=False, repr=False)     # (table rows, looked up by name: nothing compares or prints them)
class Instrument:
    """One instrument software's exports.

    name : the ``--instrument`` value. vendor : who writes such files, and how.
    columns : ((the export's name, calib's name), ...), names matched case-insensitively (a unit
        in brackets read as a suffix first: ``X [mm]`` is ``x_mm``).
    header : the column names of an export written without a header line, in order, or None (the
        export has its header line).
    comments : line prefixes of comment lines besides ``#``.
    orientation : what the orientation columns are, in words.
    """

    name: str
    vendor: str
    columns: tuple
    header: tuple | None
    comments: tuple
    orientation: str

    def renames(self) -> dict[str, str]:
        """The export's names (lower case) -> calib's names."""
        return {a.lower(): b for a, b in self.columns}


INSTRUMENTS: dict[str, Instrument] = {i.name: i for i in (
    Instrument("leica", "Leica Geosystems AT9xx laser trackers with a T-Mac 6-DoF probe, exported by the "
                        "tracker software (Point;Time [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3, ';' and decimal "
                        "commas)",
               (("Q0", "qw"), ("Q1", "qx"), ("Q2", "qy"), ("Q3", "qz")), None, (),
               "Q0, Q1, Q2, Q3: unit quaternion, Q0 the scalar (w, x, y, z)"),
    Instrument("spatialanalyzer", "New River Kinematics SpatialAnalyzer ASCII point export: no header line, "
                                  "Collection Group Target X Y Z, spaces or commas, // comment lines",
               (("Target", "name"),), ("Collection", "Group", "Target", "X", "Y", "Z"), ("//",),
               "none (points); X, Y, Z in the job's units, which the file does not state: give "
               "--length-unit"),
)}
INSTRUMENT_NAMES = tuple(INSTRUMENTS)


def parse_columns(text) -> tuple[str, ...]:
    """``"a,b,c"`` (or a sequence of names) as the names of a header-less file's columns;
    :class:`calib.ParameterError` for an empty name or a name given twice."""
    from calib.errors import ParameterError

    if not (isinstance(text, str) or isinstance(text, (list, tuple)) and all(isinstance(n, str) for n in text)):
        raise ParameterError(f"columns must be the file's column names, 'a,b,c' or a sequence of str, got "
                             f"{text!r:.60}")
    names = [n.strip() for n in (text.split(",") if isinstance(text, str) else text)]
    if not names or any(not n for n in names):
        raise ParameterError(f"--columns {text!r:.80}: expected the file's column names in order, "
                             f"separated by commas (e.g. 'point,x_mm,y_mm,z_mm'), none empty")
    low = [n.lower() for n in names]
    dup = next((n for n in names if low.count(n.lower()) > 1), None)
    if dup is not None:
        raise ParameterError(f"--columns {text!r:.80}: column {dup!r} named twice")
    return tuple(names)


def check_file_options(options) -> dict:
    """Check the fields ``instrument``, ``columns`` and ``length_unit`` of a
    :class:`calib.ReadOptions`; the normalised values (field -> value, which ReadOptions sets);
    :class:`calib.ParameterError` naming the option."""
    from calib.errors import ParameterError

    o = options
    if o.instrument is not None and (not isinstance(o.instrument, str) or o.instrument not in INSTRUMENTS):
        raise ParameterError(f"instrument must be one of {', '.join(INSTRUMENTS)} (--instrument), got "
                             f"{o.instrument!r:.60}")
    if o.length_unit is not None and (not isinstance(o.length_unit, str) or o.length_unit not in LENGTH_UNIT_NAMES):
        raise ParameterError(f"length_unit must be one of {', '.join(LENGTH_UNIT_NAMES)} (--length-unit), got "
                             f"{o.length_unit!r:.60}")
    if o.columns is None:
        return {}
    if o.header_line is not None:
        raise ParameterError("--columns names the columns of a file without a header line, --header-line "
                             "says which line the header is: give one")
    return {"columns": parse_columns(o.columns)}


def apply_to_vocabulary(vocabulary, options, plain: dict) -> None:
    """Apply ``options.instrument`` to a header's vocabulary (:class:`calib.io.csv.header.Vocabulary`
    being built; ``plain``: its names without a unit suffix): the export's names read as calib's,
    the key column excepted; x, y, z of an instrument's file take no controller convention's
    unit. Then ``options.length_unit``: the unit of x, y, z named without one."""
    if options.instrument is not None:
        key = (vocabulary.key or "").lower()
        for name, calib_name in INSTRUMENTS[options.instrument].columns:
            if calib_name in plain and name.lower() != key:
                plain[name.lower()] = plain[calib_name]
        for k in "xyz":
            vocabulary.default.pop(k, None)
    if options.length_unit is not None and vocabulary.spec.position != "none":
        vocabulary.default.update({k: options.length_unit for k in "xyz"})


def file_columns(options) -> tuple[tuple[str, ...] | None, tuple[str, ...], str]:
    """(the column names of a header-less file or None, comment prefixes, the option that named
    the columns) of the file ``options`` read: ``--columns``, else the preset's header."""
    inst = INSTRUMENTS.get(options.instrument) if options.instrument else None
    comments = inst.comments if inst is not None else ()
    if options.columns is not None:
        return tuple(options.columns), comments, "--columns"
    if inst is not None and inst.header is not None:
        return inst.header, comments, f"--instrument {inst.name}"
    return None, comments, ""


def format_help() -> str:
    """The presets as ``calib formats`` prints them."""
    import textwrap

    out = ["Instrument presets (--instrument NAME): the instrument's file as its software writes it (the",
           "tracker file of --tracker, or the measurement file); calib's own names stay valid. A file",
           "without a header line: --columns NAMES (comma separated, in order) names its columns; x, y, z",
           "named without a unit are read in --length-unit mm|m.", ""]
    for inst in INSTRUMENTS.values():
        out.append(f"{inst.name}: {inst.vendor}")
        if inst.header is not None:
            out.append(f"  columns:     {' '.join(inst.header)} (no header line)")
        out.append(f"  reads:       {', '.join(f'{a} as {b}' for a, b in inst.columns)}")
        if inst.comments:
            out.append(f"  comments:    lines starting with {' or '.join(inst.comments)}")
        out.append(f"  orientation: {inst.orientation}")
        out.append("")
    lines = []
    for line in out:
        indent = len(line) - len(line.lstrip())
        lines += textwrap.wrap(line, 98, subsequent_indent=" " * (indent + 2)) or [""]
    return "\n".join(lines) + "\n"
