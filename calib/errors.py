"""The exception hierarchy of calib: one root, subclasses that carry what the user needs.

Every error a user can cause (a bad file, a bad frame name, a bad option) is a
:class:`CalibError`. Its ``str()`` is one line that names the file, row and column
where they apply; the CLI prints it and exits with code 2.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence


class CalibError(Exception):
    """Root of every error calib raises on bad input."""


class URDFError(CalibError):
    """A URDF file that cannot be read: missing, malformed, or without the expected structure."""

    def __init__(self, path: str | Path | None, reason: str):
        self.path = None if path is None else Path(path)
        self.reason = reason
        where = f"{self.path}: " if self.path is not None else ""
        super().__init__(f"{where}{reason}")


class FrameNotFound(CalibError):
    """A frame (link or joint name) that the robot model does not have."""

    def __init__(self, name: str, available: Sequence[str], path: str | Path | None = None):
        self.name = name
        self.available = tuple(available)
        self.path = None if path is None else Path(path)
        where = f"{self.path}: " if self.path is not None else ""
        shown = ", ".join(self.available[:40])
        more = f", ... ({len(self.available)} in all)" if len(self.available) > 40 else ""
        super().__init__(f"{where}no frame named {name!r}; available frames: {shown}{more}")


class ChainError(CalibError):
    """Base and tool frames that do not bound one serial chain of supported joints."""

    def __init__(self, path: str | Path | None, reason: str):
        self.path = None if path is None else Path(path)
        self.reason = reason
        where = f"{self.path}: " if self.path is not None else ""
        super().__init__(f"{where}{reason}")


class MeasurementFormatError(CalibError):
    """A measurement file that does not follow the documented CSV format.

    ``row`` is the 1-based line number in the file (the header is line 1 unless comments
    precede it); ``column`` is the column name where one applies.
    """

    def __init__(self, path: str | Path | None, reason: str, row: int | None = None,
                 column: str | None = None):
        self.path = None if path is None else Path(path)
        self.row = row
        self.column = column
        self.reason = reason
        parts = [str(self.path) if self.path is not None else "<measurements>"]
        if row is not None:
            parts.append(f"row {row}")
        if column is not None:
            parts.append(f"column {column!r}")
        super().__init__(": ".join([", ".join(parts), reason]))


class ParameterError(CalibError):
    """An unknown parameter name or an inconsistent parameter selection."""


class DataError(CalibError):
    """Measurements that cannot support the requested computation (too few poses, etc.)."""


class OutputError(CalibError):
    """An output that cannot be written (read-only folder, full disk, ...): names the path.

    When it is raised by :class:`calib.io.fileio.OutputSet`, no output was changed."""

    def __init__(self, path: str | Path, reason: str):
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
