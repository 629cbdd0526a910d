"""Joining a joint file and a tracker (instrument) file into one measurement per measured row.

The joint file (the controller's log: joint values, with ``set`` and ``target`` if wanted) and the
tracker file (the instrument's export: x, y, z and an orientation) are each read by
:func:`calib.io.csv.layer.read_table` with the specs :func:`sides` gives; this module pairs their
rows as :attr:`calib.ReadOptions.join` says (options checked by :func:`check_join_options`):

- ``"key"``: by the value of the column ``key`` present in both files, rows in any order. A joint
  row goes with one measured row, or with several when each measured row carries the id of the
  target (reflector) it measured (the laser-tracker case: 3 SMRs measured at each pose). The id
  comes from a ``target`` column of the tracker file, from its column ``target_column``, or from a
  compound point name in its key column (``P001_SMR2``) split by ``target_from``: a regular
  expression with the named groups ``key`` and ``target`` that must match the whole cell, e.g.
  ``(?P<key>P\\d+)_(?P<target>SMR\\d+)``. Every key of either file must be in the other; a key
  twice in the joint file, or a key with the same target twice in the tracker file, is an error.
- ``"nearest-time"``: each measured row with the joint row whose timestamp in the column
  ``time`` (of both files) is nearest, at most ``max_gap`` seconds away: a joint log recorded at
  100 Hz and a tracker measuring at its own times. Timestamps are numbers in the unit of
  ``time_unit`` or of the column name's suffix (``time_s``, ``time_ms``, ``time_us``,
  ``time_ns``), times of day (``10:00:07.125``, within one day) or ISO 8601 dates and times
  (``2026-11-25T10:00:07.125``, a time zone read as UTC), the same in both files; the search is
  vectorised (``np.searchsorted`` over the sorted joint times). Refused: a measured row with no
  joint row within ``max_gap``; a measured row with two joint rows of different joint values
  equally near (to :data:`TIME_RESOLUTION`), which includes two joint rows with the same
  timestamp. Joint rows never joined (the robot moving between poses) are left out; a joint log
  not in time order is joined all the same, with a note.

When the two files name the key or the time column differently, ``key`` and ``time`` are
``JOINT=TRACKER`` (``Point=Target``, ``timestamp=Time [s]``): each file's own name
(:func:`split_sides`); a name is matched as the header check reads it (``Time [s]`` is
``time_s``). Each result row is named (:func:`_names`): the joint file's ``point`` / ``name`` /
``waypoint`` column, else the tracker's, else the tracker's key cells.

The result (:class:`Joined`) has one row per measured row, in the order of the joint rows they
join (the measured rows of one joint row in the order of the tracker file); each carries the
joint values of its joint row and its own target, so a configuration measured at three targets
is three rows, as in calib's own multi-target files. Errors are
:class:`calib.MeasurementFormatError` naming the file, row and column, and what was expected.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.csv.options import (TARGET_FROM_EXAMPLE, TIME_UNITS, ReadOptions, Spec, Table, check_target_from,
                                  key_columns, label_of, name_unit, split_sides)


__all__ = ["TIME_RESOLUTION", "Joined", "sides", "join_tables"]

#: Two gaps closer than this (seconds) are equally near; a gap this much over ``max_gap`` is
#: still within it (the rounding of decimal timestamps; epoch seconds in float64 resolve 0.24 us).
TIME_RESOLUTION = 1e-6

_CLOCK = re.compile(r"(\d{1,2}):(\d{2}):(\d{2}(?:\.\d*)?)")


# ====================================================================== specs
def _time_labels(options: ReadOptions) -> tuple[str, str] | None:
    """The labels of the time column in the joint file and in the tracker file, or None."""
    return None if options.time is None else tuple(map(label_of, split_sides(options.time)))


def _target_label(options: ReadOptions) -> str:
    return "target" if options.target_column is None else options.target_column.lower()


def sides(joint: Spec, tracker: Spec, options: ReadOptions) -> tuple[Spec, Spec]:
    """The specs of the joint file and the tracker file for ``options``: ``joint`` and
    ``tracker`` (:data:`calib.io.csv.specs.JOINT_SIDE`, :data:`~calib.io.csv.specs.TRACKER_SIDE`) keyed by
    ``key``, or with the time column as a label for a join by time; the tracker's with the
    target column ``target_column`` as a label."""
    from dataclasses import replace

    times = _time_labels(options)
    target = _target_label(options)
    keyed = options.join == "key"
    keys = key_columns(options) if keyed and options.key is not None else (None, None)

    def side(spec, k: int, more=()):
        time = None if times is None else times[k]
        extra = (time,) if time is not None else ()
        # the join's time column is a label (text: numbers, times of day, dates), not the
        # report's per-row time quantity (time_s, ...) that a spec may also name
        extras = tuple(e for e in spec.extras if time is None or not (time == e or time.startswith(e + "_")))
        return replace(spec, labels=tuple(dict.fromkeys(spec.labels + more + extra)), keyed=keyed,
                       sparse=spec.sparse + extra, extras=extras, key=keys[k])
    return side(joint, 0), side(tracker, 1, (target,))


# ====================================================================== joining
@dataclass(frozen=True, eq=False)
class Joined:
    """Two tables joined: result row ``k`` is joint row ``joint[k]`` with tracker row ``tracker[k]``.

    joint, tracker : (M,) int, indices into the rows of the joint and the tracker table.
    labels : ``set``, ``target``, ``pose_id`` and ``name`` -> (M,) tuple of str, or None where neither
        file has it (``name``: see :func:`_names`).
    one_to_one : each joint row gives exactly one result row (then the result keeps the joint
        file's row numbers; otherwise the tracker file's, one per measured row).
    notes : one-line remarks of the join (a joint log not in time order).
    unix_time_s : (M,) float, the measured rows' timestamps as seconds since 1970-01-01 UTC when
        they are dates and times (a join by time on ISO 8601 stamps: when the robot was
        measured), else None.
    """

    joint: np.ndarray
    tracker: np.ndarray
    labels: dict
    one_to_one: bool
    notes: tuple[str, ...] = ()
    unix_time_s: np.ndarray | None = None


def join_tables(j: Table, t: Table, options: ReadOptions) -> Joined:
    """Join the joint table ``j`` and the tracker table ``t`` (read with the specs of
    :func:`sides`) as ``options.join`` says (module docstring)."""
    target, target_col = _tracker_targets(t, options)
    notes: tuple[str, ...] = ()
    dates = None
    if options.join == "key":
        jidx, tidx, target, target_col = _by_key(j, t, options, target, target_col)
        how = "same key"
    else:
        jidx, tidx, notes, dates = _by_time(j, t, options)
        how = "joined by time"
    order = np.lexsort((tidx, jidx))          # joint row order, then the tracker file's
    jidx, tidx = jidx[order], tidx[order]
    labels = {"set": _agree(j, t, jidx, tidx, "set", None, t.names.get("set"), how)}
    tt = None if target is None else [target[i] for i in tidx]
    labels["target"] = _agree(j, t, jidx, tidx, "target", tt, target_col, how)
    labels["pose_id"] = _agree(j, t, jidx, tidx, "pose_id", None, t.names.get("pose_id"), how)
    labels["name"] = _names(j, t, jidx, tidx, options)
    one = len(jidx) == len(j.rows) and len(np.unique(jidx)) == len(jidx)
    return Joined(joint=jidx, tracker=tidx, labels=labels, one_to_one=bool(one), notes=notes,
                  unix_time_s=None if dates is None else dates[tidx])


def _names(j: Table, t: Table, jidx, tidx, options: ReadOptions) -> tuple | None:
    """The name of each result row: the joint file's name column (``point``, ``name``,
    ``waypoint``), else the tracker file's, else the tracker's key cells (its point names); None
    without any. Two name columns need not agree: a waypoint and the point measured there."""
    if "name" in j.labels:
        return tuple(j.labels["name"][i] for i in jidx)
    if "name" in t.labels:
        return tuple(t.labels["name"][i] for i in tidx)
    if options.join == "key":
        cells = t.labels[key_columns(options)[1]]
        return tuple(cells[i] for i in tidx)
    return None


def _tracker_targets(t: Table, options: ReadOptions) -> tuple[tuple | None, str | None]:
    """The target ids of the tracker table's rows (from ``target`` or ``target_column``) and the
    column they came from; (None, None) without one."""
    label = _target_label(options)
    if options.target_column is not None:
        if label not in t.labels:
            raise MeasurementFormatError(t.path, f"no target column {options.target_column!r} (given by "
                                                 f"--target-column)", row=t.header_row)
        if label != "target" and "target" in t.labels:
            raise MeasurementFormatError(t.path, f"two target columns: {t.names['target']!r} and "
                                                 f"{t.names[label]!r} (given by --target-column); give one",
                                         row=t.header_row, column=t.names[label])
    if label not in t.labels:
        return None, None
    return t.labels[label], t.names[label]


def _by_key(j: Table, t: Table, options: ReadOptions, target, target_col):
    jkey, key = key_columns(options)
    jkeys, cells = j.labels[jkey], t.labels[key]
    if options.target_from is not None:
        if target is not None:
            raise MeasurementFormatError(t.path, f"a target column ({target_col!r}) and --target-from: "
                                                 f"the target id comes from one of them; drop the column "
                                                 f"(--rename '{target_col}=') or --target-from",
                                         row=t.header_row, column=target_col)
        rx = check_target_from(options.target_from)
        tkeys, target = [], []
        for k, cell in enumerate(cells):
            m = rx.fullmatch(cell)
            if m is None or not m.group("key") or not m.group("target"):
                why = "does not match" if m is None else "leaves the key or the target empty by"
                raise MeasurementFormatError(
                    t.path, f"{cell!r} {why} --target-from {options.target_from!r}: expected a point "
                            f"name that it matches whole, with a non-empty key and target",
                    row=int(t.rows[k]), column=t.names[key])
            tkeys.append(m.group("key"))
            target.append(m.group("target"))
        target, target_col = tuple(target), t.names[key]
    else:
        tkeys = cells
    jpos: dict[str, int] = {}
    for k, value in enumerate(jkeys):
        if value in jpos:
            raise MeasurementFormatError(j.path, f"duplicated key {value!r} (also in row "
                                                 f"{j.rows[jpos[value]]})", row=int(j.rows[k]),
                                         column=j.names[jkey])
        jpos[value] = k
    seen: dict[tuple, int] = {}
    for k, value in enumerate(tkeys):
        pair = (value, None if target is None else target[k])
        if pair in seen:
            if options.target_from is not None:
                what = f"duplicated point {cells[k]!r}: key {value!r} and target {pair[1]!r}"
                hint = ""
            elif target is not None:
                what, hint = f"duplicated key {value!r} with target {pair[1]!r}", ""
            else:
                what = f"duplicated key {value!r}"
                hint = ("; several measured rows of one joint row need a target id each: a target "
                        "column (--target-column) or compound point names split by --target-from "
                        f"(e.g. {TARGET_FROM_EXAMPLE!r})")
            raise MeasurementFormatError(t.path, f"{what} (also in row {t.rows[seen[pair]]}){hint}",
                                         row=int(t.rows[k]), column=t.names[key])
        seen[pair] = k
    in_t = set(tkeys)
    for k, value in enumerate(jkeys):
        if value not in in_t:
            raise MeasurementFormatError(j.path, f"key {value!r} is not in {t.path}", row=int(j.rows[k]),
                                         column=j.names[jkey])
    for k, value in enumerate(tkeys):
        if value not in jpos:
            via = f" (of {cells[k]!r}, by --target-from)" if options.target_from is not None else ""
            raise MeasurementFormatError(t.path, f"key {value!r}{via} is not in {j.path}",
                                         row=int(t.rows[k]), column=t.names[key])
    jidx = np.fromiter((jpos[v] for v in tkeys), dtype=np.int64, count=len(tkeys))
    return jidx, np.arange(len(tkeys)), target, target_col


def _agree(j: Table, t: Table, jidx, tidx, label: str, b, b_col, how: str):
    """The label of each result row from either file (``b``: the tracker's, in result order; a
    label in both must agree row by row)."""
    a = j.labels.get(label)
    a = None if a is None else [a[i] for i in jidx]
    if b is None and label in t.labels:
        b = [t.labels[label][i] for i in tidx]
    if a is not None and b is not None:
        for k, (x, y) in enumerate(zip(a, b)):
            if x != y:
                raise MeasurementFormatError(
                    t.path, f"{label} {y!r} differs from {x!r} in row {j.rows[jidx[k]]} of {j.path} "
                            f"({how}); give {label} in one file or the same in both",
                    row=int(t.rows[tidx[k]]), column=b_col)
    out = a if a is not None else b
    return None if out is None else tuple(out)


# ====================================================================== by time
def _by_time(j: Table, t: Table, options: ReadOptions):
    jlabel, label = _time_labels(options)
    for table, lab, name in zip((j, t), (jlabel, label), split_sides(options.time)):
        if lab not in table.labels:
            given = f" {options.time!r}" if "=" in options.time else ""
            raise MeasurementFormatError(table.path, f"no time column {name!r} (given by --time{given})",
                                         row=table.header_row)
    tj, kind_j = _seconds(j, jlabel, options)
    tt, kind_t = _seconds(t, label, options)
    col = t.names[label]
    if kind_j != kind_t:
        raise MeasurementFormatError(t.path, f"timestamps are {kind_t} here but {kind_j} in {j.path}: "
                                             f"give both files' times the same way", row=int(t.rows[0]),
                                     column=col)
    notes = []
    back = np.flatnonzero(np.diff(tj) < 0)
    if len(back):
        notes.append(f"{j.path}: timestamps not in time order (row {j.rows[back[0] + 1]} is earlier than "
                     f"row {j.rows[back[0]]}{f' and {len(back) - 1} more' if len(back) > 1 else ''}); "
                     f"joined to the nearest time all the same")
    order = np.argsort(tj, kind="stable")
    ts = tj[order]
    n = len(ts)
    i = np.searchsorted(ts, tt)                     # ts[i - 1] < tt <= ts[i]
    left, right = np.clip(i - 1, 0, n - 1), np.clip(i, 0, n - 1)
    with np.errstate(invalid="ignore"):
        dl = np.where(i > 0, tt - ts[left], np.inf)
        dr = np.where(i < n, ts[right] - tt, np.inf)
    pick = np.where(dr < dl, right, left)
    gap = np.minimum(dl, dr)
    far = np.flatnonzero(gap > options.max_gap + TIME_RESOLUTION)
    if len(far):
        k = far[0]
        raise MeasurementFormatError(
            t.path, f"no joint row within --max-gap {options.max_gap:g} s of {t.labels[label][k]!r}: the "
                    f"nearest is row {j.rows[order[pick[k]]]} of {j.path}, {gap[k]:.6g} s away"
                    f"{f' ({len(far) - 1} more rows of this file are too far)' if len(far) > 1 else ''}",
            row=int(t.rows[k]), column=col)
    # every joint row as near as the nearest (to the resolution): one, or several of equal joints
    lo = np.searchsorted(ts, tt - gap - TIME_RESOLUTION, "left")
    hi = np.searchsorted(ts, tt + gap + TIME_RESOLUTION, "right")
    for k in np.flatnonzero(hi - lo > 1):
        near = order[lo[k]:hi[k]]
        q = j.q[near]
        differ = np.flatnonzero((q != q[0]).any(axis=1))
        if len(differ):
            a, b = sorted((int(near[0]), int(near[differ[0]])))
            same = abs(tj[a] - tj[b]) <= TIME_RESOLUTION
            what = (f"rows {j.rows[a]} and {j.rows[b]} of {j.path} have the same timestamp "
                    f"{j.labels[jlabel][a]!r}" if same else
                    f"rows {j.rows[a]} and {j.rows[b]} of {j.path} ({j.labels[jlabel][a]!r} and "
                    f"{j.labels[jlabel][b]!r}) are equally near {t.labels[label][k]!r}")
            raise MeasurementFormatError(
                t.path, f"{what}, with different joint values: the join by nearest time is ambiguous; "
                        f"expected one nearest joint row (a timestamp written more finely, or a joint "
                        f"log without repeated times)", row=int(t.rows[k]), column=col)
    return order[pick], np.arange(len(tt)), tuple(notes), (tt if kind_t == "dates and times" else None)


def _seconds(table: Table, label: str, options: ReadOptions) -> tuple[np.ndarray, str]:
    """(N,) seconds of the time column of ``table``, and "numbers", "times of day" or "dates and
    times"."""
    texts = list(table.labels[label])
    col = table.names[label]
    if "" in texts:
        k = texts.index("")
        raise MeasurementFormatError(table.path, "empty timestamp, expected a number, a time of day or "
                                                 "an ISO 8601 date and time", row=int(table.rows[k]),
                                     column=col)
    if any("," in s for s in texts):          # a decimal comma (files separated by ; or tabs)
        texts = [s.replace(",", ".") if s.count(",") == 1 and "." not in s else s for s in texts]
    try:
        values = np.array(texts, dtype=float)
        kind = "numbers"
    except ValueError:
        clock = [_CLOCK.fullmatch(s) for s in texts]
        if all(clock):
            values = np.array([int(m[1]) * 3600 + int(m[2]) * 60 + float(m[3]) for m in clock])
            kind = "times of day"
        else:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")       # a time zone: read as UTC
                    stamps = np.array(texts, dtype="datetime64[ns]")
            except ValueError:
                _first_bad(table, texts, col, label)
            if np.isnat(stamps).any():
                k = int(np.flatnonzero(np.isnat(stamps))[0])
                raise MeasurementFormatError(table.path, f"{table.labels[label][k]!r} is not a timestamp, "
                                                         f"expected a date and time", row=int(table.rows[k]),
                                             column=col)
            values, kind = stamps.astype(np.int64) * 1e-9, "dates and times"
        if options.time_unit is not None:
            raise MeasurementFormatError(table.path, f"--time-unit {options.time_unit} is the unit of "
                                                     f"timestamps that are numbers; these are {kind} "
                                                     f"({table.labels[label][0]!r}): leave it out",
                                         row=int(table.rows[0]), column=col)
        return values, kind
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        k = int(bad[0])
        raise MeasurementFormatError(table.path, f"{table.labels[label][k]!r}: expected a finite "
                                                 f"timestamp", row=int(table.rows[k]), column=col)
    unit = options.time_unit or name_unit(col)
    if unit is None:
        raise MeasurementFormatError(table.path, f"the timestamps are numbers without a unit: name it in "
                                                 f"the column ({col}_s, {col}_ms) or give --time-unit "
                                                 f"(s, ms, us, ns)", row=table.header_row, column=col)
    return values * TIME_UNITS[unit], kind


def _first_bad(table: Table, texts: list[str], col: str, label: str):
    """Raise for the first cell that is not a timestamp of the kind of the first cell."""
    def number(s):
        try:
            return math.isfinite(float(s))
        except ValueError:
            return False

    def date(s):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return not np.isnat(np.datetime64(s, "ns"))
        except ValueError:
            return False

    def clock(s):
        return _CLOCK.fullmatch(s) is not None

    kinds = {number: "a number", clock: "a time of day", date: "an ISO 8601 date and time"}
    kind = next((f for f in kinds if f(texts[0])), None)
    if kind is not None:
        k = next((k for k, s in enumerate(texts) if not kind(s)), 0)
        expected = f"{kinds[kind]} like row {table.rows[0]}'s"
    else:
        k, expected = 0, ("a number, a time of day (10:00:07.125) or an ISO 8601 date and time "
                          "(2026-11-25T10:00:07.125)")
    raise MeasurementFormatError(table.path, f"{table.labels[label][k]!r} is not a timestamp, expected "
                                             f"{expected}", row=int(table.rows[k]), column=col)
