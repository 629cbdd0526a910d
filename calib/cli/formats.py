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
                                              "conventions (--convention), instrument presets (--instrument), "
                                              "ROS bags and xacros",
                              description="Print every column rule of calib's measurement, poses and "
                                          "targets files, the table of vendor conventions that "
                                          "--convention NAME reads, the instrument presets of "
                                          "--instrument NAME, and how ROS bags (--bag) and "
                                          "xacro robot descriptions are read.",
                              formatter_class=HelpFormatter)
    p.add_argument("--markdown", action="store_true",
                   help="print only the conventions table, in Markdown (as in docs/formats.md)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Print the help page (or the Markdown table); returns 0."""
    from calib.io.csv.conventions import format_help, markdown_table

    if args.markdown:
        sys.stdout.write(markdown_table())
        return EXIT_OK
    from calib.io.bag.reader import FORMAT_HELP as BAGS
    from calib.io.urdf.xacro_file import FORMAT_HELP as XACROS

    sys.stdout.write(format_help() + "\n" + BAGS + "\n" + XACROS)
    return EXIT_OK
