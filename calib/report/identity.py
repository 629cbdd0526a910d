"""What makes a report a certificate a customer signs: its number, the measurement date, the
instrument and its own calibration date, and the people who measured and approve it.

The facts come from three places, each named in the report so that a reader knows what was
measured and what was declared:

- the identity fields given by the user (``--meta``: a YAML / JSON file or ``KEY=VALUE`` pairs;
  :data:`FIELDS` lists the ones read here, any other is shown as given);
- the input files' sha256 (:func:`calib.report.build.file_provenance`): the certificate
  number, when none is given, is derived from them (:func:`certificate_number`), so that anyone
  holding the files can check that a certificate belongs to them;
- the data's own time column: the measurement date is the first and last timestamp of the rows
  when the timestamps are dates and times (``unix_time_s`` of :attr:`calib.Measurements.columns`,
  from a join by time on ISO 8601 stamps); else the ``measurement_date`` field; else the
  modification date of the measurement files, labelled as such (it is when the file was last
  written, not necessarily when the robot was measured).

Only the standard library is imported here: the CLI checks the identity fields before any work.
"""
from __future__ import annotations

import datetime
import hashlib
import math
import re
from typing import Mapping, Sequence

from calib.errors import ParameterError

__all__ = ["FIELDS", "DATE_FIELDS", "DATA_ROLES", "check_fields", "parse_date", "certificate_number",
           "measurement_date", "instrument", "approval", "certificate_identity", "number_digest_text"]

#: The identity fields this module reads (any other field is shown in the report as given).
FIELDS = {
    "certificate_number": "the certificate's number (default: derived from the input files' sha256)",
    "customer": "who the certificate is for",
    "robot_serial": "the robot's serial number",
    "instrument": "the measuring instrument (make, model)",
    "instrument_serial": "the instrument's serial number",
    "instrument_calibration_date": "the date of the instrument's own calibration (YYYY-MM-DD)",
    "instrument_certificate": "the number of the instrument's calibration certificate",
    "measurement_date": "when the robot was measured (YYYY-MM-DD), when the data carry no dates",
    "operator": "who measured (the signature block's 'measured by')",
    "approved_by": "who approves the certificate (the signature block's 'approved by')",
}
#: Fields that hold a date: ISO 8601, YYYY-MM-DD or a date and time.
DATE_FIELDS = ("instrument_calibration_date", "measurement_date")
#: The roles of report inputs that hold the data certified (the number is derived from them; the
#: identity file, role ``meta``, is not data).
DATA_ROLES = ("robot", "measurements", "tracker", "validation")
#: The roles whose files hold the measurements (their dates stand in for the measurement date):
#: the instrument's file when a joint file is joined to one, else the measurement file.
_MEASURED_ROLES = ("tracker", "measurements", "validation")
_NUMBER = re.compile(r"[\w][\w ./#:-]{0,63}")
_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")


def parse_date(text: str, field: str = "date") -> datetime.date | datetime.datetime:
    """A date (``YYYY-MM-DD``) or a date and time (``YYYY-MM-DDTHH:MM[:SS][Z|+HH:MM]``) of ISO
    8601; :class:`calib.ParameterError` naming ``field`` otherwise."""
    s = str(text).strip()
    try:
        if _DATE.fullmatch(s):
            return datetime.date.fromisoformat(s)
        if _DATE.match(s) and len(s) > 10 and s[10] in "T ":
            return datetime.datetime.fromisoformat(s[:-1] + "+00:00" if s.endswith("Z") else s)
    except ValueError:
        pass
    raise ParameterError(f"meta {field}: {s!r} is not a date: expected YYYY-MM-DD (ISO 8601), e.g. 2026-11-25")


def check_fields(meta: Mapping[str, str]) -> None:
    """Refuse identity fields this module would misread: a date field that is not an ISO 8601
    date, a certificate number that is not one line of at most 64 letters, digits and ``-./#:``
    (:class:`calib.ParameterError`, one line naming the field)."""
    for name in DATE_FIELDS:
        if name in meta:
            parse_date(meta[name], name)
    number = meta.get("certificate_number")
    if number is not None and not _NUMBER.fullmatch(str(number).strip()):
        raise ParameterError(f"meta certificate_number: {number!r:.80} is not a certificate number: expected one "
                             f"line of at most 64 letters, digits, spaces and - . / # :")


def number_digest_text(inputs: Mapping[str, Mapping]) -> str:
    """The text whose sha256 gives the derived certificate number: one line ``ROLE SHA256`` per
    input file of a data role (:data:`DATA_ROLES`), in that order, each ended by a newline."""
    return "".join(f"{role} {inputs[role]['sha256']}\n" for role in DATA_ROLES if role in inputs)


def certificate_number(inputs: Mapping[str, Mapping], meta: Mapping[str, str]) -> dict:
    """``{"number", "from"}``: the ``certificate_number`` field when given (``from`` "meta"),
    else ``CAL-`` and the first 12 hex digits (upper case, in groups of 4) of the sha256 of
    :func:`number_digest_text` of ``inputs`` (role -> ``{"sha256", ...}`` as in a report's
    provenance; ``from`` "input sha256"); None without either."""
    if meta.get("certificate_number"):
        return {"number": str(meta["certificate_number"]).strip(), "from": "meta", "roles": []}
    text = number_digest_text(inputs)
    if not text:
        return {"number": None, "from": None, "roles": []}
    h = hashlib.sha256(text.encode("ascii")).hexdigest()[:12].upper()
    return {"number": f"CAL-{h[:4]}-{h[4:8]}-{h[8:]}", "from": "input sha256",
            "roles": [r for r in DATA_ROLES if r in inputs]}


def _utc(seconds: float) -> str:
    t = datetime.datetime.fromtimestamp(seconds, datetime.timezone.utc)
    return t.isoformat(timespec="seconds").replace("+00:00", "Z")


def measurement_date(columns: Mapping, inputs: Mapping[str, Mapping], meta: Mapping[str, str]) -> dict:
    """When the robot was measured: ``{"first", "last", "source", "label", ...}``.

    ``source`` is ``"data"`` when ``columns["unix_time_s"]`` (seconds since 1970-01-01 UTC per
    row, NaN where unknown) has a value: ``first`` and ``last`` are its extreme stamps (ISO 8601,
    UTC), ``rows`` how many rows carry one; else ``"meta"`` with the ``measurement_date`` field;
    else ``"file date"``: the modification times (``modified`` of ``inputs``) of the measurement
    files (the instrument's file when there is one, and a validation file), ``files`` their paths;
    else ``"unknown"``."""
    stamps = columns.get("unix_time_s") if columns is not None else None
    if stamps is not None:
        import numpy as np

        values = np.asarray(stamps, float)
        values = values[np.isfinite(values)]
        if len(values):
            first, last = _utc(float(values.min())), _utc(float(values.max()))
            span = first.replace("T", " ").replace("Z", "") + (
                "" if first == last else " to " + (last[11:] if last[:10] == first[:10] else last.replace("T", " "))
                .replace("Z", ""))
            return {"first": first, "last": last, "source": "data", "rows": len(values),
                    "label": f"{span} UTC (the time column of the data, {len(values)} rows)"}
    if meta.get("measurement_date"):
        text = str(meta["measurement_date"]).strip()
        return {"first": text, "last": text, "source": "meta", "label": f"{text} (as given: measurement_date)"}
    roles = [r for r in _MEASURED_ROLES if r in inputs and inputs[r].get("modified")
             and not (r == "measurements" and "tracker" in inputs)]
    if roles:
        dates = sorted(inputs[r]["modified"] for r in roles)
        names = ", ".join(str(inputs[r]["path"]).replace("\\", "/").rsplit("/", 1)[-1] for r in roles)
        span = dates[0][:10] + ("" if dates[-1][:10] == dates[0][:10] else f" to {dates[-1][:10]}")
        return {"first": dates[0], "last": dates[-1], "source": "file date",
                "files": [str(inputs[r]["path"]) for r in roles],
                "label": f"file date {span} (last modified: {names}; the data carry no dates)"}
    return {"first": None, "last": None, "source": "unknown",
            "label": "unknown (no dates in the data; give --meta measurement_date=YYYY-MM-DD)"}


def instrument(meta: Mapping[str, str]) -> dict:
    """The instrument as declared: ``{"name", "serial", "calibration_date", "certificate"}``
    (None where not given)."""
    return {"name": meta.get("instrument"), "serial": meta.get("instrument_serial"),
            "calibration_date": meta.get("instrument_calibration_date"),
            "certificate": meta.get("instrument_certificate")}


def approval(meta: Mapping[str, str]) -> list[dict]:
    """The signature block: ``[{"role", "name"}]`` for "measured by" (``operator``) and
    "approved by" (``approved_by``), the name None where not given (a line to write it on)."""
    return [{"role": "measured by", "name": meta.get("operator")},
            {"role": "approved by", "name": meta.get("approved_by")}]


def certificate_identity(provenance: Mapping, meta: Mapping[str, str], columns: Mapping | None) -> dict:
    """The certificate's identity (JSON-ready) from a report's ``provenance`` (its ``inputs``
    with sha256 and modification times, and its ``date``), the identity fields ``meta`` and the
    rows' ``columns``: ``number``, ``number_from`` and ``number_inputs`` (the roles it was
    derived from: :func:`certificate_number`), ``issued``
    (the report's date), ``measurement_date`` (:func:`measurement_date`), ``instrument``
    (:func:`instrument`), ``signatures`` (:func:`approval`) and ``notes`` (an instrument
    calibrated after the measurement)."""
    inputs = provenance.get("inputs") or {}
    number = certificate_number(inputs, meta)
    when = measurement_date(columns or {}, inputs, meta)
    inst = instrument(meta)
    notes: Sequence[str] = []
    if inst["calibration_date"] and when["first"] and when["source"] in ("data", "meta"):
        cal = parse_date(inst["calibration_date"], "instrument_calibration_date")
        cal_day = cal if not isinstance(cal, datetime.datetime) else cal.date()
        if cal_day.isoformat() > str(when["last"])[:10]:
            notes = [f"the instrument's calibration ({inst['calibration_date']}) is dated after the measurement "
                     f"({str(when['last'])[:10]})"]
    return {"number": number["number"], "number_from": number["from"], "number_inputs": number["roles"],
            "issued": provenance.get("date"),
            "measurement_date": when, "instrument": inst, "signatures": approval(meta), "notes": list(notes)}
