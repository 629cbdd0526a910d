"""The one table of display units: SI inside the library, these units at the edges (printed
tables, JSON reports) for each SI unit a parameter can have, with the factor from SI."""
from __future__ import annotations

#: SI unit of a parameter -> (display unit, factor from SI).
DISPLAY_UNITS = {"m": ("mm", 1e3), "rad": ("rad", 1.0), "rad/(N m)": ("urad/(N m)", 1e6),
                 "m/N": ("um/N", 1e6)}


def display_value(value: float, unit: str) -> float:
    """``value`` (SI ``unit``) in its display unit."""
    return value * DISPLAY_UNITS[unit][1]


def display_unit(unit: str) -> str:
    """The display unit of the SI ``unit``."""
    return DISPLAY_UNITS[unit][0]
