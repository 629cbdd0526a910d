"""Reading the cell file of ``calib plan`` (``--cell FILE``, the format: :mod:`calib.io.cell`)
into a :class:`calib.io.cell.Cell`: YAML composed by PyYAML's safe loader, each value converted
from the file's units (mm, degrees) to SI, every error one line naming the file, the line and the
key."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.errors import DataError
from calib.io.cell import Box, Camera, Cell, Nest, PlaneRegion, Target, Tracker

__all__ = ["read_cell", "MAX_CELL_BYTES"]

#: Largest cell file read (bytes): a description, not a data set.
MAX_CELL_BYTES = 1 << 20


class _Node:
    """A YAML value with the line it starts at and its key path, for the messages."""

    def __init__(self, value, line: int, path: str):
        self.value, self.line, self.path = value, line, path


def _load(path: Path):
    import yaml

    data = path.read_bytes()
    if len(data) > MAX_CELL_BYTES:
        raise DataError(f"{path}: {len(data)} bytes; a cell file is a short description (at most "
                        f"{MAX_CELL_BYTES} bytes)")
    try:
        node = yaml.compose(data.decode("utf-8-sig"), Loader=yaml.SafeLoader)
    except UnicodeDecodeError:
        raise DataError(f"{path}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise DataError(f"{path}{where}: {getattr(exc, 'problem', None) or 'not valid YAML'}") from None
    return node


class _Reader:
    """Walks the composed YAML nodes, converting scalars with SafeLoader's constructor and
    naming the file, line and key in every error."""

    def __init__(self, path: Path):
        import yaml

        self.path = path
        self.yaml = yaml
        self.constructor = yaml.SafeLoader("")

    def fail(self, node, key: str, what: str):
        line = f", line {node.start_mark.line + 1}" if node is not None else ""
        raise DataError(f"{self.path}{line}: {key}: {what}")

    def mapping(self, node, key: str, allowed: tuple) -> dict:
        if not isinstance(node, self.yaml.MappingNode):
            self.fail(node, key, "expected a mapping of keys to values")
        out = {}
        for k, v in node.value:
            name = self.constructor.construct_object(k) if isinstance(k, self.yaml.ScalarNode) else None
            where = f"{key}.{name}" if key else str(name)
            if name not in allowed:
                self.fail(k, where, f"unknown key; expected one of {', '.join(allowed)}")
            if name in out:
                self.fail(k, where, "given twice")
            out[name] = v
        return out

    def scalar(self, node):
        if not isinstance(node, self.yaml.ScalarNode):
            return None
        return self.constructor.construct_object(node)

    def number(self, node, key: str, scale: float = 1.0, minimum: float | None = None) -> float:
        v = self.scalar(node)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(node, key, f"expected a number, got {self._text(node)}")
        if minimum is not None and v < minimum:
            self.fail(node, key, f"expected a number >= {minimum:g}, got {v!r}")
        return float(v) * scale

    def integer(self, node, key: str, minimum: int = 1, maximum: int = 1000) -> int:
        v = self.scalar(node)
        if isinstance(v, bool) or not isinstance(v, int) or not minimum <= v <= maximum:
            self.fail(node, key, f"expected an integer from {minimum} to {maximum}, got {self._text(node)}")
        return int(v)

    def flag(self, node, key: str) -> bool:
        v = self.scalar(node)
        if not isinstance(v, bool):
            self.fail(node, key, f"expected true or false, got {self._text(node)}")
        return v

    def text(self, node, key: str) -> str:
        v = self.scalar(node)
        if v is None or isinstance(v, (bool, float)) or not str(v).strip():
            self.fail(node, key, f"expected a name, got {self._text(node)}")
        return str(v).strip()

    def numbers(self, node, key: str, count: int | None, scale: float = 1.0) -> np.ndarray:
        if not isinstance(node, self.yaml.SequenceNode) or (count is not None and len(node.value) != count):
            n = "numbers" if count is None else f"{count} numbers"
            self.fail(node, key, f"expected a list of {n} [a, b, ...], got {self._text(node)}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(node.value)]) * scale

    def items(self, node, key: str) -> list:
        if not isinstance(node, self.yaml.SequenceNode):
            self.fail(node, key, "expected a list of entries (- name: ...)")
        return list(node.value)

    @staticmethod
    def _text(node) -> str:
        if hasattr(node, "value") and isinstance(node.value, str):
            return repr(node.value[:40])
        return {"MappingNode": "a mapping", "SequenceNode": "a list"}.get(type(node).__name__, "that")

    def checked(self, node, key: str, make):
        """``make()`` with a value's own DataError given the file, line and key."""
        try:
            return make()
        except DataError as exc:
            self.fail(node, key, str(exc))


def read_cell(path: str | Path) -> Cell:
    """The :class:`Cell` of a YAML cell file (format: the module docstring). Raises
    :class:`calib.DataError` naming the file, line and key of what is wrong."""
    from calib.checks import check_path

    path = check_path(path, "cell")
    if not path.is_file():
        raise DataError(f"{path}: no such file (--cell: a YAML description of the cell)")
    root = _load(path)
    r = _Reader(path)
    if root is None:
        return Cell(source=path)
    top = r.mapping(root, "", ("tracker", "camera", "targets", "touch", "cell"))
    if "tracker" in top and "camera" in top:
        r.fail(top["camera"], "camera", "give a tracker or a camera, not both")
    instrument = None
    for kind in ("tracker", "camera"):
        if kind in top:
            instrument = _instrument(r, top[kind], kind)
    targets = tuple(_target(r, node, f"targets[{i}]") for i, node in enumerate(r.items(top["targets"], "targets"))) \
        if "targets" in top else ()
    if instrument is not None and not targets:
        targets = (Target("T1", np.zeros(3)),)
    features, probe, tip = (), 0.0, np.zeros(3)
    if "touch" in top:
        features, probe, tip = _touch(r, top["touch"])
    kw = _cell_options(r, top["cell"]) if "cell" in top else {}
    node = next((top[k] for k in ("touch", "targets", "tracker", "camera") if k in top), root)
    return r.checked(node, "cell", lambda: Cell(instrument=instrument, targets=targets, features=features,
                                                 tip=tip, probe_radius=probe, source=path, **kw))


def _instrument(r: _Reader, node, kind: str) -> Tracker:
    keys = ("position_mm", "range_mm", "head_mm", "beam_mm", "standoff_mm")
    if kind == "camera":
        keys += ("look_at_mm", "up", "fov_deg")
    m = r.mapping(node, kind, keys)
    if "position_mm" not in m:
        r.fail(node, kind, "position_mm (its position in the base frame, mm) is required")
    kw = {"position": r.numbers(m["position_mm"], f"{kind}.position_mm", 3, 1e-3)}
    if "range_mm" in m:
        kw["range"] = tuple(r.numbers(m["range_mm"], f"{kind}.range_mm", 2, 1e-3))
    for key, name in (("head_mm", "head"), ("beam_mm", "beam"), ("standoff_mm", "standoff")):
        if key in m:
            kw[name] = r.number(m[key], f"{kind}.{key}", 1e-3, minimum=0.0)
    if kind == "camera":
        if "look_at_mm" not in m:
            r.fail(node, kind, "look_at_mm (a point on its optical axis, mm) is required")
        kw["look_at"] = r.numbers(m["look_at_mm"], "camera.look_at_mm", 3, 1e-3)
        if "up" in m:
            kw["up"] = r.numbers(m["up"], "camera.up", 3)
        if "fov_deg" in m:
            kw["fov"] = tuple(r.numbers(m["fov_deg"], "camera.fov_deg", 2, math.pi / 180))
    return r.checked(node, kind, lambda: (Camera if kind == "camera" else Tracker)(**kw))


def _target(r: _Reader, node, key: str) -> Target:
    m = r.mapping(node, key, ("name", "offset_mm", "axis", "cone_deg"))
    kw = {"name": r.text(m["name"], f"{key}.name") if "name" in m else f"T{key.split('[')[1][:-1]}",
          "offset": r.numbers(m["offset_mm"], f"{key}.offset_mm", 3, 1e-3) if "offset_mm" in m else np.zeros(3)}
    if "axis" in m:
        kw["axis"] = r.numbers(m["axis"], f"{key}.axis", 3)
    if "cone_deg" in m:
        kw["cone"] = r.number(m["cone_deg"], f"{key}.cone_deg", math.pi / 180)
    return r.checked(node, key, lambda: Target(**kw))


def _touch(r: _Reader, node) -> tuple[tuple, float]:
    m = r.mapping(node, "touch", ("tip_mm", "probe_radius_mm", "nests", "planes"))
    probe = r.number(m["probe_radius_mm"], "touch.probe_radius_mm", 1e-3, 0.0) if "probe_radius_mm" in m else 0.0
    tip = r.numbers(m["tip_mm"], "touch.tip_mm", 3, 1e-3) if "tip_mm" in m else np.zeros(3)
    features = []
    for group, cls in (("nests", Nest), ("planes", PlaneRegion)):
        if group not in m:
            continue
        for i, item in enumerate(r.items(m[group], f"touch.{group}")):
            key = f"touch.{group}[{i}]"
            pos = "position_mm" if cls is Nest else "point_mm"
            keys = ("name", pos, "normal", "cone_deg", "poses") + (("size_mm",) if cls is PlaneRegion else ())
            f = r.mapping(item, key, keys)
            if pos not in f:
                r.fail(item, key, f"{pos} (mm, base frame) is required")
            kw = {"name": r.text(f["name"], f"{key}.name") if "name" in f else f"{cls.kind[0].upper()}{i + 1}",
                  "position": r.numbers(f[pos], f"{key}.{pos}", 3, 1e-3)}
            if "normal" in f:
                kw["normal"] = r.numbers(f["normal"], f"{key}.normal", 3)
            if "cone_deg" in f:
                kw["cone"] = r.number(f["cone_deg"], f"{key}.cone_deg", math.pi / 180, 0.0)
            if "poses" in f:
                kw["poses"] = r.integer(f["poses"], f"{key}.poses")
            if "size_mm" in f:
                kw["size"] = tuple(r.numbers(f["size_mm"], f"{key}.size_mm", 2, 1e-3))
            features.append(r.checked(item, key, lambda: cls(**kw)))
    if not features:
        r.fail(node, "touch", "expected nests or planes (or both)")
    return tuple(features), probe, tip


def _cell_options(r: _Reader, node) -> dict:
    m = r.mapping(node, "cell", ("workspace_mm", "forbidden", "floor", "joint_margin_deg", "clearance_mm",
                                 "self_clearance_mm", "home_deg"))
    kw = {}
    if "workspace_mm" in m:
        w = r.mapping(m["workspace_mm"], "cell.workspace_mm", ("min", "max"))
        if set(w) != {"min", "max"}:
            r.fail(m["workspace_mm"], "cell.workspace_mm", "expected min and max corners (mm)")
        kw["workspace"] = r.checked(m["workspace_mm"], "cell.workspace_mm", lambda: Box(
            "workspace", r.numbers(w["min"], "cell.workspace_mm.min", 3, 1e-3),
            r.numbers(w["max"], "cell.workspace_mm.max", 3, 1e-3)))
    if "forbidden" in m:
        boxes = []
        for i, item in enumerate(r.items(m["forbidden"], "cell.forbidden")):
            key = f"cell.forbidden[{i}]"
            b = r.mapping(item, key, ("name", "min_mm", "max_mm"))
            if "min_mm" not in b or "max_mm" not in b:
                r.fail(item, key, "expected min_mm and max_mm corners (mm, base frame)")
            name = r.text(b["name"], f"{key}.name") if "name" in b else f"box{i + 1}"
            boxes.append(r.checked(item, key, lambda: Box(name, r.numbers(b["min_mm"], f"{key}.min_mm", 3, 1e-3),
                                                          r.numbers(b["max_mm"], f"{key}.max_mm", 3, 1e-3))))
        kw["forbidden"] = tuple(boxes)
    if "floor" in m:
        kw["floor"] = r.flag(m["floor"], "cell.floor")
    for key, name, scale, hi in (("joint_margin_deg", "joint_margin", math.pi / 180, 45.0),
                                 ("clearance_mm", "clearance", 1e-3, 999.0),
                                 ("self_clearance_mm", "self_clearance", 1e-3, 999.0)):
        if key in m:
            v = r.number(m[key], f"cell.{key}", 1.0, minimum=0.0)
            if v > hi:
                r.fail(m[key], f"cell.{key}", f"expected at most {hi:g}, got {v:g}")
            kw[name] = v * scale
    if "home_deg" in m:
        kw["home"] = r.numbers(m["home_deg"], "cell.home_deg", None, math.pi / 180)
    return kw
