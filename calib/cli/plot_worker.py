"""The plots of ``--plots`` and ``--html`` drawn in a worker process (issue 27, item 3).

matplotlib's import (about 0.35 s CPU) and the drawing (about 0.1 s a figure) cost more than
the calibration of a few hundred rows. :class:`PlotWorker` starts a second process as soon as a
command knows that it will draw: a fork of the command on Linux when it runs no other thread
(numpy and calib are then already imported), else a new interpreter (``python -m
calib.cli.plot_worker``). The worker imports matplotlib (without the property tables of its
docstrings: :func:`_without_property_docs`) and the plotting code while the command reads its
inputs and calibrates, then draws the rows it is sent while the command builds the JSON
report and the HTML page, half of the plots in a fork of itself when there are two cores (the
command only waits meanwhile). With free cores the import and most of the drawing leave the
command's wall time; the CPU time (the workers', counted in the command's once waited for) grows
a little (the fork, the rows pickled, the first figure's set-up in each process). On a machine
whose cores are busy with other work the wall time gains little.

The images are :func:`calib.report.plots.plot_rows` of the same rows, byte for byte
as drawn in the command's own process, in the same order. Nothing is written by the worker: the
command stages the images with its other outputs (:mod:`calib.cli.output`), so an error anywhere
still writes nothing. The worker ignores SIGINT (Ctrl-C reaches the whole process group; the
command handles it and stops the worker), writes nothing on the command's terminal, and ends
when the command closes its pipe or stops it (:meth:`PlotWorker.close`, on every path).

Protocol: the command writes one pickle, ``(rows, tolerance_m, columns)``, to the worker's stdin;
the worker answers on its stdout with pickles ``("progress", k, n)`` as plots are done, then
``("images", {name: png bytes})`` or ``("error", traceback text)``.
"""
from __future__ import annotations

import gc
import os
import pickle
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable, Mapping

__all__ = ["PlotWorker"]


class PlotWorker:
    """A worker process drawing one set of plots; start it early, :meth:`submit` the rows when
    they are known, collect the images with :meth:`images`. Use as a context manager (or call
    :meth:`close`): the process is stopped and waited for on every path."""

    def __init__(self) -> None:
        import threading

        self._sender = None
        if _can_fork() and threading.active_count() == 1:
            self._proc = _Forked()        # numpy and calib already imported: ready about 0.15 s sooner
            return
        import calib                      # (a new interpreter: forking a threaded process is unsafe)

        env = dict(os.environ)
        # the worker imports the calib this process runs, wherever it was found
        root = str(Path(calib.__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        # (its own process group, as a forked worker's: close() stops the fork drawing its other half too)
        self._proc = subprocess.Popen([sys.executable, "-m", "calib.cli.plot_worker"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
                                      start_new_session=True)

    def __enter__(self) -> "PlotWorker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def submit(self, rows, *, tolerance_m: float | None = None, columns: Mapping | None = None) -> None:
        """Send the rows to draw (:class:`calib.report.rows.ReportRows`, and the
        arguments of :func:`calib.report.plots.plot_rows`). Returns at once: a thread
        writes them while the worker may still be importing matplotlib."""
        import threading

        from dataclasses import replace

        rows = replace(rows, columns=dict(rows.columns))     # (a read-only mapping does not pickle)
        data = pickle.dumps((rows, tolerance_m, None if columns is None else dict(columns)),
                            protocol=pickle.HIGHEST_PROTOCOL)
        self._sender = threading.Thread(target=self._send, args=(data,), name="calib-plots-submit", daemon=True)
        self._sender.start()

    def _send(self, data: bytes) -> None:
        try:
            self._proc.stdin.write(data)
            self._proc.stdin.close()
        except (BrokenPipeError, ValueError):    # the worker ended (images() says so) or was stopped
            pass

    def images(self, progress: Callable[[int, int], None] | None = None) -> dict[str, bytes]:
        """The PNG images by file name, once drawn; ``progress(k, n)`` after each plot."""
        self._sender.join()
        while True:
            try:
                message = pickle.load(self._proc.stdout)
            except EOFError:
                self._failed()
            if message[0] == "progress":
                if progress is not None:
                    progress(message[1], message[2])
            elif message[0] == "images":
                self._proc.wait()         # (the worker ends at once: os._exit after its answer)
                return message[1]
            else:
                self._proc.wait()
                raise RuntimeError(f"drawing the plots failed in the worker process:\n{message[1]}")

    def _failed(self):
        code = self._proc.wait()
        raise RuntimeError(f"the plots' worker process ended before drawing them (exit code {code})")

    def close(self) -> None:
        """Stop the worker (and the fork drawing its other half) if it still runs, wait for it,
        close the pipes."""
        if self._proc.poll() is None:      # (not reaped yet: its id still names its process group)
            try:
                os.killpg(self._proc.pid, signal.SIGKILL)
            except (AttributeError, OSError):     # (no process groups, or already gone)
                self._proc.kill()
        self._proc.wait()
        if self._sender is not None:
            self._sender.join()
        for pipe in (self._proc.stdin, self._proc.stdout):
            try:
                pipe.close()
            except OSError:           # (rows still buffered for a worker that is gone)
                pass


class _Forked:
    """The worker as a forked copy of this (single-threaded) process, with the part of
    :class:`subprocess.Popen` that :class:`PlotWorker` uses: ``stdin``, ``stdout``, ``poll``,
    ``wait``, ``kill``, ``returncode``."""

    def __init__(self) -> None:
        job_read, job_write = os.pipe()
        answer_read, answer_write = os.pipe()
        self.returncode = None
        # the command's objects set apart from the worker's garbage collections, which would
        # otherwise write into (and so copy) every page holding them (Python's gc.freeze advice)
        # (only when nothing is frozen yet: unfreezing would also release what a program that
        # runs the command in its own process had frozen for itself)
        ours = gc.get_freeze_count() == 0
        if ours:
            gc.freeze()
        try:
            self.pid = os.fork()
        finally:
            if ours and getattr(self, "pid", None) != 0:       # (this process, also when fork() failed)
                gc.unfreeze()
        if self.pid == 0:                 # the worker: never returns into the command's code
            code = 1
            try:
                os.setpgid(0, 0)          # its own process group, with the fork drawing its other half
                os.close(job_write)
                os.close(answer_read)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                devnull = os.open(os.devnull, os.O_RDWR)
                for fd in (0, 1, 2):      # (the command's terminal and pipes are not the worker's)
                    os.dup2(devnull, fd)
                with os.fdopen(job_read, "rb") as stdin, os.fdopen(answer_write, "wb") as stdout:
                    code = serve(stdin, stdout)
            except BaseException:  # noqa: BLE001 - the exit code says it; the command reports it
                pass
            finally:
                os._exit(code)
        try:
            os.setpgid(self.pid, self.pid)    # (also here: close() may come before the worker runs)
        except OSError:
            pass
        os.close(job_read)
        os.close(answer_write)
        self.stdin = os.fdopen(job_write, "wb")
        self.stdout = os.fdopen(answer_read, "rb")

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self) -> int:
        if self.returncode is None:
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])
        return self.returncode

    def kill(self) -> None:
        if self.poll() is None:
            os.kill(self.pid, signal.SIGKILL)


def _can_fork() -> bool:
    """Whether a process may fork without exec here: Linux (macOS's system libraries do not
    survive it, Windows has no fork)."""
    return sys.platform.startswith("linux") and hasattr(os, "fork")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:      # (not on Linux)
        return os.cpu_count() or 1


class _Half:
    """``draw()`` run in a forked copy of this process (matplotlib already imported: nothing to
    pay twice): :meth:`images` waits for its images (raises what it raised), :meth:`stop` ends it."""

    def __init__(self, draw: Callable[[], dict]) -> None:
        self.read_end, self.pid = _forked(draw)

    def images(self) -> dict:
        with os.fdopen(self.read_end, "rb") as fh:
            try:
                message = pickle.load(fh)
            except EOFError:
                message = ("error", "the worker's second process ended without answering")
        os.waitpid(self.pid, 0)
        if message[0] != "images":
            raise RuntimeError(message[1])
        return message[1]

    def stop(self) -> None:
        os.kill(self.pid, signal.SIGKILL)
        os.waitpid(self.pid, 0)
        os.close(self.read_end)


def _forked(draw: Callable[[], dict]) -> tuple[int, int]:
    """Fork; the copy runs ``draw()`` and pickles ``("images", ...)`` or ``("error", traceback)``
    into a pipe, then ends. Returns the pipe's read end and the copy's pid."""
    import traceback

    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:                  # the copy: draw, answer through the pipe, end at once
        code = 1
        try:
            os.close(read_end)
            with os.fdopen(write_end, "wb") as out:
                try:
                    message = ("images", draw())
                    code = 0
                except Exception:  # noqa: BLE001 - raised again in the worker
                    message = ("error", traceback.format_exc())
                pickle.dump(message, out, protocol=pickle.HIGHEST_PROTOCOL)
        finally:
            os._exit(code)
    os.close(write_end)
    return read_end, pid


def _without_property_docs() -> None:
    """Let matplotlib's import skip writing its artists' property lists into docstrings.

    Each Artist class, as it is defined, inspects all its setters (signatures, docstrings,
    regular expressions) to write the signature and docstring of its ``set()`` and the
    ``%(Name:kwdoc)s`` tables of other docstrings: about 40 % of importing matplotlib's figure
    and Agg canvas (0.33 -> 0.20 s CPU, 2.37 -> 1.39 G instructions with Python's start-up),
    for text that only help() reads. This process only draws: once ``matplotlib.artist`` is
    imported (no subclass defined yet), both are made to write nothing. ``set()`` still takes the
    same keywords (it calls ``Artist.set``); the images are byte for byte those drawn with the
    full import (tests/cli/test_plot_worker.py). Nothing is changed when the program that forked
    this process had imported matplotlib already, or when matplotlib no longer has these hooks."""
    if "matplotlib.artist" in sys.modules:
        return
    import matplotlib.artist as artist

    if callable(getattr(artist, "kwdoc", None)) and \
            callable(getattr(artist.Artist, "_update_set_signature_and_docstring", None)):
        artist.kwdoc = lambda _artist: ""
        artist.Artist._update_set_signature_and_docstring = classmethod(lambda cls: None)


def serve(stdin, stdout) -> int:
    """The worker's side: import the plotting code, read one job, draw it (half of the plots in a
    forked copy of itself when there are two cores: the command waits, idle, meanwhile), answer."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import traceback
    import warnings

    from calib.report.plots import plot_names, plot_rows, warm_up

    gc.disable()              # (no garbage worth a collection while importing)
    _without_property_docs()
    warm_up()                 # matplotlib imported while the command calibrates
    gc.freeze()               # (its modules out of the collections, here and in the fork drawing half)
    gc.enable()
    try:
        rows, tolerance_m, columns = pickle.load(stdin)
    except EOFError:          # the command needs no plots after all
        return 0

    def send(*message) -> None:
        pickle.dump(message, stdout, protocol=pickle.HIGHEST_PROTOCOL)
        stdout.flush()

    theirs = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # (the command keeps library warnings off the terminal)
            names = plot_names(rows, columns)
            if len(names) > 1 and _cores() > 1 and _can_fork():
                theirs = _Half(lambda: plot_rows(rows, tolerance_m=tolerance_m, columns=columns,
                                                 names=names[1::2]))
            mine = plot_rows(rows, tolerance_m=tolerance_m, columns=columns,
                             names=names if theirs is None else names[0::2],
                             progress=lambda k, n: send("progress", k, len(names)))
            if theirs is not None:
                half, theirs = theirs, None
                mine.update(half.images())
                send("progress", len(names), len(names))
            images = {name: mine[name] for name in names}
    except Exception:  # noqa: BLE001 - any failure is the command's to report
        if theirs is not None:           # (this half failed: the other is not waited for)
            theirs.stop()
        send("error", traceback.format_exc())
        return 1
    send("images", images)
    return 0


if __name__ == "__main__":
    try:
        code = serve(sys.stdin.buffer, sys.stdout.buffer)
    except BrokenPipeError:   # the command stopped waiting
        code = 1
    os._exit(code)            # the answer is flushed: no interpreter shutdown for the command to wait on
