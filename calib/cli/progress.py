"""Progress of long stages on stderr, and stage logging.

Used by ``calibrate`` (reading: time elapsed; the calibration: its stage, the fraction done by
the stages' shares of the time and the time left; the report stage: rows, plots, JSON, HTML
with the fraction done and the time left), ``evaluate --html`` and ``select-poses`` (the
candidates' Jacobians, the greedy start and each exchange pass). ``--progress`` draws the line
also when stderr is not a terminal.

:class:`Progress` draws one line (``label: 120/400 (30%), 12 s elapsed, ~28 s left``) on a
stream that is a terminal, once a stage has run for :data:`SHOW_AFTER_S` seconds, redrawn at
most every :data:`REDRAW_S` seconds; on anything else (a pipe, a log file, a test's captured
stderr) it draws nothing. The remaining time is estimated only once some work is done: before
that it reads ``estimating...``, never ``nan``.

:func:`stage` logs the start and the end (with its duration) of a stage on a ``calib.*`` logger
(``-v`` shows them).
"""
from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from typing import IO, Iterator

__all__ = ["Progress", "format_eta", "stage", "working"]

#: A stage shows progress once it has run this long (seconds).
SHOW_AFTER_S = 2.0
#: Smallest interval between two redraws (seconds).
REDRAW_S = 0.2
#: Units of work of a stage measured as a fraction (:meth:`Progress.fraction`).
FRACTION_UNITS = 1000


def format_eta(elapsed: float, done: float, total: float) -> str:
    """``"~28 s left"`` (or min / h) from the time spent on ``done`` of ``total`` units of work;
    ``"estimating..."`` while nothing is done or the numbers cannot give an estimate."""
    if not (done > 0 and total > 0 and math.isfinite(elapsed) and elapsed >= 0):
        return "estimating..."
    left = elapsed * max(total - done, 0.0) / done
    if not math.isfinite(left):
        return "estimating..."
    if left < 90:
        return f"~{left:.0f} s left"
    if left < 5400:
        return f"~{left / 60:.1f} min left"
    return f"~{left / 3600:.1f} h left"


class Progress:
    """Progress of a stage of ``total`` units of work (rows, candidates, cases ...).

    ``stream`` defaults to stderr; ``enabled`` (default: whether ``stream`` is a terminal)
    decides whether anything is drawn. Use as a context manager, call :meth:`update` with the
    units done since the last call (or :meth:`set` with the units done so far).
    """

    def __init__(self, total: int, label: str, *, stream: IO[str] | None = None,
                 enabled: bool | None = None, show_after: float | None = None):
        self.total, self.label = max(int(total), -1), label
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.show_after = SHOW_AFTER_S if show_after is None else show_after
        self.done = 0
        self.stage: str | None = None
        self.t0 = time.monotonic()
        self._last_draw = -math.inf
        self._drawn = False

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.set(self.done + n)

    def set(self, done: int, total: int | None = None) -> None:
        """``done`` units so far (and, when given, a new ``total``: an estimate revised)."""
        if total is not None:
            self.total = max(int(total), -1)
        self.done = min(max(int(done), 0), self.total) if self.total > 0 else int(done)
        now = time.monotonic()
        if self.enabled and now - self.t0 >= self.show_after and (now - self._last_draw >= REDRAW_S
                                                                  or self.done == self.total):
            self._draw(now)

    def fraction(self, done: float, stage: str | None = None) -> None:
        """Work measured as a fraction (0..1) done, in the stage named ``stage``: the line shows
        the stage, the percentage and the time left (:data:`FRACTION_UNITS` units of work)."""
        self.stage = stage
        self.set(round(min(max(float(done), 0.0), 1.0) * FRACTION_UNITS), FRACTION_UNITS)

    def line(self, now: float | None = None) -> str:
        """The text of the progress line."""
        elapsed = (time.monotonic() if now is None else now) - self.t0
        if self.total < 0:            # work of unknown size: elapsed time only
            return f"{self.label}: {elapsed:.0f} s elapsed"
        if self.stage is not None:    # a fraction done, by stage
            return (f"{self.label}: {self.stage}, {100.0 * self.done / max(self.total, 1):.0f}%, "
                    f"{elapsed:.0f} s elapsed, {format_eta(elapsed, self.done, self.total)}")
        if self.total:
            pct = f" ({100.0 * self.done / self.total:.0f}%)"
            count = f"{self.done}/{self.total}{pct}"
        else:
            count = f"{self.done}"
        return (f"{self.label}: {count}, {elapsed:.0f} s elapsed, "
                f"{format_eta(elapsed, self.done, self.total)}")

    def _draw(self, now: float) -> None:
        isatty = getattr(self.stream, "isatty", None)
        if not (isatty and isatty()):        # forced (--progress) onto a file or pipe: one line each
            self.stream.write(self.line(now) + "\n")
            self.stream.flush()
            self._last_draw = now
            return
        self.stream.write("\r" + self.line(now) + "\033[K")
        self.stream.flush()
        self._last_draw, self._drawn = now, True

    def close(self) -> None:
        """Finish the line (only if one was drawn)."""
        if self._drawn:
            self._draw(time.monotonic())
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


@contextlib.contextmanager
def stage(logger: logging.Logger, what: str) -> Iterator[None]:
    """Log ``what...`` at the start and ``what: done in 1.23 s`` at the end of a stage."""
    logger.info("%s...", what)
    t0 = time.monotonic()
    yield
    logger.info("%s: done in %.2f s", what, time.monotonic() - t0)


@contextlib.contextmanager
def working(label: str, *, stream: IO[str] | None = None, enabled: bool | None = None,
            logger: logging.Logger | None = None) -> Iterator[Progress]:
    """A stage of unknown length (one library call): on a terminal, a line with the elapsed time
    redrawn every second by a background thread once :data:`SHOW_AFTER_S` have passed; with
    ``logger``, the start and the duration logged as :func:`stage` does. Yields the
    :class:`Progress`: a call that reports the fraction it has done (``calibrate(progress=)``)
    is given its :meth:`Progress.fraction`, and the line then shows the stage, the percentage and
    the time left."""
    progress = Progress(-1, label, stream=stream, enabled=enabled)
    stop = threading.Event()

    def tick():
        while not stop.wait(1.0):
            progress.set(progress.done)

    thread = None
    if progress.enabled:
        thread = threading.Thread(target=tick, name="calib-progress", daemon=True)
        thread.start()
    with (stage(logger, label) if logger is not None else contextlib.nullcontext()):
        try:
            yield progress
        finally:
            stop.set()
            if thread is not None:
                thread.join()
            progress.close()
