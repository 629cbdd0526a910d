"""The cells of the CSV files calib writes, safe to open in a spreadsheet (CSV or formula
injection), and read back to the text they hold.

A spreadsheet opening a CSV runs a cell that begins with ``=`` (or ``+``, ``-``, ``@``) as a
formula: a joint, target or feature name from a URDF or a measurement file, written as it is,
runs in the user's spreadsheet. OWASP's guidance (the "CSV Injection" page of OWASP's
www-community, ``pages/attacks/CSV_Injection.md`` at commit 0e5e8f0, August 2025; the
characters of the list, quoted as published there):

    To remediate it, ensure that no cells begin with any of the following characters:
    - Equals to (`=`)  - Plus (`+`)  - Minus (`-`)  - At (`@`)
    - Tab (`0x09`)  - Carriage return (`0x0D`)  - Line feed (`0x0A`)

    Keep in mind that it is not sufficient to make sure that the untrusted user input does not
    start with these characters. You also need to take care of the field separator (e.g., `,`,
    or `;`) and quotes (e.g., `'`, or `"`), [...]

and, as the sanitisation it gives: "Prepend each cell field with a single quote" and "Escape
every double quote using an additional double quote". calib does so for each text cell that
begins with one of those characters (:func:`spreadsheet_cell`: a single quote in front, which a
spreadsheet shows as text); the csv module quotes cells holding the separator, a quote or a
line end (RFC 4180), so no text starts a cell in the middle of another. Numbers calib formats
(``-0.5``, ``1e-06``) are numbers to a spreadsheet, not formulas, and stay as they are; a text
cell that begins with a single quote gets another, so that the readers' :func:`read_cell`
gives every cell back exactly (``'=x`` -> ``=x``, ``''x`` -> ``'x``). Comment lines (``# ...``)
are split by a spreadsheet at the commas too: :func:`comment_line` treats each piece as a cell.
"""
from __future__ import annotations

import csv
import io
import re
from typing import Sequence

__all__ = ["FORMULA_LEADS", "spreadsheet_cell", "read_cell", "csv_field", "comment_line", "csv_records", "csv_text"]

#: The characters that make a spreadsheet read a cell as a formula (OWASP, above).
FORMULA_LEADS = frozenset("=+-@\t\r\n")
#: What follows a single quote that calib wrote (a formula lead, or the quote itself).
_ESCAPED = FORMULA_LEADS | {"'"}
#: A decimal number as calib writes it (repr of a float, %g): a number to a spreadsheet.
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def spreadsheet_cell(text: str) -> str:
    """``text`` as a cell no spreadsheet runs as a formula: a single quote in front when it
    begins with one of :data:`FORMULA_LEADS` (and is not a number) or with a single quote;
    otherwise unchanged (a value that is not a str, a number the csv module formats, too).
    :func:`read_cell` undoes it."""
    if isinstance(text, str) and text and (text[0] in FORMULA_LEADS or text[0] == "'") and not _NUMBER.fullmatch(text):
        return "'" + text
    return text


def read_cell(text: str) -> str:
    """A cell as written by :func:`spreadsheet_cell` back to its text: the single quote in front
    of a formula lead (or of another single quote) dropped; any other cell unchanged."""
    if len(text) > 1 and text[0] == "'" and text[1] in _ESCAPED:
        return text[1:]
    return text


def csv_field(text: str) -> str:
    """:func:`spreadsheet_cell` of ``text``, quoted as RFC 4180 and the csv module do when it
    holds a comma, a double quote or a line end (inner quotes doubled): one field of a line that
    is written without the csv module."""
    cell = spreadsheet_cell(text)
    if any(c in cell for c in ',"\r\n'):
        return '"' + cell.replace('"', '""') + '"'
    return cell


def comment_line(text: str) -> str:
    """``# text`` as a comment line whose comma-separated pieces (the cells a spreadsheet splits
    it into) none begins a formula (:func:`spreadsheet_cell` of each piece after the first: the
    first begins with ``#``); readers skip comment lines whole."""
    first, *rest = f"# {text}".rstrip().split(",")
    return ",".join([first] + [spreadsheet_cell(piece) for piece in rest])


def csv_records(rows) -> str:
    """The CSV text of ``rows`` (lists of str cells; ``\\n`` line ends) as the csv module writes
    it, but with a record that holds a carriage return written with every field quoted: the
    csv module quotes only the characters of its line terminator (``\\n``), and a bare carriage
    return ends a line for other readers (a name beginning with one, escaped or not, broke the
    file)."""
    rows = rows if isinstance(rows, list) else list(rows)
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    text = buf.getvalue()
    if "\r" not in text:
        return text
    buf = io.StringIO()
    plain = csv.writer(buf, lineterminator="\n")
    quoted = csv.writer(buf, lineterminator="\n", quoting=csv.QUOTE_ALL)
    for row in rows:
        (quoted if any(isinstance(c, str) and "\r" in c for c in row) else plain).writerow(row)
    return buf.getvalue()


def csv_text(header: Sequence[str], rows, comment: str | None = None,
             text_columns: Sequence[int] | None = None) -> str:
    """CSV text (comma separated, ``\\n`` line ends): ``#`` comment lines, the header, the rows.
    Every header cell, and the cells of ``text_columns`` (indices; None: every column), are
    written so that no spreadsheet runs them as a formula (:mod:`calib.io.csv.cells`); the other
    columns hold numbers calib formatted."""
    buf = io.StringIO()
    if comment is not None:
        for line in str(comment).splitlines() or [""]:
            buf.write(comment_line(line) + "\n")
    records = [[spreadsheet_cell(str(h)) for h in header]]
    if text_columns is None:
        records += ([spreadsheet_cell(c) for c in row] for row in rows)
    elif len(text_columns):
        text_columns = list(text_columns)
        for row in rows:
            row = list(row)
            for k in text_columns:
                row[k] = spreadsheet_cell(row[k])
            records.append(row)
    else:
        records += rows
    buf.write(csv_records(records))
    return buf.getvalue()
