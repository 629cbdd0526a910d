"""The cell a measurement plan is made for (``calib plan --cell FILE``): the instrument, the
targets on the tool or the touch features, and what the robot must not touch; read from a small
YAML file into frozen values in SI units (metres, radians), every position in the robot's base
frame (the URDF frame calib's model is expressed in: the ``--base-frame``, default the root link).

The file (lengths in millimetres, angles in degrees, as the key names say; every key optional)::

    tracker:                       # a laser tracker (or camera:, not both)
      position_mm: [2500, 0, 800]  # its head's centre
      range_mm: [800, 20000]       # the distances it measures at, min and max
      head_mm: 300                 # the head's diameter: an obstacle the robot keeps clear of
      beam_mm: 10                  # the beam's diameter: kept free of the robot and the boxes
      standoff_mm: 25              # the beam's last length before a target, not checked (the
                                   # target's own mount)
    camera:                        # a camera instead of a tracker
      position_mm: [..]
      look_at_mm: [..]             # the point on its optical axis
      up: [0, 0, 1]                # the image's up direction (default base z)
      fov_deg: [60, 45]            # full horizontal and vertical field of view
      range_mm: [500, 4000]
      head_mm: 150
      beam_mm: 10
      standoff_mm: 25
    targets:                       # what the instrument measures, on the tool (tool frame)
      - name: SMR1
        offset_mm: [0, 0, 60]      # its position in the tool frame
        axis: [0, 0, 1]            # the direction it faces (an SMR's opening), tool frame
        cone_deg: 30               # its acceptance: half-angle around axis
    touch:                         # touch features instead of an instrument
      tip_mm: [0, 0, 150]          # the probe's tip in the tool frame (default: the tool frame)
      probe_radius_mm: 0           # a ball tip's radius (planes)
      nests:
        - name: N1
          position_mm: [600, 200, 100]
          normal: [0, 0, 1]        # out of the nest, toward where the probe comes from
          cone_deg: 30             # the tool's axis within this of -normal
          poses: 8
      planes:
        - name: top
          point_mm: [700, 0, 300]  # the centre of the region touched
          normal: [0, 0, 1]        # out of the material
          size_mm: [80, 80]        # the region: a rectangle around point, in the plane
          cone_deg: 20             # the approach: the tool's axis within this of -normal
          poses: 6
    cell:
      workspace_mm: {min: [-1000, -1000, 0], max: [1500, 1000, 1800]}   # the tool stays in it
      forbidden:                   # boxes the robot keeps clear of (fixtures, a table)
        - {name: table, min_mm: [400, -400, 0], max_mm: [900, 400, 700]}
      floor: true                  # nothing of the robot below the base frame's xy-plane
      joint_margin_deg: 5          # kept inside every joint limit
      clearance_mm: 20             # from the floor, the boxes and the instrument
      self_clearance_mm: 5         # between the robot's own links
      home_deg: [0, -90, 90, -90, -90, 0]   # where the program starts and ends (optional)

Errors name the file, the line and the key (:class:`calib.DataError`); unknown keys are refused
(a misspelt ``clearence_mm`` must not silently leave the default).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.errors import DataError

__all__ = ["Box", "Target", "Tracker", "Camera", "Nest", "PlaneRegion", "Cell", "read_cell", "DEFAULT_CELL",
           "MAX_CELL_BYTES"]

#: Largest cell file read (bytes): a description, not a data set.
MAX_CELL_BYTES = 1 << 20
#: Defaults (SI): a clearance from the floor, boxes and instrument, and between the robot's links.
CLEARANCE_M = 0.02
SELF_CLEARANCE_M = 0.005
JOINT_MARGIN_RAD = math.radians(2.0)
BEAM_DIAMETER_M = 0.01
STANDOFF_M = 0.025
HEAD_DIAMETER_M = 0.3
CONE_RAD = math.radians(30.0)


def _unit(v, what: str) -> np.ndarray:
    try:
        v = np.asarray(v, float)
    except (TypeError, ValueError):
        raise DataError(f"{what}: expected a non-zero direction (x, y, z)") from None
    n = float(np.linalg.norm(v))
    if v.shape != (3,) or not np.isfinite(v).all() or n < 1e-12:
        raise DataError(f"{what}: expected a non-zero direction (x, y, z)")
    return v / n


def _point(v, what: str) -> np.ndarray:
    try:
        v = np.array(v, float)
    except (TypeError, ValueError):
        raise DataError(f"{what}: expected a point (x, y, z) in metres") from None
    if v.shape != (3,) or not np.isfinite(v).all():
        raise DataError(f"{what}: expected a point (x, y, z) in metres")
    v.setflags(write=False)
    return v


def _frozen(obj, **arrays) -> None:
    for name, a in arrays.items():
        a = np.array(a, float)
        a.setflags(write=False)
        object.__setattr__(obj, name, a)


# ====================================================================== values
@dataclass(frozen=True, eq=False)
class Box:
    """An axis-aligned box of the base frame: ``lower``, ``upper`` (3,) metres, its corners."""

    name: str
    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        lo, hi = _point(self.lower, f"box {self.name!r} lower"), _point(self.upper, f"box {self.name!r} upper")
        if not (hi > lo).all():
            raise DataError(f"box {self.name!r}: every max must exceed its min, got min {lo * 1e3} mm, "
                            f"max {hi * 1e3} mm")
        _frozen(self, lower=lo, upper=hi)

    @property
    def centre(self) -> np.ndarray:
        return (self.lower + self.upper) / 2

    @property
    def size(self) -> np.ndarray:
        return self.upper - self.lower

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which points (N, 3) metres lie inside (boundary included)."""
        p = np.atleast_2d(points)
        return np.all((p >= self.lower) & (p <= self.upper), axis=1)


@dataclass(frozen=True, eq=False)
class Target:
    """A target the instrument measures on the tool: ``offset`` (3,) metres and ``axis`` (3,) unit,
    the direction it faces, both in the tool frame; ``cone`` radians, its acceptance half-angle
    (the instrument must lie within it of ``axis``)."""

    name: str
    offset: np.ndarray
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    cone: float = CONE_RAD

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise DataError(f"a target's name must be non-empty text, got {self.name!r}")
        if not 0 < self.cone <= math.pi:
            raise DataError(f"target {self.name!r}: cone must lie in (0, 180] degrees")
        _frozen(self, offset=_point(self.offset, f"target {self.name!r} offset"),
                axis=_unit(self.axis, f"target {self.name!r} axis"))


@dataclass(frozen=True, eq=False)
class Tracker:
    """A laser tracker at ``position`` (3,) metres, measuring at distances within ``range``
    (min, max) metres; its head a sphere of diameter ``head`` (an obstacle); the beam a cylinder
    of diameter ``beam`` kept free up to ``standoff`` before the target."""

    position: np.ndarray
    range: tuple = (0.5, 40.0)
    head: float = HEAD_DIAMETER_M
    beam: float = BEAM_DIAMETER_M
    standoff: float = STANDOFF_M

    kind = "tracker"

    def __post_init__(self):
        _frozen(self, position=_point(self.position, f"{self.kind} position"))
        lo, hi = (float(v) for v in self.range)
        if not 0 <= lo < hi:
            raise DataError(f"{self.kind} range: expected 0 <= min < max, got {lo * 1e3:g}, {hi * 1e3:g} mm")
        object.__setattr__(self, "range", (lo, hi))
        for name in ("head", "beam", "standoff"):
            if not getattr(self, name) >= 0:
                raise DataError(f"{self.kind} {name} must not be negative")


@dataclass(frozen=True, eq=False)
class Camera(Tracker):
    """A camera at ``position`` looking at ``look_at`` (3,) metres, ``up`` the image's up direction,
    ``fov`` (horizontal, vertical) full angles in radians; otherwise as :class:`Tracker`."""

    look_at: np.ndarray = None
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    fov: tuple = (math.radians(60.0), math.radians(45.0))

    kind = "camera"

    def __post_init__(self):
        super().__post_init__()
        if self.look_at is None:
            raise DataError("camera: look_at_mm (a point on its optical axis) is required")
        at = _point(self.look_at, "camera look_at")
        if np.linalg.norm(at - self.position) < 1e-6:
            raise DataError("camera: look_at_mm must differ from position_mm")
        up = _unit(self.up, "camera up")
        if abs(up @ _unit(at - self.position, "camera axis")) > 1 - 1e-9:
            raise DataError("camera: up must not be along the optical axis")
        h, v = (float(x) for x in self.fov)
        if not (0 < h < math.pi and 0 < v < math.pi):
            raise DataError("camera fov_deg: expected two angles in (0, 180) degrees")
        _frozen(self, look_at=at, up=up)
        object.__setattr__(self, "fov", (h, v))

    @property
    def R_base_camera(self) -> np.ndarray:
        """(3, 3): the camera frame in the base frame (z the optical axis, y down the image)."""
        z = _unit(self.look_at - self.position, "camera axis")
        x = np.cross(-self.up, z)
        x /= np.linalg.norm(x)
        return np.column_stack([x, np.cross(z, x), z])


@dataclass(frozen=True, eq=False)
class Nest:
    """A nest the tool point is touched into: ``position`` (3,) metres, ``normal`` (3,) unit out
    of it; the tool's axis (its z) within ``cone`` radians of ``-normal``; ``poses`` rows wanted."""

    name: str
    position: np.ndarray
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    cone: float = CONE_RAD
    poses: int = 8

    kind = "point"

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise DataError(f"a {self.kind}'s name must be non-empty text, got {self.name!r}")
        if not 0 <= self.cone < math.pi / 2:
            raise DataError(f"{self.kind} {self.name!r}: cone must lie in [0, 90) degrees")
        if isinstance(self.poses, bool) or not isinstance(self.poses, (int, np.integer)) or not 1 <= self.poses <= 1000:
            raise DataError(f"{self.kind} {self.name!r}: poses must be an integer from 1 to 1000")
        _frozen(self, position=_point(self.position, f"{self.kind} {self.name!r} position"),
                normal=_unit(self.normal, f"{self.kind} {self.name!r} normal"))


@dataclass(frozen=True, eq=False)
class PlaneRegion(Nest):
    """A plane touched within a rectangle: ``position`` (3,) metres its centre, ``normal`` out of
    the material, ``size`` (2,) metres its sides (along the first two columns of
    :meth:`frame`); the tool's axis within ``cone`` of ``-normal``."""

    size: tuple = (0.1, 0.1)

    kind = "plane"

    def __post_init__(self):
        super().__post_init__()
        s = tuple(float(v) for v in self.size)
        if len(s) != 2 or not all(v >= 0 and math.isfinite(v) for v in s):
            raise DataError(f"plane {self.name!r}: size must be two lengths >= 0")
        object.__setattr__(self, "size", s)

    def frame(self) -> np.ndarray:
        """(3, 3): in-plane directions u, v and the normal as columns (u horizontal when it can be)."""
        n = self.normal
        ref = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u = np.cross(ref, n)
        u /= np.linalg.norm(u)
        return np.column_stack([u, np.cross(n, u), n])


@dataclass(frozen=True, eq=False)
class Cell:
    """The cell a plan is made for (see the module docstring), SI units, base frame.

    instrument : a :class:`Tracker` or :class:`Camera`, or None (no line of sight is checked:
        an instrument that needs none, or touch data). targets : the :class:`Target` s it
        measures (several: each pose measures those it sees). features : touch features
        (:class:`Nest`, :class:`PlaneRegion`); tip : (3,) metres, the probe's tip in the tool
        frame; probe_radius : metres.
    workspace : a :class:`Box` the tool point (and the targets) stay in, or None. forbidden :
        boxes the robot keeps ``clearance`` from. floor : nothing of the robot within
        ``clearance`` of the base frame's xy-plane or below it. joint_margin : radians (metres
        for prismatic joints) kept inside each limit. self_clearance : metres between links.
    home : (n,) joint values where the program starts and ends, or None: radians, and for a
        prismatic joint the millimetres of the file times pi / 180 (the file does not know which
        joints are prismatic: :meth:`home_configuration` converts them).
    source : the file read, or None.
    """

    instrument: Tracker | None = None
    targets: tuple = ()
    features: tuple = ()
    tip: np.ndarray = field(default_factory=lambda: np.zeros(3))
    probe_radius: float = 0.0
    workspace: Box | None = None
    forbidden: tuple = ()
    floor: bool = True
    joint_margin: float = JOINT_MARGIN_RAD
    clearance: float = CLEARANCE_M
    self_clearance: float = SELF_CLEARANCE_M
    home: np.ndarray | None = None
    source: Path | None = None

    def __post_init__(self):
        if self.instrument is not None and not isinstance(self.instrument, Tracker):
            raise DataError(f"instrument must be a Tracker, a Camera or None, got {type(self.instrument).__name__}")
        for name, cls in (("targets", Target), ("features", Nest), ("forbidden", Box)):
            value = getattr(self, name)
            if not isinstance(value, (tuple, list)) or not all(isinstance(v, cls) for v in value):
                raise DataError(f"{name} must be a tuple of {cls.__name__} values, got {value!r:.60}")
            object.__setattr__(self, name, tuple(value))
        if self.workspace is not None and not isinstance(self.workspace, Box):
            raise DataError(f"workspace must be a Box or None, got {type(self.workspace).__name__}")
        if not isinstance(self.floor, bool):
            raise DataError(f"floor must be True or False, got {self.floor!r:.40}")
        if self.source is not None and not isinstance(self.source, (str, Path)):
            raise DataError(f"source must be a path or None, got {type(self.source).__name__}")
        if self.instrument is not None and self.features:
            raise DataError("a cell has an instrument or touch features, not both: plan them separately")
        if self.targets and self.instrument is None:
            raise DataError("targets are measured by an instrument: give a tracker or a camera")
        names = [t.name for t in self.targets]
        if len(set(names)) != len(names):
            raise DataError(f"target names must differ, got {', '.join(names)}")
        fnames = [(f.kind, f.name) for f in self.features]
        if len(set(fnames)) != len(fnames):
            raise DataError("touch features must have different names")
        bnames = [b.name for b in self.forbidden]
        if len(set(bnames)) != len(bnames):
            raise DataError(f"forbidden box names must differ, got {', '.join(bnames)}")
        for name in ("probe_radius", "joint_margin", "clearance", "self_clearance"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < 1:
                raise DataError(f"{name} must be a number in [0, 1) (metres or radians), got {v!r:.40}")
        try:
            tip = np.array(self.tip, float)
        except (TypeError, ValueError):
            tip = None
        _frozen(self, tip=_point(tip, "touch tip"))
        if self.home is not None:
            try:
                h = np.array(self.home, float)
            except (TypeError, ValueError):
                h = np.zeros((0, 0))
            if h.ndim != 1 or not len(h) or not np.isfinite(h).all():
                raise DataError("home: expected one finite joint value per joint")
            _frozen(self, home=h)

    def home_configuration(self, prismatic: np.ndarray) -> np.ndarray | None:
        """(n,) rad / m: :attr:`home` for a robot whose joints ``prismatic`` (n,) bool are
        prismatic (their entries read as millimetres), or None without a home; DataError when
        the counts differ."""
        if self.home is None:
            return None
        prismatic = np.asarray(prismatic, bool)
        if len(self.home) != len(prismatic):
            where = f"{self.source}: " if self.source else ""
            raise DataError(f"{where}cell.home_deg: {len(self.home)} values for a robot of {len(prismatic)} joints")
        return np.where(prismatic, self.home * (180.0 / math.pi) * 1e-3, self.home)


#: The cell of a plan without a cell file: no instrument, the floor, the default clearances.
DEFAULT_CELL = Cell()


# ====================================================================== the file
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
