"""Atomic file output: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and a failure leaves any existing file untouched.
"""
from __future__ import annotations

import _signal      # (signal's C core: the signal module's enums cost 2.8M instructions of every start)
import contextlib
import os
import sys
import tempfile
import threading
from pathlib import Path
from typing import Callable, Iterable

from calib.errors import CalibError, OutputError


def check_not_input(output: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Refuse an output path that is one of the inputs (inputs are never overwritten)."""
    out = _resolved(output, output=True)
    for p in inputs:
        if p is not None and _resolved(p) == out:
            raise CalibError(f"{output}: refusing to overwrite an input file; choose another output path")


def _resolved(path: str | Path, output: bool = False) -> Path:
    """``path`` with its symbolic links resolved; a link loop (which no file can be written
    through) is an :class:`OutputError` for an output, and left unresolved for an input (its
    reader then says it cannot be read)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError):     # Python < 3.13: RuntimeError; later: OSError (ELOOP)
        if output:
            raise OutputError(Path(path), "is a symbolic link loop: no file can be written through it; "
                                          "choose another output path") from None
        return Path(os.path.abspath(path))


def output_target(path: str | Path) -> Path:
    """The file an output at ``path`` replaces: ``path`` itself, or the file a symbolic link there
    points to (the link is kept; the file it names is replaced). Raises :class:`OutputError` when
    that is something other than a regular file (a device such as /dev/null, a FIFO, a socket):
    writing by rename would destroy it."""
    import stat

    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        return target
    except OSError as exc:
        raise OutputError(path, f"cannot be inspected: {_reason(exc)}") from None
    if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        raise OutputError(path, "is not a regular file (a device, FIFO or socket): outputs are "
                                "written by replacing the file, which would destroy it; choose a file name")
    return target


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


class OutputSet:
    """Output files written as a set: all or none.

    :meth:`stage` keeps each file's bytes (or the list of its chunks, written in order: a large
    file need not be joined into one more copy in memory); :meth:`commit` writes every one to a temporary file
    in its target folder (``.NAME.XXXX.tmp``), and only when all are written and flushed renames
    them into place (SIGINT and SIGTERM are held back during the renames). If anything fails --
    a read-only folder, a full disk, a signal before the renames -- every temporary file is
    removed, folders it created are removed again, and no existing output has changed; the
    failure is an :class:`calib.errors.OutputError` naming the path. Should a rename itself fail
    half-way (the folder was made read-only in between), the files already renamed are put back
    from hard-linked copies where the file system allows it.
    """

    def __init__(self) -> None:
        self.data: dict[Path, bytes] = {}
        self.folders: list[Path] = []
        self.removals: list[Path] = []

    def stage(self, path: str | Path, data: bytes | str | list[bytes]) -> None:
        """Keep ``data`` (str: UTF-8; a list: the file's chunks of bytes, in order) to be written
        to ``path`` by :meth:`commit` (through a symbolic link: into the file it names; see
        :func:`output_target`)."""
        self.data[output_target(path)] = _chunks_or_bytes(data)

    def remove(self, path: str | Path) -> None:
        """Remove ``path`` (if it exists then) with the renames of :meth:`commit`, as part of the
        set: a stale file that belongs with the outputs (a sidecar the new output has no use
        for) goes with them, or stays if the commit fails."""
        self.removals.append(Path(path))

    def make_folder(self, folder: str | Path) -> None:
        """Create ``folder`` (its parent must exist) at commit time, if it does not exist then."""
        folder = Path(folder)
        if folder not in self.folders:
            self.folders.append(folder)

    def commit(self, on_renamed: Callable[[list[Path]], None] | None = None) -> list[Path]:
        """Write every staged file (see the class docstring); returns the paths written.

        on_renamed : called with the paths once every file is in place, while the signals are
        still held back: a caller records there that its outputs changed, so that a signal
        delivered the moment they are released is not taken for one that stopped the work."""
        made: list[Path] = []
        temps: list[tuple[str, Path]] = []
        try:
            for folder in self.folders:
                if not folder.is_dir():
                    try:
                        folder.mkdir()
                    except OSError as exc:
                        raise OutputError(folder, f"cannot create the folder: {_reason(exc)}") from None
                    made.append(folder)
            temps = _write_temporaries(list(self.data.items()))
            _rename_all(temps, on_renamed, self.removals)
        except BaseException:
            def undo() -> None:
                for tmp, _ in temps:
                    _unlink(tmp)
                for folder in reversed(made):
                    try:
                        folder.rmdir()
                    except OSError:
                        pass
            _to_the_end(undo)
            raise
        return [path for _, path in temps]


def _unlink(path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _chunks_or_bytes(data: bytes | str | list[bytes]) -> bytes | list[bytes]:
    """What :meth:`OutputSet.stage` keeps of ``data``: bytes, or a list of chunks of bytes."""
    if isinstance(data, str):
        return data.encode("utf-8")
    if isinstance(data, list):
        return [bytes(c) for c in data]
    return bytes(data)


def _write_temporaries(items: list[tuple[Path, bytes | list[bytes]]]) -> list[tuple[str, Path]]:
    """:func:`_write_temporary` of each (path, data), one thread each: every file's fsync waits
    for the disk, and the waits overlap (the 7 files of ``calibrate --report --html --plots``:
    28-43 ms one after the other, 5-11 ms at once on the benchmark machine). Returns
    (temporary file, path) in the order given. On a failure (the first in that order is raised,
    as when they were written in turn) or an interruption, every temporary file written is
    removed before the exception goes on."""
    if len(items) < 2:
        return [(_write_temporary(path, data), path) for path, data in items]
    done: list[tuple[str | None, BaseException | None]] = [(None, None)] * len(items)
    mode = 0o666 & ~_umask()            # (read once, here: os.umask is process-wide, not per thread)

    def write(k: int, path: Path, data) -> None:
        try:
            done[k] = (_write_temporary(path, data, mode), None)
        except BaseException as exc:  # noqa: BLE001 - raised again in the calling thread
            done[k] = (None, exc)
    threads = [threading.Thread(target=write, args=(k, path, data), name="calib-write", daemon=True)
               for k, (path, data) in enumerate(items)]
    try:
        with _signals_held():           # (every thread started, or none: no writer left unjoined)
            for t in threads:
                t.start()
        for t in threads:
            t.join()
        failed = next((exc for _, exc in done if exc is not None), None)
        if failed is not None:
            raise failed
    except BaseException:
        def undo() -> None:
            for t in threads:           # (after an interruption: the files still being written too)
                if t.ident is not None:
                    t.join()
            for tmp, _ in done:
                if tmp is not None:
                    _unlink(tmp)
        _to_the_end(undo)
        raise
    return [(tmp, path) for (tmp, _), (path, _) in zip(done, items)]


def _to_the_end(undo: Callable[[], None], attempts: int = 10) -> None:
    """Run the (repeatable) clean-up ``undo`` to its end, signals held: a second Ctrl-C does not
    cut it short, and one that arrived just before they were held (its handler runs at the
    next bytecode, mask or not) starts it again; the exception being handled goes on after."""
    for _ in range(attempts):
        try:
            with _signals_held():
                undo()
            return
        except BaseException:       # noqa: BLE001 - (the first interruption is the one raised)
            continue


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM held back (in the main thread) for the block, delivered after it."""
    held = {_signal.SIGINT, _signal.SIGTERM}
    blocked = threading.current_thread() is threading.main_thread() and hasattr(_signal, "pthread_sigmask")
    old = _signal.pthread_sigmask(_signal.SIG_BLOCK, held) if blocked else None
    try:
        yield
    finally:
        if blocked:
            _signal.pthread_sigmask(_signal.SIG_SETMASK, old)


def _write_temporary(path: Path, data: bytes | list[bytes], mode: int | None = None) -> str:
    """``data`` (bytes, or chunks of bytes written in order) in a new temporary file beside
    ``path`` (flushed to disk); its name."""
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(path, f"folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise OutputError(path, f"cannot write in folder {folder}: {_reason(exc)}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in (data if isinstance(data, list) else [data]):
                fh.write(chunk)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask() if mode is None else mode)  # mkstemp: 0600; the usual permissions
    except OSError as exc:
        _unlink(tmp)
        raise OutputError(path, f"cannot be written: {_reason(exc)}") from None
    except BaseException:
        _unlink(tmp)
        raise
    return tmp


def _put_back(backups: list[tuple[Path, str | None]]) -> None:
    """Undo the renames done so far: each target back from its copy (``saved``), or removed
    when there was none before; the list emptied."""
    for done, saved in reversed(backups):
        if saved is not None:
            os.replace(saved, done)
        else:
            _unlink(done)
    backups.clear()


def _rename_all(temps: list[tuple[str, Path]], on_renamed=None, removals=()) -> None:
    """Rename each temporary file onto its target, then move each of ``removals`` that exists
    aside, signals held back; on a failure put back the targets already replaced or moved (from
    hard-linked copies) and raise OutputError. ``on_renamed`` (paths) is called after the last
    rename, before the signals are released; the files moved aside are deleted at the end."""
    backups: list[tuple[Path, str | None]] = []
    with _signals_held():
        try:
            for tmp, path in temps:
                backup = None
                if path.exists():
                    backup = f"{tmp}.old"
                    try:
                        os.link(path, backup)
                    except OSError:
                        backup = None
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    if backup:
                        _unlink(backup)
                    _put_back(backups)
                    raise OutputError(path, f"cannot be replaced: {_reason(exc)}") from None
                backups.append((path, backup))
            for path in removals:
                if not os.path.lexists(path):
                    continue
                aside = str(path.parent / f".{path.name}.removed.tmp")
                try:
                    os.replace(path, aside)
                except OSError as exc:
                    _put_back(backups)
                    raise OutputError(path, f"cannot be removed: {_reason(exc)}") from None
                backups.append((path, aside))
            if on_renamed is not None:
                on_renamed([path for _, path in temps])
        finally:
            for _, saved in backups:
                if saved is not None:
                    _unlink(saved)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename);
    :class:`calib.errors.OutputError` naming the path if it cannot be written."""
    out = OutputSet()
    out.stage(path, data)
    out.commit()


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def captured_c_output():
    """Capture what C/C++ code writes to the process's stdout and stderr (file descriptors 1
    and 2; e.g. Pinocchio's URDF parser) instead of letting it reach the terminal.

    Yields a list that holds, on exit, the captured text (one string). Python's own
    ``sys.stdout``/``sys.stderr`` are flushed first so that nothing of theirs is captured.
    """
    captured: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError, OSError):
            pass
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:          # no such descriptors (embedded interpreter): nothing to capture
        yield captured
        return
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            yield captured
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            tmp.seek(0)
            captured.append(tmp.read().decode("utf-8", "replace"))
