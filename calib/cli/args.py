"""What the ``calib`` subcommands share: argument types, the help formatter, the common options
(robot, frames, file format, compliance, targets, -v), and the loading of the robot and the
measurements from them."""
from __future__ import annotations

import argparse
import logging
import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:       # numpy is imported where it is used: the CLI starts without it
    import numpy as np


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks; appends "(default: ...)" where there is one."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "%(default)" not in text and not any(action.default is v for v in (None, False, argparse.SUPPRESS)) \
                and action.option_strings and not isinstance(action, argparse._VersionAction):
            text += " (default: %(default)s)"
        return text


class ArgumentParser(argparse.ArgumentParser):
    """argparse with short usage errors: one usage line (the positional arguments and required
    options, ``[options]`` for the rest) and one ``calib: error: ...`` line, exit code 2.
    Subcommand parsers made with ``add_subparsers`` inherit the class."""

    def error(self, message: str):
        message = " ".join(str(message).split())
        self.exit(2, f"usage: {self.short_usage()}\n{self.prog.split()[0]}: error: {message}\n")

    def short_usage(self) -> str:
        parts, optional = [self.prog], False
        for action in self._actions:
            if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
                continue
            if isinstance(action, argparse._SubParsersAction):
                parts.append("COMMAND ...")
            elif not action.option_strings:
                parts.append(str(action.metavar or action.dest))
            elif action.required:
                parts.append(f"{action.option_strings[0]} {action.metavar or action.dest.upper()}")
            else:
                optional = True
        if optional:
            parts.insert(1, "[options]")
        return " ".join(parts) + f"  (help: {self.prog} --help)"


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be at least 1")
    return value


def count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} must not be negative")
    return value


def nonnegative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number >= 0")
    return value


def positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):    # (-1 is told > 0, not >= 0: 0 is refused too)
        raise argparse.ArgumentTypeError(f"{text} must be a finite number > 0")
    return value


def add_frames(p: argparse.ArgumentParser, base_help: str | None = None,
               tool_help: str | None = None) -> None:
    """The --base-frame / --tool-frame options, in their own help group."""
    g = p.add_argument_group("frames")
    g.add_argument("--base-frame", metavar="F", default=None,
                   help=base_help or "URDF link (or joint) that plays the measurement frame; the "
                                     "measured poses are in it (default: the root link)")
    g.add_argument("--tool-frame", metavar="F", default=None,
                   help=tool_help or "URDF link (or joint) whose pose is measured (default: the "
                                     "last link before the tree branches)")


# ---------------------------------------------------------------------- file-format options
def _rename(text: str):
    from calib.errors import CalibError
    from calib.io.csv.options import parse_rename

    try:
        return parse_rename(text)
    except CalibError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _columns(text: str):
    from calib.errors import CalibError
    from calib.io.csv.instruments import parse_columns

    try:
        return parse_columns(text)
    except CalibError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _euler(text: str) -> str:
    from calib.errors import CalibError
    from calib.io.csv.options import check_euler_sequence

    try:
        return check_euler_sequence(text)
    except CalibError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fraction(text: str) -> float:
    """A fraction in [0, 1], written 0.01 or 1%."""
    percent = text.strip().endswith("%")
    try:
        value = float(text.strip().rstrip("%")) / (100.0 if percent else 1.0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a fraction (0.01) or a percentage "
                                         f"(1%)") from None
    if not (math.isfinite(value) and 0 <= value <= 1):
        raise argparse.ArgumentTypeError(f"{text} must be between 0 and 1 (0% and 100%)")
    return value


def add_file_format(p: argparse.ArgumentParser, *, tracker: bool = False) -> None:
    """The options that read CSV files as trackers and controllers write them, in their own help
    group: --rename, --euler, --convention, --header-line, --limit-tolerance, and with
    ``tracker`` --tracker and --key."""
    g = p.add_argument_group("file format (see calib formats, docs/formats.md)")
    g.add_argument("--rename", metavar="OLD=NEW[,...]", type=_rename, default=None,
                   help="rename the file's columns to calib's names before reading, e.g. "
                        "'X=x_mm,Y=y_mm,Z=z_mm'; OLD= (empty NEW) drops a column")
    g.add_argument("--euler", metavar="SEQ", type=_euler, default=None,
                   help="axis sequence of the e1, e2, e3 angle columns in scipy's notation: upper "
                        "case intrinsic (ZYX, ZYZ, ...), lower case extrinsic (xyz, ...)")
    from calib.io.csv.conventions import CONVENTION_NAMES

    g.add_argument("--convention", choices=CONVENTION_NAMES, default=None,
                   help="the column names and units a vendor's controller writes (KUKA A1..A6, "
                        "X, Y, Z, A, B, C; ABB rax_1.., q1..q4; UR base..wrist3, x, y, z in m, "
                        "rx, ry, rz rotation vector, RTDE actual_q_*, actual_TCP_pose_*; ...): "
                        "`calib formats` lists every mapping; 'calib' states calib's own ZYX "
                        "reading of rx, ry, rz in any column order")
    from calib.io.csv.instruments import INSTRUMENT_NAMES, LENGTH_UNIT_NAMES

    g.add_argument("--instrument", choices=INSTRUMENT_NAMES, default=None,
                   help="the instrument's file as its software exports it (the tracker file of "
                        "--tracker, else the measurement file): leica (Q0..Q3 a quaternion, Q0 the "
                        "scalar; X [mm] ...), spatialanalyzer (no header line: Collection Group Target "
                        "X Y Z, // comments; give --length-unit); `calib formats` lists them, docs/instruments.md "
                        "shows them")
    g.add_argument("--columns", metavar="NAMES", type=_columns, default=None,
                   help="the column names of a file without a header line, in order, comma separated "
                        "(e.g. 'point,x_mm,y_mm,z_mm'): the instrument's file, as --instrument")
    g.add_argument("--length-unit", choices=LENGTH_UNIT_NAMES, default=None,
                   help="the unit of x, y, z columns named without one (a SpatialAnalyzer export's "
                        "X Y Z are in the job's units, which the file does not state)")
    g.add_argument("--header-line", metavar="N", type=positive_int, default=None,
                   help="line number of the header (default: the first line that names known "
                        "columns; a preamble before it is skipped)")
    g.add_argument("--limit-tolerance", metavar="F", type=_fraction, default=0.01,
                   help="keep joint readings at most this fraction of the joint range past a "
                        "limit (with a note); 0.01 or 1%%")
    if tracker:
        from calib.choices import JOINS, TIME_UNITS

        g.add_argument("--tracker", metavar="POSES.csv", default=None,
                       help="the measured poses (x, y, z and an orientation) in a second file, "
                            "joined to the joint file row by row by --key")
        g.add_argument("--key", metavar="COLUMN|JOINT=TRACKER", default=None,
                       help="column present in both files whose values pair their rows (e.g. a "
                            "point name), in any order; JOINT=TRACKER when the files name it "
                            "differently (--key Point=Target); one joint row may go with several "
                            "measured rows, each with its target id (--target-column, "
                            "--target-from, or a target column)")
        g.add_argument("--target-column", metavar="COLUMN", default=None,
                       help="column of the tracker file holding the id of the target (reflector) "
                            "measured in each row (default: a column named target)")
        g.add_argument("--target-from", metavar="REGEX", default=None,
                       help="take key and target id from compound point names in the tracker "
                            "file's --key column: a Python regular expression that must match "
                            "the whole name, with the named groups key (matched to the joint "
                            "file's key) and target, e.g. '(?P<key>P\\d+)_(?P<target>SMR\\d+)' "
                            "splits P001_SMR2 into P001 and SMR2")
        g.add_argument("--join", choices=JOINS, default="key",
                       help="how the files' rows are paired: by --key, or each measured "
                            "row with the joint row of the nearest timestamp (--time, --max-gap)")
        g.add_argument("--time", metavar="COLUMN|JOINT=TRACKER", default=None,
                       help="with --join nearest-time: the timestamp column of both files (JOINT=TRACKER "
                            "when they name it differently: --time 'timestamp=Time [s]'), numbers "
                            "with the unit in the name (time_s, Time [s], time_ms, time_us, time_ns) or "
                            "--time-unit, or times of day (10:00:07.125), or ISO 8601 dates and times")
        g.add_argument("--time-unit", choices=TIME_UNITS, default=None,
                       help="unit of the --time column's numbers when its name does not say it")
        g.add_argument("--max-gap", metavar="S", type=nonnegative, default=None,
                       help="with --join nearest-time: the largest time in seconds between a "
                            "measured row and its joint row (a farther row is an error; so are "
                            "two joint rows of different joint values equally near)")


def read_options(args: argparse.Namespace, *, joined: bool = True):
    """The :class:`calib.io.csv.specs.ReadOptions` of parsed file-format options (``joined=False``:
    without the key, for a file read on its own)."""
    from calib.io.csv.specs import ReadOptions

    join = {}
    if joined:
        join = {k: getattr(args, k, None) for k in ("key", "target_column", "target_from", "time",
                                                    "time_unit", "max_gap")}
        join["join"] = getattr(args, "join", None) or "key"
    return ReadOptions(rename=args.rename or (), euler=args.euler, limit_tolerance=args.limit_tolerance,
                       convention=args.convention, header_line=args.header_line,
                       instrument=getattr(args, "instrument", None), columns=getattr(args, "columns", None),
                       length_unit=getattr(args, "length_unit", None), **join)


def print_notes(notes, prog: str = "calib") -> None:
    """Each note of a reading (ignored columns, readings kept past a limit) as one stderr line."""
    import sys

    for note in notes:
        sys.stderr.write(f"{prog}: note: {' '.join(str(note).split())}\n")


def add_compliance(p: argparse.ArgumentParser, role: str):
    """The joint-compliance options (calib.model.compliance), in their own help group. ``role``:
    "calibrate" (--compliance is a flag), "compensate" or "evaluate" (--compliance FILE) or
    "simulate" (no --compliance: the --deviations JSON names c<i>). Returns the help group."""
    g = p.add_argument_group("joint compliance under gravity (q + c_i tau_i(q))")
    if role == "calibrate":
        g.add_argument("--compliance", action="store_true",
                       help="joint compliances c<i> (urad/(N m); um/N prismatic) under the gravity "
                            "torque of the links (URDF inertias) and the payload: calibrate "
                            "identifies them (into the report and CALIBRATED.compliance.json beside "
                            "the URDF), identifiability says which the poses can see")
    elif role in ("compensate", "evaluate"):
        g.add_argument("--compliance", metavar="REPORT.json|SIDECAR.json", default=None,
                       help=("correct for joint compliance too" if role == "compensate" else
                             "apply joint compliance to the model (a note on stderr says so)")
                       + ": the JSON report of calib calibrate --compliance, or the "
                         "CALIBRATED.compliance.json written beside the URDF")
    g.add_argument("--payload-kg", metavar="M", default=None,
                   help="payload mass, kg (default: the one in the compliance file, else none)")
    g.add_argument("--payload-com-mm", metavar="X,Y,Z", default=None,
                   help="payload centre of mass in the tool frame, mm (default 0,0,0)")
    g.add_argument("--gravity", metavar="X,Y,Z", default=None,
                   help="gravity in the URDF root frame, m/s^2 (default 0,0,-9.80665)")
    return g


def compliance_options(args):
    """(payload or None, gravity (3,) or None) from the options of :func:`add_compliance`;
    :class:`calib.ParameterError` naming the option for bad values."""
    import numpy as np

    from calib.errors import ParameterError

    payload = None
    if args.payload_kg is not None:
        try:
            mass = float(args.payload_kg)
        except ValueError:
            raise ParameterError(f"--payload-kg {args.payload_kg!r}: expected a mass in kg") from None
        if not (math.isfinite(mass) and mass >= 0):
            raise ParameterError(f"--payload-kg {args.payload_kg}: expected a finite mass >= 0 kg")
        com = (np.zeros(3) if args.payload_com_mm is None
               else parse_triple(args.payload_com_mm, "--payload-com-mm", 1e-3))
        from calib.model.compliance import Payload

        payload = Payload(mass, com)
    elif args.payload_com_mm is not None:
        raise ParameterError("--payload-com-mm without --payload-kg: give the payload mass too")
    gravity = None if args.gravity is None else parse_triple(args.gravity, "--gravity")
    return payload, gravity


def with_compliance_file(robot, args, *, torques_from=None, hint: str = ""):
    """``robot`` with the compliances of ``--compliance FILE`` (a sidecar or a calibration
    report, :func:`calib.io.compliance_file.read_compliance`) and the payload and gravity of the options,
    else of the file; unchanged without ``--compliance``. torques_from : the model whose URDF
    gives the gravity torques (default ``robot``; see :func:`calib.io.compliance_file.apply_record`).
    :class:`calib.ParameterError` for --payload-kg or --gravity without --compliance (``hint``
    ends that message)."""
    from calib.errors import ParameterError

    payload, gravity = compliance_options(args)
    if args.compliance is None:
        if payload is not None or gravity is not None:
            raise ParameterError(f"--payload-kg and --gravity need --compliance{hint}")
        return robot
    from calib.io.compliance_file import apply_record, read_compliance

    return apply_record(robot, read_compliance(args.compliance), payload=payload, gravity=gravity,
                        torques_from=torques_from, source=args.compliance)


def _target_offset(text: str) -> tuple[str, tuple[float, float, float]]:
    """``ID=X,Y,Z`` (mm) of ``--target``."""
    tid, sep, rest = text.partition("=")
    try:
        xyz = tuple(float(v) for v in rest.split(","))
    except ValueError:
        xyz = ()
    if not sep or not tid.strip() or len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
        raise argparse.ArgumentTypeError(f"expected ID=X,Y,Z (millimetres in the tool frame), got {text!r}")
    return tid.strip(), xyz


def add_targets(p: argparse.ArgumentParser) -> None:
    """``--target ID=X,Y,Z`` (repeated): targets at known points of the tool, each measured at
    every pose (see :func:`with_targets`)."""
    p.add_argument("--target", dest="targets", type=_target_offset, action="append", default=None,
                   metavar="ID=X,Y,Z", help="a target (reflector) on the tool at X,Y,Z mm in the tool "
                   "frame, measured at every pose; repeat for each (two or more)")


def with_targets(robot, args: argparse.Namespace):
    """``robot`` with the ``--target`` offsets of ``args`` (unchanged without any);
    :class:`calib.ParameterError` unless two or more distinct ids are given."""
    if not getattr(args, "targets", None):
        return robot
    from calib.errors import ParameterError

    ids = [t for t, _ in args.targets]
    if len(ids) < 2 or len(set(ids)) != len(ids):
        raise ParameterError(f"--target: give two or more targets with distinct ids, got {', '.join(ids)}")
    return robot.with_target_offsets({t: [v * 1e-3 for v in xyz] for t, xyz in args.targets})


COMMON_EPILOG = """
Units: the measurement CSV carries its units in its column names (joint1_deg, x_mm, ...); printed
positions are in mm, orientations in rad. Exit codes: 0 success, 2 bad input (one-line message on
stderr, no file written)."""


def add_verbose(p: argparse.ArgumentParser, *, top: bool = False,
                help: str = "log progress on stderr (-vv: also the nominal model)") -> None:
    """-v / --verbose: on the main parser (``top``) it counts from 0; on a subcommand's it adds
    to the count given before the subcommand."""
    p.add_argument("-v", "--verbose", action="count", default=0 if top else argparse.SUPPRESS,
                   help=help)


def add_report_options(p: argparse.ArgumentParser, *, residuals: bool = True) -> None:
    """The certificate options of a report: --meta, --tolerance-mm (and --residuals)."""
    p.add_argument("--meta", action="append", default=None, metavar="KEY=VALUE,...|FILE.yaml|FILE.json",
                   help="identity fields of the HTML and JSON report, e.g. robot_serial=R123,instrument="
                        "'AT960 #4711',operator=J. Doe, or a YAML / JSON file of such fields (a mapping); "
                        "may be repeated (the fields: docs/certificate.md)")
    p.add_argument("--tolerance-mm", type=positive, default=None, metavar="T",
                   help="position tolerance of the report's verdict (mm): pass when every position error of "
                        "the held-out rows (without them: the calibration rows without the outliers) is "
                        "within T")
    if residuals:
        p.add_argument("--residuals", choices=("auto", "json", "csv", "none"), default="auto",
                       help="per-row residuals of --report: json inline (as columns), csv in REPORT.residuals.csv "
                            "beside it, none; auto (default): inline up to 20,000 rows, csv above")


def add_progress(p: argparse.ArgumentParser) -> None:
    """--progress: draw the progress line even when stderr is not a terminal."""
    p.add_argument("--progress", action="store_true",
                   help="show progress (fraction done, time left) on stderr even when it is not a terminal "
                        "(by default only on a terminal)")


def progress_enabled(args: argparse.Namespace) -> bool | None:
    """True when --progress was given (draw even off a terminal), None otherwise (draw on a
    terminal only)."""
    return True if getattr(args, "progress", False) else None


def parse_meta(values) -> dict:
    """The identity fields of ``--meta`` options (each ``key=value,...`` or a YAML / JSON file of
    a mapping); ParameterError (one line naming the option or the file) otherwise."""
    from calib.errors import ParameterError

    meta: dict[str, str] = {}
    for text in values or ():
        text = text.strip()
        if "=" not in text:
            from calib.io.report_meta import read_meta

            fields = read_meta(text)
        else:
            fields = {}
            for part in text.split(","):
                key, sep, value = part.partition("=")
                if not sep or not key.strip() or not value.strip():
                    raise ParameterError(f"--meta {text!r}: expected KEY=VALUE pairs separated by commas "
                                         f"(robot_serial=R123,instrument=AT960,operator=J. Doe) or a "
                                         f"YAML / JSON file")
                if key.strip() in fields and fields[key.strip()] != value.strip():
                    raise ParameterError(f"--meta: {key.strip()} given twice ({fields[key.strip()]!r} and "
                                         f"{value.strip()!r})")
                fields[key.strip()] = value.strip()
        for key, value in fields.items():
            if key in meta and meta[key] != value:
                raise ParameterError(f"--meta: {key} given twice ({meta[key]!r} and {value!r})")
            meta[key] = value
    from calib.report.identity import check_fields

    check_fields(meta)       # (dates, the certificate number) before any work
    return meta


def meta_inputs(values) -> dict:
    """The identity files among ``--meta`` options (a value without ``=``) as report inputs:
    ``{"meta": path}``, or ``{"meta": ..., "meta 2": ...}`` for several (their sha256 go into the
    report's provenance)."""
    files = [v.strip() for v in values or () if "=" not in v]
    return {("meta" if k == 0 else f"meta {k + 1}"): f for k, f in enumerate(files)}


def read(path, robot, args: argparse.Namespace, tracker=None, *, joined: bool = True):
    """The measurements of ``path`` for ``robot``, read with the file-format options (its notes
    on stderr)."""
    from calib.cli.progress import working
    from calib.io.csv.specs import read_measurements

    log = logging.getLogger("calib.cli")
    with working(f"reading {path}", logger=log, enabled=progress_enabled(args)):
        m = read_measurements(path, robot, tracker=tracker, options=read_options(args, joined=joined))
    log.info("read %r", m)
    print_notes(m.notes)
    return m


def parse_triple(text: str, option: str, scale: float = 1.0) -> np.ndarray:
    """(3,) from "X,Y,Z" (times ``scale``); ParameterError naming ``option`` otherwise."""
    import numpy as np

    from calib.errors import ParameterError

    parts = [s.strip() for s in str(text).split(",")]
    try:
        v = np.array([float(s) for s in parts])
    except ValueError:
        raise ParameterError(f"{option} {text!r}: expected three numbers X,Y,Z") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ParameterError(f"{option} {text!r}: expected three finite numbers X,Y,Z")
    return v * scale


def check_measurement_link(name, robot) -> None:
    """Refuse a --measurement-link name that is empty, has spaces or is a link of the URDF
    (calibrate, of measurement and touch files)."""
    from calib.errors import ParameterError

    if name is None:
        return
    if not name.strip() or any(c.isspace() for c in name):
        raise ParameterError(f"--measurement-link: expected a link name without spaces, got {name!r}")
    links = () if robot.source is None else robot.source.document.links
    if robot.source is None:
        raise ParameterError("--measurement-link needs a robot read from a URDF")
    if name in links:
        raise ParameterError(f"--measurement-link {name}: {robot.urdf_path} has a link of that name already; "
                             f"choose a new name")


def is_touch_input(args: argparse.Namespace) -> bool:
    """Whether ``calibrate``'s measurement file is a touch file (its header names point, plane or
    sphere); False for a file that cannot be read (the measurement reader then says why)."""
    from pathlib import Path

    from calib.errors import CalibError
    from calib.io.csv.touch import is_touch_file

    if getattr(args, "tracker", None) is not None or args.measurements is None or not Path(args.measurements).is_file():
        return False
    try:
        options = read_options(args, joined=False)
        columns, comments = None, ()
        if options.instrument is not None or options.columns is not None:
            from calib.io.csv.instruments import file_columns

            columns, comments, _ = file_columns(options)
        return is_touch_file(args.measurements, options.header_line, options.rename, columns, comments)
    except CalibError:
        return False
