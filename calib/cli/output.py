"""The one output policy of the ``calib`` subcommands, and their exit codes.

Outputs are produced in memory first and written only when everything succeeded, as a set
(:class:`calib.io.fileio.OutputSet`: temporary files in the target folders, renamed together);
an output path that names an input is refused before any work (:class:`Outputs`). JSON printed
or written by a command is strict (:func:`json_text`).
"""
from __future__ import annotations

import logging
import math
import sys
import tempfile
from pathlib import Path
from typing import Callable, Sequence

from calib.errors import CalibError
from calib.io.fileio import OutputSet, check_not_input, output_target

__all__ = ["PROG", "EXIT_OK", "EXIT_INPUT", "EXIT_NOT_CONVERGED", "Outputs", "json_text", "command_line"]

log = logging.getLogger(__name__)

PROG = "calib"
EXIT_OK = 0
EXIT_INPUT = 2
#: ``calibrate``: the fit did not converge; ``compensate``: some targets were not reached
#: (the outputs are written all the same, for inspection).
EXIT_NOT_CONVERGED = 3

#: The outputs the running command has put in place (set while the signals are held back, the
#: moment the last one is renamed): a signal after that no longer means "nothing changed"
#: (:func:`calib.cli.main.main` reads it; :func:`forget_written` starts a command).
_WRITTEN: list[Path] = []


def written() -> list[Path]:
    """The outputs the running command has put in place (empty before its commit)."""
    return list(_WRITTEN)


def forget_written() -> None:
    """Start a command: no output of it is in place yet."""
    _WRITTEN.clear()


class Outputs:
    """Output files staged in memory and written together at the end.

    :meth:`add` checks a path at once (not an input, not another output, its folder exists, not
    a folder itself), so that a bad path fails before any work is done; :meth:`commit` writes
    every staged file atomically.
    """

    def __init__(self, inputs: Sequence[str | Path | None]):
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.paths: list[Path] = []
        self.data: dict[Path, bytes] = {}
        self.folders: list[Path] = []
        self.removals: list[Path] = []

    def add(self, path: str | Path, *, make_folder: bool = False) -> Path:
        """Reserve ``path`` as an output; with ``make_folder`` its folder may not exist yet (it
        is created by :meth:`commit`)."""
        path = Path(path)
        check_not_input(path, self.inputs)
        check_not_input(path, self.paths)
        output_target(path)          # a device, FIFO or socket is refused before any work
        if path.is_dir():
            raise CalibError(f"{path}: is a folder, expected a file name for the output")
        folder = path.parent
        if not folder.is_dir():
            if make_folder and not folder.exists() and folder.parent.is_dir():
                if folder not in self.folders:
                    self.folders.append(folder)
            elif folder.exists():
                raise CalibError(f"{path}: {folder} is not a folder")
            else:
                raise CalibError(f"{path}: folder {folder} does not exist")
        self.paths.append(path)
        return path

    def add_folder(self, folder: str | Path, names: Sequence[str], option: str) -> dict[str, Path]:
        """Reserve the files ``names`` in ``folder`` (the value of ``option``, such as --plots,
        which takes a folder; created by :meth:`commit` when missing): name -> path. A folder
        that is a file, or lies in one, is refused naming the option (each file's path was then
        refused as 'cannot be inspected: Not a directory')."""
        from calib.errors import ParameterError

        folder = Path(folder)
        there = next((p for p in (folder, *folder.parents) if p.exists() or p.is_symlink()), None)
        if there is not None and not there.is_dir():
            where = "is a file" if there == folder else f"{there} is a file"
            raise ParameterError(f"{option} {folder}: {where}, not a folder; {option} takes a folder, into "
                                 f"which it writes {', '.join(names)}")
        return {name: self.add(folder / name, make_folder=True) for name in names}

    def stage(self, path: Path, data: bytes | str | list[bytes]) -> None:
        """Keep ``data`` for ``path`` (str: UTF-8; a list: the file's chunks of bytes, in order,
        so that a large file is not joined into one more copy in memory)."""
        if path not in self.paths:
            raise ValueError(f"{path} was not reserved with Outputs.add")
        self.data[path] = data.encode("utf-8") if isinstance(data, str) else data

    def remove(self, path: Path) -> None:
        """Remove the reserved ``path`` with the commit (a stale file of an earlier run that the
        new outputs have no use for); nothing happens if the commit does not."""
        if path not in self.paths:
            raise ValueError(f"{path} was not reserved with Outputs.add")
        self.removals.append(path)

    def stage_from_file(self, path: Path, write: Callable[[Path], None]) -> None:
        """Stage what ``write(temporary_path)`` writes (for API writers that take a path)."""
        with tempfile.TemporaryDirectory(prefix="calib-") as tmp:
            target = Path(tmp) / path.name
            write(target)
            self.stage(path, target.read_bytes())

    def commit(self) -> None:
        """Write every staged file as a set (:class:`calib.io.fileio.OutputSet`): all or none."""
        out = OutputSet()
        for folder in self.folders:
            out.make_folder(folder)
        for path in self.paths:
            if path in self.data:
                out.stage(path, self.data[path])
            elif path in self.removals:
                out.remove(path)
        for path in out.commit(on_renamed=_WRITTEN.extend):
            log.info("wrote %s", path)


def json_text(obj) -> str:
    """Strict JSON (NaN and infinities become null), indented, newline-terminated."""
    import numpy as np

    def clean(o):
        if isinstance(o, float):
            return o if math.isfinite(o) else None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, np.generic):
            return clean(o.item())
        return o
    import json

    return json.dumps(clean(obj), indent=2, allow_nan=False) + "\n"


def command_line(args) -> str:
    """The command line that ran, shell-quoted (``calib`` and ``args.argv``), for file comments."""
    argv = getattr(args, "argv", None)
    if argv is None:
        return f"{PROG} " + args.command if getattr(args, "command", None) else PROG
    import shlex

    return " ".join(shlex.quote(a) for a in [PROG, *argv])


def refuse_implausible(report_text: str, message: str) -> int:
    """An implausible calibration refused (nothing written): its report on stdout, one line on
    stderr naming why, exit 3."""
    sys.stdout.write(report_text + "\n")
    way = "" if "--accept-implausible" in message else " (--accept-implausible writes the outputs for inspection)"
    sys.stderr.write(f"{PROG}: error: the calibration cannot be trusted: {message}; nothing written{way}\n")
    return EXIT_NOT_CONVERGED


def status_exit(status: str, message: str) -> int:
    """The exit code of a calibration whose outputs were written, and the warning of a status
    other than "converged" on stderr (the outputs are for inspection then)."""
    if status == "implausible":
        sys.stderr.write(f"{PROG}: warning: the calibration converged to a result that cannot be trusted "
                         f"({message}); the outputs were written for inspection (--accept-implausible), "
                         f"do not use them as a calibrated model\n")
        return EXIT_NOT_CONVERGED
    if status != "converged":
        sys.stderr.write(f"{PROG}: warning: the calibration did NOT converge (status {status}: {message}); "
                         f"the outputs were written for inspection, do not use them as a calibrated model\n")
        return EXIT_NOT_CONVERGED
    return EXIT_OK
