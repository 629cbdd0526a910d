"""The identity fields of a report (robot serial, instrument, operator, ...) from a small YAML or
JSON file: one mapping of field names to text or numbers, read with PyYAML (YAML is a superset of
JSON, so one reader takes both)."""
from __future__ import annotations

import datetime
from pathlib import Path

from calib.errors import CalibError

__all__ = ["read_meta", "MAX_META_BYTES"]

#: Largest identity file read (bytes): a few fields, not a data set.
MAX_META_BYTES = 65536


def read_meta(path: str | Path) -> dict[str, str]:
    """``{field: text}`` of a YAML / JSON file holding one mapping of names to text, numbers or
    dates (YAML's unquoted ``2026-03-02``: its ISO 8601 text);
    :class:`calib.CalibError` naming the file (and the line for a syntax error) otherwise."""
    path = Path(path)
    if path.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise CalibError(f"--meta {path}: expected KEY=VALUE pairs (robot_serial=R123,operator=J. Doe) "
                         f"or a .yaml / .yml / .json file")
    if not path.is_file():
        raise CalibError(f"{path}: no such file (--meta: a YAML or JSON file of identity fields)")
    data = path.read_bytes()
    if len(data) > MAX_META_BYTES:
        raise CalibError(f"{path}: {len(data)} bytes; an identity file holds a few fields "
                         f"(at most {MAX_META_BYTES} bytes)")
    import yaml

    try:
        doc = yaml.load(data.decode("utf-8-sig"), Loader=_unique_key_loader())
    except UnicodeDecodeError:
        raise CalibError(f"{path}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "not valid YAML / JSON"
        raise CalibError(f"{path}{where}: {problem}") from None
    if not isinstance(doc, dict) or not doc:
        raise CalibError(f"{path}: expected a mapping of identity fields (robot_serial: R123, "
                         f"operator: J. Doe), got {type(doc).__name__}")
    out = {}
    for key, value in doc.items():
        if not isinstance(key, str) or not key.strip():
            raise CalibError(f"{path}: field name {key!r} is not a name")
        if isinstance(value, datetime.date):      # YAML reads 2026-03-02 as a date: kept as written
            value = value.isoformat()
        if isinstance(value, bool) or not isinstance(value, (str, int, float)) or not str(value).strip():
            raise CalibError(f"{path}: field {key}: expected text, a number or a date, got {value!r:.40}")
        out[key.strip()] = str(value).strip()
    return out


def _unique_key_loader():
    """PyYAML's safe loader refusing a mapping that names a key twice (it keeps the last value
    silently; ``--meta a=1,a=2`` is refused, so is ``a: 1`` then ``a: 2`` in a file, and a JSON
    object with a key twice)."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                try:
                    if key in seen:
                        raise yaml.constructor.ConstructorError(
                            None, None, f"field {key} given twice", key_node.start_mark)
                    seen.add(key)
                except TypeError:        # an unhashable key: the base loader says so
                    break
            return super().construct_mapping(node, deep=deep)

    return UniqueKeyLoader
