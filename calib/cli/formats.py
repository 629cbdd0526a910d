"""``calib formats``: the column rules of calib's files and the vendor conventions, as a help page
(an installed wheel needs no documentation); ``--markdown`` prints the conventions table of docs/formats.md."""
from __future__ import annotations

import argparse
import sys

from calib.cli.args import HelpFormatter
from calib.cli.output import EXIT_OK

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``formats`` to ``subparsers``; it runs :func:`run`."""
    p = subparsers.add_parser("formats", help="the column rules of measurement files, the vendor "
                                              "conventions (--convention) and instrument presets (--instrument)",
                              description="Print every column rule of calib's measurement, poses and "
                                          "targets files, the table of vendor conventions that "
                                          "--convention NAME reads and the instrument presets of "
                                          "--instrument NAME.",
                              formatter_class=HelpFormatter)
    p.add_argument("--markdown", action="store_true",
                   help="print only the conventions table, in Markdown (as in docs/formats.md)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Print the help page (or the Markdown table); returns 0."""
    from calib.io.csv.conventions import format_help, markdown_table

    sys.stdout.write(markdown_table() if args.markdown else format_help())
    return EXIT_OK
