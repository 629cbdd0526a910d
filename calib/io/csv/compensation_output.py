"""Corrected joint values in a controller's terms (``calib compensate --convention``): its joint
names and units, its digits, the target names, and its configuration data.

One row per target: ``name`` (when the targets have names), the joints as the convention names
them (KUKA ``A1``.. degrees, ABB ``rax_1``.. degrees, UR ``base``..``wrist3`` radians, FANUC,
Staubli and Yaskawa ``J1``.. degrees; prismatic joints mm, or m under UR) written with the digits
the controller keeps (:data:`DIGITS`), the configuration of the corrected joints (KUKA ``S``,
``T``; ABB ``cf1``, ``cf4``, ``cf6``, ``cfx``; FANUC ``config``), then ``status``,
``residual_mm``, ``residual_rad`` and ``detail`` as :func:`calib.io.csv.specs.write_compensation`
writes them. The file reads back with the same ``--convention`` as a targets or poses file.
"""
from __future__ import annotations

import math
from pathlib import Path


from calib.errors import ParameterError
from calib.io.csv.conventions import CONVENTIONS

__all__ = ["DIGITS", "joint_header", "format_joint", "write_compensation_convention"]

#: How each controller writes a joint value: ("significant", n) digits or ("decimals", n).
#: KUKA: KRL REALs as the controller prints them, nine significant digits (``-41.7453308``,
#: kuka_experimental's .dat files); ABB: six decimals of a degree (RoboDK's RAPID post:
#: ``format(ji, ".6f")``); UR: radians to 1e-9 (URScript takes any float; 1e-9 rad is far below
#: the encoders); FANUC: three decimals, as the .LS format holds them (``J1=    0.000 deg``);
#: Staubli and Yaskawa: four decimals of a degree.
DIGITS = {"kuka": ("significant", 9), "abb": ("decimals", 6), "ur": ("decimals", 9), "fanuc": ("decimals", 3),
          "staubli": ("decimals", 4), "yaskawa": ("decimals", 4), "calib": ("significant", 17)}
_CONFIG_COLUMNS = {"kuka": ("S", "T"), "abb": ("cf1", "cf4", "cf6", "cfx"), "fanuc": ("config",)}


def joint_header(convention: str, n: int, prismatic) -> list[str]:
    """The joint column names of ``convention`` for an n-joint robot (the first naming the
    convention reads), with no unit suffix: the convention's unit is implied."""
    pattern = CONVENTIONS[convention].joints[0][0]
    if isinstance(pattern, tuple):
        if n > len(pattern):
            raise ParameterError(f"--convention {convention} names {len(pattern)} joints; the chain has {n}")
        return list(pattern[:n])
    return [pattern.format(i=i + 1, i0=i) for i in range(n)]


def format_joint(convention: str, value_si: float, prismatic: bool) -> str:
    """One joint value (rad / m) in the convention's unit and digits."""
    unit = CONVENTIONS[convention].joints[1]
    if prismatic:
        x = value_si * (1e3 if unit == "deg" else 1.0)
    else:
        x = math.degrees(value_si) if unit == "deg" else value_si
    kind, digits = DIGITS[convention]
    if kind == "significant":
        s = f"{x:.{digits}g}"
        return s + ".0" if "." not in s and "e" not in s else s
    s = f"{x:.{digits}f}"
    return s.rstrip("0").rstrip(".") if "." in s else s


def _configuration_cells(vendor: str, value) -> list[str]:
    if vendor == "kuka":
        return [str(value[0]), str(value[1])]
    if vendor == "abb":
        return [str(int(v)) for v in value]
    return [f"{value[0]} {value[1]} {value[2]}, {value[3]}, {value[4]}, {value[5]}"]


def write_compensation_convention(path: str | Path, result, *, convention: str, names=None, configurations=None,
                                  comment: str | None = None) -> None:
    """Write a :class:`calib.CompensationResult` in ``convention``'s terms (module docstring),
    atomically. ``names`` : (N,) target names or None; ``configurations`` : the vendor's tuple of
    each target's corrected joints (None: no configuration columns)."""
    from calib.io.csv.layer import csv_text
    from calib.io.fileio import atomic_write_text

    from calib.io.csv.specs import check_names

    if not isinstance(convention, str) or convention not in CONVENTIONS:
        raise ParameterError(f"unknown convention {convention!r}")
    names = check_names(names, result.n_targets)
    header = (["name"] if names is not None else []) + joint_header(convention, len(result.joint_names),
                                                                    result.prismatic)
    vendor_cols = _CONFIG_COLUMNS.get(convention) if configurations is not None else None
    if vendor_cols:
        header += list(vendor_cols)
    header += ["status", "residual_mm"] + (["residual_rad"] if result.rotation_error is not None else [])
    framed = getattr(result, "frame_position_std", None) is not None
    if framed:
        header += ["frame_std_mm", "frame_std_deg"]
    header.append("detail")
    rows = []
    for k in range(result.n_targets):
        row = [str(names[k])] if names is not None else []
        row += [format_joint(convention, float(v), bool(p)) for v, p in zip(result.q[k], result.prismatic)]
        if vendor_cols:
            row += _configuration_cells(convention, configurations[k])
        row += [str(result.status[k]), f"{result.position_error[k] * 1e3:.6g}"]
        if result.rotation_error is not None:
            row.append(f"{result.rotation_error[k]:.6g}")
        if framed:
            row += [f"{result.frame_position_std[k] * 1e3:.4g}", f"{math.degrees(result.frame_rotation_std[k]):.4g}"]
        row.append("" if result.status[k] == "ok" and not framed else result.describe(k))
        rows.append(row)
    atomic_write_text(path, csv_text(header, rows, comment))
