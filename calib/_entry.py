"""The ``calib`` console command's entry point: Ctrl-C and SIGTERM handled from the first instant.

Python's start-up and ``import calib.cli.main`` take a moment on a cold start (numpy, scipy and
Pinocchio come later, inside :func:`calib.cli.main.main`, which handles the signals from there on).
A signal in that time would otherwise end the process with a traceback (SIGINT) or silently
(SIGTERM); here it ends it with the command's one line and exit code 128 + the signal, as
:func:`calib.cli.main.main` does later. Nothing has been written yet at that point.

The console script and ``python -m calib`` run :func:`console`: the command, then the end of
the process without the interpreter's teardown (freeing every module, Pinocchio's and numpy's
included, took ~45 ms of a ~300 ms ``calib calibrate``), once the command's outputs are
committed and stdout and stderr flushed.
"""
from __future__ import annotations

import _signal      # (signal's C core: the signal module's enums cost 2.8M instructions of every start)
import gc
import os
import sys


#: The signals :func:`_stop` handles, by name.
_NAMES = {_signal.SIGINT: "SIGINT", _signal.SIGTERM: "SIGTERM"}


def _stop(signum, frame) -> None:      # noqa: ARG001 - signal handler signature
    sys.stderr.write(f"calib: interrupted by {_NAMES[signum]}\n")
    sys.stderr.flush()
    os._exit(128 + signum)


#: The cyclic garbage collector's first-generation threshold in the command (Python's default
#: 700): importing calib, numpy and Pinocchio allocates ~10^5 container objects, none of them
#: garbage, and the collections that the default threshold set off traversed them again and
#: again (22M of ~1,150M instructions of ``calib calibrate`` on the bundled example). Cyclic
#: garbage is still collected, every 50,000 allocations: a few MB at most.
GC_THRESHOLD = 50_000


def main() -> None:
    """Install the start-up handlers, import the command, hand over to :func:`calib.cli.main.main_entry`."""
    previous = {s: _signal.signal(s, _stop) for s in _NAMES}
    gc.set_threshold(GC_THRESHOLD, *gc.get_threshold()[1:])
    from calib.cli.main import main_entry

    for s, handler in previous.items():
        _signal.signal(s, handler)
    main_entry()


def console() -> None:
    """The ``calib`` command (console script, ``python -m calib``): :func:`main`, then the exit
    handlers (atexit: logging's, weakref finalizers, a coverage tool's), stdout and stderr
    flushed, and ``os._exit`` with its exit code, skipping the interpreter's teardown of the
    modules (the outputs are written and closed by then). Python's own exit instead when a
    profiler or tracer runs (``python -m cProfile -m calib``: it reports after the command) or a
    stream cannot be flushed (a closed pipe: Python reports it as before). An exception other
    than SystemExit (a bug) is Python's to report."""
    import atexit

    try:
        main()
    except SystemExit as exc:
        code = exc.code
        if (code is None or isinstance(code, int)) and sys.gettrace() is None and sys.getprofile() is None:
            atexit._run_exitfuncs()
            try:
                for stream in (sys.stdout, sys.stderr):
                    if stream is not None:
                        stream.flush()
            except (OSError, ValueError):
                raise exc from None
            os._exit(code or 0)
        raise
