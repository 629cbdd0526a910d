"""The ``calib`` console command's entry point: Ctrl-C and SIGTERM handled from the first instant.

Python's start-up and ``import calib.cli.main`` take a moment on a cold start (numpy, scipy and
Pinocchio come later, inside :func:`calib.cli.main.main`, which handles the signals from there on).
A signal in that time would otherwise end the process with a traceback (SIGINT) or silently
(SIGTERM); here it ends it with the command's one line and exit code 128 + the signal, as
:func:`calib.cli.main.main` does later. Nothing has been written yet at that point.
"""
from __future__ import annotations

import os
import signal
import sys


def _stop(signum, frame) -> None:      # noqa: ARG001 - signal handler signature
    sys.stderr.write(f"calib: interrupted by {signal.Signals(signum).name}\n")
    sys.stderr.flush()
    os._exit(128 + signum)


def main() -> None:
    """Install the start-up handlers, import the command, hand over to :func:`calib.cli.main.main_entry`."""
    previous = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    from calib.cli.main import main_entry

    for s, handler in previous.items():
        signal.signal(s, handler)
    main_entry()
