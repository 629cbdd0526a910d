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
