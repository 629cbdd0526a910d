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


def format_number(value: float, spec: str) -> str:
    """``format(value, spec)`` without a sign on a zero: ``-0.0`` and the small negatives that
    round to zero (``-1e-9`` at ``.6f``) print ``0.000000``, never ``-0.000000`` (the width of a
    padded field kept)."""
    text = format(value, spec)
    if "-" in text and value == value and float(text) == 0.0:
        same = len(text) == len(format(0.0, spec))          # a padded field: keep its width
        text = text.replace("-", "", 1) + (" " if same and text.startswith("-") else "")
        text = text.rjust(len(text) + 1) if same and len(text) < len(format(0.0, spec)) else text
    return text
