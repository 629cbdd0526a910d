"""The targets of ``calib compensate`` as read (:class:`CompensationTargets`, made by
:func:`calib.io.csv.specs.read_targets`), in a module of its own: loaded when a targets file is read,
not by every command that reads measurements (a dataclass costs ~3M instructions to build at
import)."""
from __future__ import annotations

from dataclasses import dataclass, field
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
    names : (N,) the name column's cells, or None without one.
    configuration : the configuration columns present (s, t, cf1, cf4, cf6, cfx, config) ->
        (the header name as written, (N,) cells as text): read by the CLI under --convention.
    """

    q: np.ndarray | None
    position: np.ndarray | None
    rotation: np.ndarray | None
    rows: np.ndarray
    source: Path | None = None
    ignored_columns: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    names: tuple[str, ...] | None = None
    configuration: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        """"joints", "pose" or "position"."""
        if self.position is None:
            return "joints"
        return "pose" if self.rotation is not None else "position"

    @property
    def n_targets(self) -> int:
        return len(self.rows)


#: The configuration columns of each vendor in a targets file (read with ``--convention``).
CONFIGURATION_COLUMNS = {"kuka": ("s", "t"), "abb": ("cf1", "cf4", "cf6", "cfx"), "fanuc": ("config",)}


def configurations_of(targets: CompensationTargets, vendor: str | None):
    """The configuration of each target from its configuration columns (KUKA ``S`` and ``T``:
    integers or ``'Bnnn'``; ABB ``cf1``, ``cf4``, ``cf6``, ``cfx``: integers; FANUC ``config``:
    ``'N U T, 0, 0, 0'``), as tuples of :func:`calib.compensation.configuration.vendor_configuration`;
    None when the file has none. Raises :class:`calib.MeasurementFormatError` (file, row, column)
    for columns of another vendor than ``vendor`` (the ``--convention``), a vendor's columns in
    part, or a cell that is not a configuration."""
    from calib.errors import MeasurementFormatError

    present = dict(targets.configuration)
    if not present:
        return None
    path, row0 = targets.source, int(targets.rows[0])
    wanted = CONFIGURATION_COLUMNS.get(vendor or "", ())
    other = [present[k][0] for k in present if k not in wanted]
    if other:
        owners = [v for v, cols in CONFIGURATION_COLUMNS.items() if set(present) <= set(cols)]
        raise MeasurementFormatError(path, f"configuration column {other[0]!r} needs --convention "
                                           f"{owners[0] if owners else '/'.join(CONFIGURATION_COLUMNS)}"
                                           + (f" (not {vendor})" if vendor else ""), row=row0, column=other[0])
    missing = [c for c in wanted if c not in present]
    if missing:
        raise MeasurementFormatError(path, f"configuration columns in part: expected {', '.join(wanted)} "
                                           f"(missing {', '.join(missing)})", row=row0, column=missing[0])
    out = []
    for k, row in enumerate(targets.rows.tolist()):
        cells = {c: present[c][1][k].strip() for c in wanted}
        if vendor == "fanuc":
            from calib.io.programs.fanuc import parse_config

            out.append(parse_config(path, row, f"row {row}, column {present['config'][0]}",
                                    cells["config"].strip("'")))
            continue
        value = []
        for c in wanted:
            t = cells[c].strip("'")
            try:
                value.append(int(t[1:], 2) if vendor == "kuka" and t.upper().startswith("B") else int(t))
            except ValueError:
                raise MeasurementFormatError(path, f"{cells[c]!r} is not a configuration value; expected "
                                                   f"{'an integer or a binary literal such as B010' if vendor == 'kuka' else 'an integer'}",
                                             row=row, column=present[c][0]) from None
        value = tuple(value)
        out.append(value)
    return tuple(out)
