"""Argument checks of the public API entry points: type, range and finiteness, each failure a
:class:`calib.ParameterError` (or :class:`calib.DataError` for arrays) naming the argument.

Every public function checks its arguments once, on entry, with these helpers (as scipy's
``least_squares`` does), so that a wrong call never surfaces as a bare ``TypeError``,
``ValueError``, ``IndexError`` or ``AttributeError`` from deep inside, and never runs on NaN.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from calib.errors import DataError, ParameterError

_REAL = (int, float, np.integer, np.floating)


def check_number(value: Any, name: str, *, minimum: float | None = None, maximum: float | None = None,
                 strict: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a finite float within [minimum, maximum] (``strict``: minimum excluded).

    ``None`` is returned as is when ``allow_none``. Booleans are refused (``True`` is not a
    tolerance)."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, _REAL):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ParameterError(f"{name} must be a finite number, got {value!r}")
    if minimum is not None and (x < minimum or (strict and x == minimum)):
        bound = f"> {minimum:g}" if strict else f">= {minimum:g}"
        raise ParameterError(f"{name} must be {bound}, got {value!r}")
    if maximum is not None and x > maximum:
        raise ParameterError(f"{name} must be <= {maximum:g}, got {value!r}")
    return x


def check_int(value: Any, name: str, *, minimum: int = 0, maximum: int | None = None,
              allow_none: bool = False) -> int | None:
    """``value`` as an int within [minimum, maximum] (integral floats such as 5.0 are refused:
    counts are integers)."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ParameterError(f"{name} must be at least {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ParameterError(f"{name} must be at most {maximum}, got {value!r}")
    return int(value)


def check_choice(value: Any, name: str, choices: Iterable[str]) -> str:
    """``value`` if it is one of ``choices`` (strings, compared exactly)."""
    choices = tuple(choices)
    if not isinstance(value, str) or value not in choices:
        raise ParameterError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    return value


def check_path(value: Any, name: str) -> Path:
    """``value`` (a str or os.PathLike, not empty) as a Path."""
    if isinstance(value, (str, os.PathLike)) and str(os.fspath(value)).strip():
        return Path(value)
    raise ParameterError(f"{name} must be a file path (str or pathlib.Path), got {value!r}")


def check_instance(value: Any, name: str, cls: type, how: str, *, allow_none: bool = False):
    """``value`` if it is a ``cls`` (``how`` says where one comes from, e.g. ``calib.load_robot``)."""
    if value is None and allow_none:
        return None
    if not isinstance(value, cls):
        raise ParameterError(f"{name} must be a {cls.__name__} ({how}), got {type(value).__name__}")
    return value


def check_names(value: Any, name: str, *, allow_none: bool = False) -> tuple[str, ...] | None:
    """``value`` (a list, tuple or array of strings; not one string) as a tuple of str."""
    if value is None and allow_none:
        return None
    if isinstance(value, (list, tuple, np.ndarray)) and all(isinstance(s, str) for s in value):
        return tuple(str(s) for s in value)
    raise ParameterError(f"{name} must be a list of strings, got {value!r:.60}")


def check_array(value: Any, name: str, shape: tuple, *, unit: str = "") -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (None in it: any length), else a
    :class:`calib.DataError` naming ``name``, the shape and the unit expected."""
    want = "(" + ", ".join("N" if d is None else str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"
    what = f"{name} must be a finite numeric array of shape {want}{', ' + unit if unit else ''}"
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise DataError(f"{what}, got {type(value).__name__}") from None
    if arr.ndim != len(shape) or any(d is not None and d != k for d, k in zip(shape, arr.shape)):
        raise DataError(f"{what}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DataError(f"{what}: it holds NaN or infinite values")
    return arr


def check_configurations(Q: Any, n_joints: int, name: str = "Q") -> np.ndarray:
    """Q as a finite (N, n_joints) float array (a single (n_joints,) configuration is refused:
    pass [q])."""
    try:
        arr = np.asarray(Q, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be a numeric array of shape (N, {n_joints}), got "
                        f"{type(Q).__name__}") from None
    if arr.ndim != 2 or arr.shape[1] != n_joints:
        raise DataError(f"{name} must have shape (N, {n_joints}) (one row of joint values per "
                        f"configuration, rad / m), got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad.size:
        raise DataError(f"{name} row {bad[0]} holds NaN or infinite values")
    return arr


def check_deviations(deviations: Any, names: Iterable[str], name: str = "deviations") -> dict[str, float]:
    """``deviations`` as {parameter name: finite float}; unknown names are refused."""
    names = tuple(names)
    if not isinstance(deviations, Mapping):
        raise ParameterError(f"{name} must be a mapping of parameter name to deviation (SI units), "
                             f"got {type(deviations).__name__}")
    missing = [str(n) for n in deviations if n not in names]
    if missing:
        raise ParameterError(f"the {name} name parameters this robot does not have: "
                             f"{', '.join(missing)} (the robot has {', '.join(names)})")
    return {k: check_number(v, f"{name}[{k!r}]") for k, v in deviations.items()}


def check_rng(value: Any, name: str = "rng") -> np.random.Generator:
    """``np.random.default_rng(value)`` (None, an int seed >= 0 or a Generator)."""
    if isinstance(value, bool) or isinstance(value, float):
        raise ParameterError(f"{name} must be None, an integer seed >= 0 or a numpy Generator, got {value!r}")
    try:
        return np.random.default_rng(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be None, an integer seed >= 0 or a numpy Generator, "
                             f"got {value!r}") from None


def check_target_indices(targets: Any, n_rows: int, n_targets: int, name: str = "targets") -> np.ndarray | None:
    """``targets`` as an (n_rows,) int array of target indices in [0, n_targets), or None."""
    if targets is None:
        return None
    arr = np.asarray(targets) if isinstance(targets, (list, tuple, np.ndarray)) else None
    if arr is None or arr.ndim != 1 or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
        raise ParameterError(f"{name} must be a sequence of target indices (ints), one per configuration, "
                             f"got {type(targets).__name__}")
    if len(arr) != n_rows:
        raise ParameterError(f"{name} has {len(arr)} entries for {n_rows} configurations")
    if arr.size and (arr.min() < 0 or arr.max() >= n_targets):
        raise ParameterError(f"{name} must be indices in [0, {n_targets}), got {int(arr.min())}..{int(arr.max())}")
    return arr.astype(int)


def check_target_ids(targets: Any, n_rows: int, name: str = "targets") -> tuple[str, ...] | None:
    """``targets`` as n_rows target ids (strings), or None."""
    if targets is None:
        return None
    if isinstance(targets, (str, bytes)) or not isinstance(targets, (list, tuple, np.ndarray)):
        raise ParameterError(f"{name} must be a sequence of target ids (strings), one per row, "
                             f"got {type(targets).__name__}")
    ids = tuple(targets)
    if len(ids) != n_rows or not all(isinstance(t, str) for t in ids):
        raise ParameterError(f"{name} must hold {n_rows} target ids (strings), one per row")
    return ids


def check_transform(value: Any, name: str) -> np.ndarray:
    """``value`` as a finite (4, 4) float array (a homogeneous transform), else
    :class:`calib.ParameterError` naming ``name``."""
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        T = None
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
        raise ParameterError(f"{name} must be a finite (4, 4) homogeneous transform, got {value!r:.60}")
    return T
