"""The text of a CSV file: its lines, its delimiter, its header line and its data lines.

Part of the CSV layer (:mod:`calib.io.csv.layer` reads the tables): UTF-8 (a byte-order mark is
accepted) with any line ends; ``#`` comment lines and blank lines skipped; the delimiter (comma,
semicolon, tab, else runs of whitespace) the one that splits the header into the most fields;
the header the first line that names known columns (a preamble before it skipped) or the line
given; a file too large for the memory refused before it is read.
"""
from __future__ import annotations

import csv
import math
import os
from operator import methodcaller
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError

_DELIMITERS = (",", ";", "\t")


#: Peak memory of reading a CSV file, in bytes per byte of the file, above the process before
#: the read: scripts/bench_read.py prints the measured figure (2.6 at 1,000,000 rows, 3.3 at
#: 200,000: the text of the lines, their index, the parsed columns and one chunk's scratch), with
#: a margin. A file whose size times this exceeds the memory available is refused before it is
#: read, rather than the process being killed.
READ_BYTES_PER_FILE_BYTE = 4.0


def available_memory() -> int | None:
    """Bytes of memory available to this process: MemAvailable of /proc/meminfo (Linux), else
    the free physical pages; None when unknown."""
    try:
        with open("/proc/meminfo", encoding="utf-8") as fh:     # (ASCII text; utf-8: a codec already loaded)
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_size(path: Path) -> None:
    """Refuse a file too large to read in this machine's memory (see READ_BYTES_PER_FILE_BYTE)."""
    try:
        size = path.stat().st_size
    except OSError:
        return                 # reported by the read itself
    available = available_memory()
    need = size * READ_BYTES_PER_FILE_BYTE
    if available is not None and need > available:
        raise MeasurementFormatError(path, f"{size / 1e6:.0f} MB: reading it needs about "
                                           f"{need / 1e9:.1f} GB of memory, "
                                           f"{available / 1e9:.1f} GB are available; split the file "
                                           f"or use a larger machine")


def _read_stream(path: Path) -> bytes:
    """The bytes of a file that is not a regular file (a pipe, ``<(...)``), read in chunks up to
    what this machine's memory can read (as :func:`check_size`): an endless stream is refused
    once it passes that, not read until memory runs out."""
    available = available_memory()
    limit = int(available / READ_BYTES_PER_FILE_BYTE) if available is not None else 1 << 30
    chunks, total = [], 0
    with open(path, "rb") as fh:
        while True:
            chunk = fh.read(1 << 20)
            if not chunk:
                return b"".join(chunks)
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise MeasurementFormatError(path, f"more than {limit / 1e6:.0f} MB and not at its end: "
                                                   f"more than this machine's memory can read "
                                                   f"(an endless stream?); expected a CSV file")


def read_lines(path: Path) -> list[str]:
    import stat

    try:
        mode = path.stat().st_mode
    except OSError:
        mode = None            # reported by the read itself
    if mode is not None and (stat.S_ISCHR(mode) or stat.S_ISBLK(mode)):
        raise MeasurementFormatError(path, "is a device, expected a CSV file")
    if mode is not None and stat.S_ISREG(mode):
        check_size(path)
    try:
        data = path.read_bytes() if mode is None or stat.S_ISREG(mode) or stat.S_ISDIR(mode) \
            else _read_stream(path)
    except FileNotFoundError:
        raise MeasurementFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise MeasurementFormatError(path, "is a directory, expected a CSV file") from None
    except OSError as exc:
        raise MeasurementFormatError(path, f"cannot be read: {exc.strerror or exc}") from None
    if not data:
        raise MeasurementFormatError(path, "file is empty, expected a header row and data rows")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        row = data[:exc.start].count(b"\n") + 1
        raise MeasurementFormatError(path, f"not UTF-8 text (byte 0x{data[exc.start]:02x})",
                                     row=row) from None
    del data        # (a million rows: each copy of the file held at once costs 250 MB)
    if "\r" in text:
        if '"' in text and text.count("\r") != text.count("\r\n"):
            # a carriage return of its own in a quoted field is the field's (a name that begins
            # with one, as calib writes it: calib.io.csv.cells): line ends converted outside
            # quotes only (between an even number of quotes from the start)
            parts = text.split('"')
            parts[::2] = [p.replace("\r\n", "\n").replace("\r", "\n") for p in parts[::2]]
            text = '"'.join(parts)
        else:
            text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text.split("\n")


def parse_number(path: Path, row: int, column: str, text: str, decimal_comma: bool = False) -> float:
    s = text.strip()
    if not s:
        raise MeasurementFormatError(path, "empty value, expected a number", row, column)
    t = s.replace(",", ".") if decimal_comma and s.count(",") == 1 and "." not in s else s
    try:
        if "_" in t:
            raise ValueError(t)
        value = float(t)
    except ValueError:
        hint = ""
        if "," in s and not decimal_comma:
            hint = " (a decimal comma is read only in files separated by ; or tabs)"
        raise MeasurementFormatError(path, f"{s!r} is not a number{hint}", row, column) from None
    if math.isnan(value):
        raise MeasurementFormatError(path, f"{s!r}: NaN value, expected a finite number", row, column)
    if math.isinf(value):
        raise MeasurementFormatError(path, f"{s!r}: infinite value, expected a finite number",
                                     row, column)
    return value


WHITESPACE = " "
#: How many non-comment lines before the header a preamble may hold.
MAX_PREAMBLE = 200


def split_fields(path: Path, row: int, line: str, delimiter: str = ",") -> list[str]:
    if delimiter == WHITESPACE:
        return line.split()
    try:
        return next(csv.reader([line], delimiter=delimiter, strict=True))
    except csv.Error as exc:
        raise MeasurementFormatError(path, f"malformed CSV: {exc}", row=row) from None


def _field_count(path: Path, row: int, line: str, delimiter: str) -> int:
    """How many fields ``line`` splits into at ``delimiter``; 0 when it is not valid CSV with it
    (a header quoted field by field, ``"a","b"``, is malformed for every other delimiter)."""
    try:
        return len(split_fields(path, row, line, delimiter))
    except MeasurementFormatError:
        return 0


def _delimiter(path: Path, row: int, line: str) -> str:
    """The delimiter that splits ``line`` into the most fields: comma, semicolon or tab, else
    runs of whitespace (a whitespace-separated log: UR's RTDE recorder)."""
    best = max(_DELIMITERS, key=lambda d: _field_count(path, row, line, d))
    if _field_count(path, row, line, best) <= 1 and len(line.split()) > 1:
        return WHITESPACE
    return best


def _looks_numeric(fields: list[str]) -> bool:
    try:
        [float(f.replace(",", ".")) for f in fields]
    except ValueError:
        return False
    return True


def _has_number(fields: list[str]) -> bool:
    return any(_looks_numeric([f]) for f in fields if f.strip())


def records(path: Path, known=None, header_line: int | None = None, *, columns=None, comments=(),
             named_by: str = "--columns") -> tuple[int | None, list[str], str, list[str], np.ndarray]:
    """(header line number, header names as written, delimiter, the file's lines, (N,) index of
    each data line among them): an index array, not (line number, line) pairs, which cost a
    million-row file 100 MB more.

    The header is line ``header_line`` when given; else the first line that names a known column
    (``known(name) -> bool``) before any line of numbers (the lines before it are a preamble),
    else the first line when it alone comes before the data with the data's field count (whose
    names the header check then explains); other lines before the data, or lines and no data,
    are refused as no header line; a first line that holds numbers as data rows do (a file without
    a header line) is refused naming --columns.

    With ``columns`` (the names of a header-less file's columns: ``--columns``, or an instrument
    preset's, ``named_by`` saying which) the file has no header line: every line that is not a
    comment is data, the delimiter the one that splits the first into ``len(columns)`` fields;
    the header line number returned is None. ``comments``: line prefixes of comment lines besides
    ``#`` (SpatialAnalyzer's ``//``)."""
    return header_of(path, read_lines(path), known, header_line, columns=columns, comments=comments,
                     named_by=named_by)


def header_of(path: Path, lines: list[str], known=None, header_line: int | None = None, *, columns=None,
              comments=(), named_by: str = "--columns") -> tuple[int | None, list[str], str, list[str], np.ndarray]:
    """:func:`records` of the file's ``lines`` (as :func:`read_lines` gives them; a file's
    first lines alone find its header as well, e.g. to tell its kind without reading it whole)."""
    heads = list(map(str.lstrip, lines))      # (map over C methods: no Python frame per line)
    records = np.flatnonzero(np.fromiter(map(bool, heads), bool, len(lines)) &
                             ~np.fromiter(map(methodcaller("startswith", ("#",) + tuple(comments)), heads),
                                          bool, len(lines)))
    del heads
    if columns is not None:
        return _headerless(path, lines, records, list(columns), named_by)
    if header_line is not None:
        k = header_line - 1
        size = len(lines) - (not lines[-1])       # (a final line end starts no line)
        what = ("past the end of the file" if k >= size else
                "a blank line" if not lines[k].strip() else
                "a comment line" if lines[k].lstrip().startswith("#") else "")
        if what:
            raise MeasurementFormatError(path, f"--header-line {header_line} is {what} (the file has "
                                               f"{size} lines), expected the "
                                               f"line of column names", row=header_line)
        first = int(np.searchsorted(records, k))
    else:
        if not len(records):
            raise MeasurementFormatError(path, "no header row: the file holds only comments and "
                                               "blank lines")
        first = 0
        if known is not None:
            window = records[:MAX_PREAMBLE].tolist()
            for j, k in enumerate(window):
                row = k + 1
                delimiter = _delimiter(path, row, lines[k])
                names = split_fields(path, row, lines[k], delimiter)
                if _looks_numeric(names):
                    # one line before the data is its header (of names calib does not know: the
                    # header check says what they should be) when it has the data's field count;
                    # two or more, or one of another width, are a preamble
                    if j >= 2 or (j == 1 and _field_count(path, row, lines[k], previous) != width):
                        shown = f"lines {records[0] + 1}-{records[j - 1] + 1}" if j > 1 else \
                            f"line {records[0] + 1}"
                        raise MeasurementFormatError(
                            path, f"no header line: {shown} {'name' if j > 1 else 'names'} no "
                                  f"column calib knows and line {row} is data; expected a line of "
                                  f"column names (such as joint1_deg, x_mm; calib formats lists "
                                  f"them) before the data, or --header-line N for a header calib "
                                  f"does not recognise, or --columns NAMES for a file without "
                                  f"one{_instrument_hint(lines, records)}", row=row)
                    break
                if any(known(n) for n in names):
                    first = j
                    break
                previous, width = delimiter, len(names)
            else:
                # no line is data and none has a number: not a header over rows with labels
                if len(records) <= MAX_PREAMBLE and not any(
                        _has_number(split_fields(path, k + 1, lines[k], _delimiter(path, k + 1, lines[k])))
                        for k in window):
                    shown = f"lines {records[0] + 1}-{records[-1] + 1} name" if len(records) > 1 \
                        else f"line {records[0] + 1} names"
                    raise MeasurementFormatError(
                        path, f"no header line and no data: {shown} no column calib knows and no "
                              f"line is data; expected a line of column names (such as joint1_deg, "
                              f"x_mm; calib formats lists them) followed by data rows",
                        row=int(records[0]) + 1)
                # lines with numbers, none all numbers, no known name: the first line that is
                # not SpatialAnalyzer's // comment holds numbers as data rows do: no header line
                first = next((i for i, k in enumerate(window) if not lines[k].lstrip().startswith("//")), 0)
                k = records[first]
                if _has_number(split_fields(path, k + 1, lines[k], _delimiter(path, k + 1, lines[k]))):
                    raise MeasurementFormatError(
                        path, f"no header line: line {k + 1} holds numbers, as data rows do, and no line "
                              f"names a column calib knows; give the file's column names with --columns "
                              f"NAMES (e.g. --columns 'point,x_mm,y_mm,z_mm'; calib formats lists the "
                              f"names){_instrument_hint(lines, records)}", row=int(k) + 1)
    k = int(records[first])
    header_row, header_line_text = k + 1, lines[k]
    best = _delimiter(path, header_row, header_line_text)
    names = split_fields(path, header_row, header_line_text, best)
    if _looks_numeric(names):
        raise MeasurementFormatError(path, "this line looks like data, expected the header row "
                                           "(column names such as joint1_deg, x_mm; a line starting "
                                           "with # is a comment), or --columns NAMES for a file "
                                           "without one", row=header_row)
    return header_row, names, best, lines, records[first + 1:]


def _instrument_hint(lines: list[str], records: np.ndarray) -> str:
    """"; lines starting with // ... --instrument spatialanalyzer" when the file's first lines
    are SpatialAnalyzer's comments, else ""."""
    if any(lines[k].lstrip().startswith("//") for k in records[:MAX_PREAMBLE].tolist()):
        return ("; lines starting with // are comments of a SpatialAnalyzer ASCII export: "
                "--instrument spatialanalyzer reads it")
    return ""


def _headerless(path: Path, lines: list[str], records: np.ndarray, columns: list[str], named_by: str):
    """(None, ``columns``, delimiter, lines, records) of a file without a header line: the
    delimiter (tab, semicolon, comma, else whitespace: the first of them) that splits the first
    data line into one field per name."""
    if not len(records):
        raise MeasurementFormatError(path, "no data rows: the file holds only comments and blank lines")
    k = int(records[0])
    # (tab and semicolon first: a line of decimal commas, 1,5;2,5, may split into as many at commas)
    counts = {d: _field_count(path, k + 1, lines[k], d) for d in ("\t", ";", ",")}
    counts[WHITESPACE] = len(lines[k].split())
    fits = [d for d, n in counts.items() if n == len(columns)]
    if not fits:
        shown = max(counts.values())
        raise MeasurementFormatError(path, f"wrong number of fields: {shown}, expected {len(columns)} (one "
                                           f"per column named by {named_by}: {', '.join(columns)})"
                                           f"{_instrument_hint(lines, records[:1])}", row=k + 1,
                                     column=columns[shown] if shown < len(columns) else None)
    return None, columns, fits[0], lines, records


