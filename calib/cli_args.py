"""Argument types and the help formatter shared by the ``calib`` subcommands."""
from __future__ import annotations

import argparse
import math


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
    value = nonnegative(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"{text} must be > 0")
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
    from .errors import CalibError
    from .formats.csv_layer import parse_rename

    try:
        return parse_rename(text)
    except CalibError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _euler(text: str) -> str:
    from .errors import CalibError
    from .formats.csv_layer import check_euler_sequence

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
    group: --rename, --euler, --limit-tolerance, and with ``tracker`` --tracker and --key."""
    g = p.add_argument_group("file format (see README, Measurement file format)")
    g.add_argument("--rename", metavar="OLD=NEW[,...]", type=_rename, default=None,
                   help="rename the file's columns to calib's names before reading, e.g. "
                        "'X=x_mm,Y=y_mm,Z=z_mm'; OLD= (empty NEW) drops a column")
    g.add_argument("--euler", metavar="SEQ", type=_euler, default=None,
                   help="axis sequence of the e1, e2, e3 angle columns in scipy's notation: upper "
                        "case intrinsic (ZYX, ZYZ, ...), lower case extrinsic (xyz, ...)")
    g.add_argument("--limit-tolerance", metavar="F", type=_fraction, default=0.01,
                   help="keep joint readings at most this fraction of the joint range past a "
                        "limit (with a note); 0.01 or 1%%")
    if tracker:
        g.add_argument("--tracker", metavar="POSES.csv", default=None,
                       help="the measured poses (x, y, z and an orientation) in a second file, "
                            "joined to the joint file row by row by --key")
        g.add_argument("--key", metavar="COLUMN", default=None,
                       help="column present in both files whose values pair their rows (e.g. a "
                            "point name), in any order")


def read_options(args: argparse.Namespace, *, joined: bool = True):
    """The :class:`calib.formats.ReadOptions` of parsed file-format options (``joined=False``:
    without the key, for a file read on its own)."""
    from .formats import ReadOptions

    return ReadOptions(rename=args.rename or (), euler=args.euler, limit_tolerance=args.limit_tolerance,
                       key=getattr(args, "key", None) if joined else None)


def print_notes(notes, prog: str = "calib") -> None:
    """Each note of a reading (ignored columns, readings kept past a limit) as one stderr line."""
    import sys

    for note in notes:
        sys.stderr.write(f"{prog}: note: {' '.join(str(note).split())}\n")
