"""The ``calib`` command: a thin layer over the Python API, one subcommand per job.

    calib identifiability ROBOT.urdf            which parameters the data can identify
    calib simulate ROBOT.urdf -o meas.csv       synthetic measurements of a perturbed robot
    calib calibrate ROBOT.urdf MEAS.csv -o calibrated.urdf
    calib evaluate ROBOT.urdf MEAS.csv          accuracy of a model against measurements
    calib select-poses ROBOT.urdf -n N -o poses.csv       configurations worth measuring
    calib plan ROBOT.urdf --poses N -o plan.csv --cell CELL.yaml   a plan the robot can run
    calib compensate CALIBRATED.urdf NOMINAL.urdf TARGETS.csv -o corrected.csv
    calib export CALIBRATED.urdf --format ur-yaml -o kinematics.yaml   for the user's stack
    calib formats                               column rules and vendor conventions

Exit codes: 0 success; 2 bad input or usage (one line ``calib: error: ...`` on stderr, no
output file created or changed); 3 ``calibrate`` ran but the fit did not converge, or
``compensate`` could not reach every target (outputs are written so that they can be
inspected, the status is printed on stderr); 130 / 143 interrupted by SIGINT / SIGTERM (one
line, no output changed); 1 is left to Python for unexpected internal errors (a bug: the
traceback says where).

Outputs are produced in memory first and written only when everything succeeded, as a set
(:mod:`calib.cli.output`); an output path that names an input is refused.

Each subcommand is one module of this package exposing ``add_parser(subparsers)`` and
``run(args) -> int`` (:data:`COMMAND_NAMES`); this module assembles the parser and runs the command
with the signals and errors handled once. numpy, scipy and Pinocchio are imported by the
subcommands when they run, not when this module is imported.
"""
from __future__ import annotations

import _signal      # (signal's C core: the signal module's enums cost 2.8M instructions of every start)
import argparse
import os
import logging
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Sequence

from calib.cli.args import ArgumentParser, HelpFormatter, add_verbose
from calib.cli.output import EXIT_INPUT, PROG, forget_written, written
from calib.errors import CalibError

__all__ = ["main", "main_entry", "build_parser", "COMMAND_NAMES", "command_module"]

log = logging.getLogger(__name__)

#: The subcommands, in the order ``calib --help`` lists them: each is the module
#: ``calib.cli.<name>`` (``select-poses``: ``select_poses``), imported when its parser is built
#: (a command line that names one loads that one only).
COMMAND_NAMES = ("identifiability", "simulate", "calibrate", "evaluate", "select-poses", "plan", "compensate",
                 "export", "formats")


def command_module(name: str):
    """The module of subcommand ``name`` (one of :data:`COMMAND_NAMES`), with its ``add_parser``
    and ``run``."""
    import importlib

    return importlib.import_module("calib.cli." + name.replace("-", "_"))


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the ``calib`` command; with ``command`` (a subcommand's name) the
    main parser with that subcommand's parser only (what :func:`main` parses a command line that
    names it with: the other subcommands' parsers are not built)."""
    from calib import __version__ as ver
    parser = ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Kinematic calibration of serial robots: TM-MDH error model, C-LM "
                    "identification (Lao et al. 2023), on Pinocchio.",
        epilog="Run `calib COMMAND --help` for each command. Exit codes: 0 success, 2 bad input "
               "(no file written), 3 calibration did not converge or a compensation target was "
               "not reached.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {ver}")
    add_verbose(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_NAMES:
        if command is None or name == command:
            command_module(name).add_parser(sub)
    return parser


def _named_command(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names when only -v / --verbose come before it; otherwise None (the
    whole parser then parses: help, version, usage errors, unknown commands)."""
    names = set(COMMAND_NAMES)
    for arg in argv:
        if arg in names:
            return arg
        if arg != "--verbose" and not (len(arg) > 1 and arg == "-" + "v" * (len(arg) - 1)):
            return None
    return None


# ====================================================================== entry points
class _ElapsedFormatter(logging.Formatter):
    """Log lines with the seconds since the command started (``%(elapsed)``)."""

    def __init__(self, fmt: str):
        super().__init__(fmt)
        self.start = time.monotonic()

    def format(self, record: logging.LogRecord) -> str:
        record.elapsed = time.monotonic() - self.start
        return super().format(record)


class Interrupted(BaseException):
    """A termination signal (SIGTERM) received while a command runs (SIGINT arrives as
    KeyboardInterrupt); a BaseException so that no ``except Exception`` swallows it."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: Signals received after the running command's outputs were put in place (recorded, not
#: raised: the work they would stop is done; main reports them and keeps the command's code).
_LATE: list[int] = []


def _raise_interrupted(signum, frame):
    """SIGTERM / SIGINT handler while a command runs: stop it (Interrupted, KeyboardInterrupt),
    unless its outputs are already in place."""
    if written():
        _LATE.append(signum)
        return
    if signum == _signal.SIGINT:
        raise KeyboardInterrupt
    raise Interrupted(signum)


def _signal_name(signum: int) -> str:
    """The name of a signal (SIGINT, SIGTERM), for the messages of an interruption."""
    from signal import Signals

    return Signals(signum).name


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _run(args) -> int:
    """``args.func(args)`` with library warnings (numpy, scipy) kept off the terminal: logged at
    debug level (``-vv``) instead."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return args.func(args)
        finally:
            for w in caught:
                log.debug("warning from %s:%d: %s", Path(w.filename).name, w.lineno, _one_line(w.message))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``calib`` command with ``argv`` (default ``sys.argv[1:]``); return the exit code.

    Bad input: one line ``calib: error: ...`` on stderr and 2. SIGINT / SIGTERM: one line
    ``calib: interrupted by SIGINT`` and 130 / 143 (128 + the signal number); outputs are
    committed as a set with the signals held back, so none is half-written."""
    argv = list(sys.argv[1:] if argv is None else argv)
    root_log = logging.getLogger("calib")     # every module logs as calib.<module>
    handler = None
    previous = {}
    forget_written()
    _LATE.clear()
    if threading.current_thread() is threading.main_thread():
        previous = {s: _signal.signal(s, _raise_interrupted) for s in (_signal.SIGINT, _signal.SIGTERM)}
    try:
        # the parser's choices and defaults come from the library: building it imports numpy
        # and Pinocchio, so a signal may land here too
        parser = build_parser(_named_command(argv))
        try:
            args = parse_arguments(parser, argv)
        except SystemExit as exc:  # --help, --version (0) and usage errors (2)
            return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else EXIT_INPUT)
        args.argv = argv

        if args.verbose:
            handler = logging.StreamHandler(sys.stderr)
            handler.setFormatter(_ElapsedFormatter(f"{PROG}: %(message)s  [%(elapsed).2f s]"))
            root_log.addHandler(handler)
            root_log.setLevel(logging.DEBUG if args.verbose > 1 else logging.INFO)
        return _run(args)
    except CalibError as exc:
        sys.stderr.write(f"{PROG}: error: {_one_line(exc)}\n")
        return EXIT_INPUT
    except OSError as exc:     # an input or output the system refuses (permissions, full disk)
        where = f"{exc.filename}: " if exc.filename else ""
        sys.stderr.write(f"{PROG}: error: {where}{_one_line(exc.strerror or exc)}\n")
        return EXIT_INPUT
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: interrupted by SIGINT\n")
        return 128 + _signal.SIGINT
    except Interrupted as exc:
        name = _signal_name(exc.signum)
        sys.stderr.write(f"{PROG}: interrupted by {name}\n")
        return 128 + exc.signum
    finally:
        for s, h in previous.items():
            _signal.signal(s, h)
        if _LATE:
            sys.stderr.write(f"{PROG}: {_signal_name(_LATE[0])} received after the outputs were written "
                             f"({', '.join(str(p) for p in written())}): they are complete\n")
        if handler is not None:
            root_log.removeHandler(handler)
            root_log.setLevel(logging.NOTSET)


def parse_arguments(parser: argparse.ArgumentParser, argv) -> argparse.Namespace:
    """``argv`` parsed by the command's ``parser`` (:func:`build_parser`); arguments left over are
    reported by the subcommand's parser, so that its usage line is shown (SystemExit 2)."""
    args, extra = parser.parse_known_args(argv)
    if extra:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        extra = _late_positionals(sub.choices[args.command], args, list(extra))
        if extra:
            sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def _late_positionals(parser: argparse.ArgumentParser, args: argparse.Namespace, extra: list[str]) -> list[str]:
    """The arguments left over once the optional positionals (nargs "?": MEAS.csv of calibrate and
    evaluate, which --bag replaces) that argparse left empty are filled from them, in order:
    argparse fills such a positional only from the run of positionals it parses it with, so
    ``ROBOT --ur-type ur5e MEAS.csv`` left MEAS.csv over (python/cpython#59317)."""
    for action in parser._actions:
        if not action.option_strings and action.nargs == "?" and getattr(args, action.dest, None) is None \
                and extra and not extra[0].startswith("-"):
            setattr(args, action.dest, extra.pop(0))
    return extra


def main_entry() -> None:
    """Console-script entry point: ``sys.exit(main())`` with one BLAS thread. calib's matrices
    are small (tens of columns): BLAS threads only add start-up and, on a busy machine,
    contention (a 70 ms calibration was seen taking 2 s with them).

    numpy is imported by the commands, after this point: the BLAS libraries read their thread
    count from the environment when they load, so it is set there (threadpoolctl, which limits
    the libraries already loaded, limited none: the commands ran with one BLAS thread per core).
    When numpy is already loaded (main_entry called from a Python program) threadpoolctl does it."""
    import contextlib

    from calib.threads import LIMITER

    if "numpy" not in sys.modules:          # (this process's own environment: the command's)
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = "1"
        LIMITER.disabled = True
        limit = contextlib.nullcontext()
    else:
        limit = LIMITER.limit()
    # (main's handlers on both sides of main: a signal before it stops with the one line, one
    # after it is recorded when the outputs are in place; then ignored while Python exits, so
    # that the exit code stays the command's)
    for s in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(s, _raise_interrupted)
    try:
        with limit:
            code = main()
    except (Interrupted, KeyboardInterrupt) as exc:     # (outside main's run: nothing written)
        signum = getattr(exc, "signum", _signal.SIGINT)
        sys.stderr.write(f"{PROG}: interrupted by {_signal_name(signum)}\n")
        code = 128 + signum
    for s in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(s, _signal.SIG_IGN)
    sys.exit(code)
