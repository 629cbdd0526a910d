"""The targets of ``calib compensate`` as read (:class:`CompensationTargets`, made by
:func:`calib.io.csv.specs.read_targets`), in a module of its own: loaded when a targets file is read,
not by every command that reads measurements (a dataclass costs ~3M instructions to build at
import)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np



@dataclass(frozen=True, eq=False)
class CompensationTargets:
    """Targets read by :func:`read_targets` (SI units, meas frame).

    q : (N, n) rad / m, the nominal joints (or the start for pose targets), or None.
    position : (N, 3) metres, target tool positions, or None for joint targets.
    rotation : (N, 3, 3) target tool orientations, or None (joint or position targets).
    rows : (N,) line numbers in the file; source : the file.
    ignored_columns, notes : as in :class:`calib.Measurements`.
    """

    q: np.ndarray | None
    position: np.ndarray | None
    rotation: np.ndarray | None
    rows: np.ndarray
    source: Path | None = None
    ignored_columns: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        """"joints", "pose" or "position"."""
        if self.position is None:
            return "joints"
        return "pose" if self.rotation is not None else "position"

    @property
    def n_targets(self) -> int:
        return len(self.rows)
