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

The file is read by :func:`calib.io.cell_file.read_cell` (:func:`calib.read_cell`): errors name
the file, the line and the key (:class:`calib.DataError`); unknown keys are refused (a misspelt
``clearence_mm`` must not silently leave the default).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.errors import DataError

__all__ = ["Box", "Target", "Tracker", "Camera", "Nest", "PlaneRegion", "Cell", "DEFAULT_CELL"]

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


def _frozen(a) -> np.ndarray:
    """A read-only float copy of ``a``."""
    a = np.array(a, float)
    a.setflags(write=False)
    return a


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
        object.__setattr__(self, "lower", _frozen(lo))
        object.__setattr__(self, "upper", _frozen(hi))

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
        object.__setattr__(self, "offset", _frozen(_point(self.offset, f"target {self.name!r} offset")))
        object.__setattr__(self, "axis", _frozen(_unit(self.axis, f"target {self.name!r} axis")))


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
        object.__setattr__(self, "position", _frozen(_point(self.position, f"{self.kind} position")))
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
        object.__setattr__(self, "look_at", _frozen(at))
        object.__setattr__(self, "up", _frozen(up))
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
        object.__setattr__(self, "position", _frozen(_point(self.position, f"{self.kind} {self.name!r} position")))
        object.__setattr__(self, "normal", _frozen(_unit(self.normal, f"{self.kind} {self.name!r} normal")))


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
        ``clearance`` of the base frame's xy-plane or below it. joint_margin : radians kept inside
        each limit (a prismatic joint: as many millimetres as the margin has degrees).
        self_clearance : metres between links.
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
        object.__setattr__(self, "tip", _frozen(_point(tip, "touch tip")))
        if self.home is not None:
            try:
                h = np.array(self.home, float)
            except (TypeError, ValueError):
                h = np.zeros((0, 0))
            if h.ndim != 1 or not len(h) or not np.isfinite(h).all():
                raise DataError("home: expected one finite joint value per joint")
            object.__setattr__(self, "home", _frozen(h))

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
