"""Touch data: the tool point touching fixed points, planes and spheres (issue 24).

Without a measuring instrument, a row records the joint values at which the tool point touched a
fixed feature of the cell, whose location is unknown:

* ``point`` (id): the tool point was at the feature's fixed point c (a tip in a nest or cone).
  Unknowns: c = (x, y, z), metres, in the meas frame. Residual (3 components): p - c.
* ``plane`` (id): the tool point lay on the feature's plane (a datum plate, a face of a cube);
  with a ball tip of radius r (``probe_radius``) its centre lies at r from the plane. Unknowns:
  the unit normal by two angles (a, b) about a reference normal and the offset d (metres):
  ``n(a, b) = R_ref Rx(a) Ry(b) e_z``; residual (1 component): ``n . p - d - r``. The reference
  ``R_ref`` (its third column the reference normal) is chosen by whoever starts a fit (the plane
  fitted to the nominal tool points), so that (a, b) stay far from the singularity at 90 degrees.
* ``sphere`` (id, radius R, metres): the tool point was at R from the feature's fixed centre c
  (a ball bar of known length pivoting on a fixed ball, or a sphere of radius R touched by the
  tip). Unknowns: c; residual (1 component): ``|p - c| - R``.

The tool point p is that of the chain in the meas frame (``T_meas_tool``); the meas frame's
parameters u are not identifiable from such data (a rigid motion of the cell moves the features
with it) and stay nominal, so a calibration from touch data is relative to the nominal base frame.
Values are SI; feature parameters are named ``point_<id>_x``, ``plane_<id>_a``, ``plane_<id>_d``,
``sphere_<id>_z`` ... (:func:`feature_parameter_names`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib.checks import check_array, check_int, check_number
from calib.choices import FEATURE_KINDS
from calib.errors import DataError

#: The three unknowns of each kind, as suffixes of the parameter names.
FEATURE_UNKNOWNS = {"point": ("x", "y", "z"), "plane": ("a", "b", "d"), "sphere": ("x", "y", "z")}
#: The unit of each unknown.
FEATURE_UNITS = {"x": "m", "y": "m", "z": "m", "a": "rad", "b": "rad", "d": "m"}
#: Residual components per row of each kind.
RESIDUAL_SIZE = {"point": 3, "plane": 1, "sphere": 1}
#: The largest sphere radius (metres): no sphere a robot touches is larger (over a 2 m reach a
#: sphere of 1 km departs from a plane by 0.5 mm: give such a surface as a plane). A radius of
#: 1e300 overflowed the closed-form start (its square) with a traceback.
MAX_SPHERE_RADIUS_M = 1000.0


@dataclass(frozen=True)
class Feature:
    """A feature of the cell the tool point touched: ``kind`` in FEATURE_KINDS, ``id`` its name,
    ``radius`` the sphere's known radius in metres (None for points and planes)."""

    kind: str
    id: str
    radius: float | None = None

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in FEATURE_KINDS:
            raise DataError(f"feature kind must be one of {', '.join(FEATURE_KINDS)}, got {self.kind!r}")
        if not isinstance(self.id, str) or not self.id:
            raise DataError(f"a {self.kind} id must be a non-empty string, got {self.id!r}")
        if self.kind == "sphere":
            if (self.radius is None or isinstance(self.radius, bool) or not isinstance(self.radius, (int, float, np.number))
                    or not np.isfinite(self.radius) or not 0 < self.radius <= MAX_SPHERE_RADIUS_M):
                raise DataError(f"sphere {self.id!r}: expected a positive radius in metres, at most "
                                f"{MAX_SPHERE_RADIUS_M:g} m (larger spheres are planes to a robot), got {self.radius!r}")
        elif self.radius is not None:
            raise DataError(f"{self.kind} {self.id!r}: only a sphere has a radius")

    @property
    def parameter_names(self) -> tuple[str, str, str]:
        return tuple(f"{self.kind}_{self.id}_{k}" for k in FEATURE_UNKNOWNS[self.kind])


def feature_parameter_names(features) -> tuple[str, ...]:
    """The 3 K names of the unknowns of K features, feature by feature."""
    return tuple(n for f in features for n in f.parameter_names)


@dataclass(frozen=True, eq=False)
class TouchData:
    """Rows of joint values at which the tool point touched features (immutable, SI units).

    q : (N, n) joint values, radians / metres, chain order. feature : (N,) int, each row's index
    into ``features``. features : the touched features (each touched by at least one row).
    probe_radius : metres, the ball tip's radius for plane rows (0: a pointed tip).
    rows : (N,) 1-based line numbers in the source file (1 ... N without a file).
    joint_names : (n,) names in chain order, or None.
    measured : rows of the same file measured by an instrument (their tool position, optionally
    orientation, in the meas frame: :class:`calib.model.measurements.Measurements`, one tool
    frame, no sets), identified together with the touch rows; None for touch rows alone.
    """

    q: np.ndarray
    feature: np.ndarray
    features: tuple[Feature, ...]
    probe_radius: float = 0.0
    rows: np.ndarray | None = None
    joint_names: tuple[str, ...] | None = None
    source: object | None = field(default=None, repr=False)
    measured: object | None = field(default=None, repr=False)

    def __post_init__(self):
        q = check_array(self.q, "q", (None, None), unit="joint values, rad / m").copy()
        feature = np.array(self.feature)
        if feature.shape != (len(q),) or (feature.size and feature.dtype.kind not in "iu"):
            raise DataError(f"feature must be ({len(q)},) integer indices into features")
        feature = feature.astype(int)
        if not isinstance(self.features, (list, tuple)):
            raise DataError(f"features must be a list of Feature values, got {type(self.features).__name__}")
        features = tuple(self.features)
        if not all(isinstance(f, Feature) for f in features):
            raise DataError("features must be Feature values")
        if len({(f.kind, f.id) for f in features}) != len(features):
            raise DataError("features must not repeat a (kind, id)")
        if feature.size and (feature.min() < 0 or feature.max() >= len(features)):
            raise DataError(f"feature indices must lie in 0 .. {len(features) - 1}")
        if set(feature.tolist()) != set(range(len(features))):
            unused = [f"{features[k].kind} {features[k].id!r}" for k in range(len(features))
                      if k not in set(feature.tolist())]
            raise DataError(f"no row touches {', '.join(unused)}")
        check_number(self.probe_radius, "probe_radius (m)", minimum=0.0)
        if self.rows is None:
            rows = np.arange(1, len(q) + 1)
        else:
            rows = np.asarray(self.rows)
            if rows.shape != (len(q),) or (rows.size and rows.dtype.kind not in "iu"):
                raise DataError(f"rows must be ({len(q)},) integer line numbers")
            rows = rows.astype(int)
        if self.measured is not None:
            from calib.model.measurements import Measurements

            m = self.measured
            if not isinstance(m, Measurements):
                raise DataError(f"measured must be calib.Measurements or None, got {type(m).__name__}")
            if m.q.shape[1] != q.shape[1]:
                raise DataError(f"measured rows have {m.q.shape[1]} joint values, the touch rows {q.shape[1]}")
            if m.target is not None or m.sets is not None:
                raise DataError("measured rows mixed with touch rows take no target or set column")
        for name, a in (("q", q), ("feature", feature), ("rows", rows)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "features", features)
        object.__setattr__(self, "probe_radius", float(self.probe_radius))

    @property
    def n_rows(self) -> int:
        return len(self.q)

    @property
    def n_measured(self) -> int:
        """Rows measured by an instrument (0 without)."""
        return 0 if self.measured is None else self.measured.n_poses

    @property
    def kinds(self) -> np.ndarray:
        """(N,) str: each row's feature kind."""
        return np.array([self.features[k].kind for k in self.feature], dtype=object)

    def rows_of(self, k: int) -> np.ndarray:
        """Indices of the rows touching feature k."""
        check_int(k, "k", maximum=len(self.features) - 1)
        return np.flatnonzero(self.feature == k)

    @property
    def n_residuals(self) -> int:
        """Residual components of all rows (3 per point row, 1 per plane or sphere row)."""
        return int(sum(RESIDUAL_SIZE[self.features[k].kind] for k in self.feature))

    def measured_subset(self, keep) -> "TouchData":
        """The touch rows and the measured rows ``keep`` (a mask or indices into them)."""
        if self.measured is None:
            raise DataError("these touch data have no measured rows")
        return replace(self, measured=self.measured.subset(keep))

    def subset(self, keep) -> "TouchData":
        """The touch rows ``keep`` (a mask or indices; the measured rows all kept); every
        feature must keep a row."""
        keep = np.asarray(keep) if isinstance(keep, (list, tuple, np.ndarray)) else None
        if keep is None or keep.ndim != 1 or (keep.size and keep.dtype.kind not in "biu") \
                or (keep.dtype == bool and len(keep) != self.n_rows) \
                or (keep.dtype != bool and keep.size and (keep.min() < 0 or keep.max() >= self.n_rows)):
            raise DataError(f"keep must be a ({self.n_rows},) boolean mask or row indices in 0 .. {self.n_rows - 1}")
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep.astype(int)
        used = sorted(set(self.feature[idx].tolist()))
        remap = {k: i for i, k in enumerate(used)}
        return TouchData(self.q[idx], np.array([remap[k] for k in self.feature[idx]], int),
                         tuple(self.features[k] for k in used), self.probe_radius, self.rows[idx],
                         self.joint_names, self.source, self.measured)


# ====================================================================== plane geometry
def plane_normals(R_ref: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Unit normals of planes and their derivatives: ``n = R_ref Rx(a) Ry(b) e_z``.

    R_ref : (K, 3, 3) reference rotations; a, b : (K,) radians. Returns (n, dn_da, dn_db), each
    (K, 3), in the frame of R_ref's columns (the meas frame).
    """
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    local = np.stack([sb, -sa * cb, ca * cb], axis=1)
    d_a = np.stack([np.zeros_like(a), -ca * cb, -sa * cb], axis=1)
    d_b = np.stack([cb, sa * sb, -ca * sb], axis=1)
    n, dn_a, dn_b = (np.einsum("kij,kj->ki", R_ref, v) for v in (local, d_a, d_b))
    return n, dn_a, dn_b


def frame_with_normal(n: np.ndarray) -> np.ndarray:
    """(3, 3) a rotation whose third column is the unit vector n (3,)."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    x = np.cross(helper, n)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(n, x), n])


@dataclass(frozen=True, eq=False)
class FeatureStart:
    """Start values of the features' unknowns and the planes' reference rotations.

    values : (3 K,) SI, feature by feature (see the module docstring); plane_refs : (K, 3, 3),
    the reference rotation of each plane (identity for points and spheres).
    """

    values: np.ndarray
    plane_refs: np.ndarray


def initial_features(data: TouchData, p_tool: np.ndarray, z_tool: np.ndarray | None = None) -> FeatureStart:
    """Start values fitted to tool points ``p_tool`` (N, 3) metres (those of the nominal model):
    a point's mean; a plane by total least squares (its normal the reference, a = b = 0, turned
    against the tool's z axes ``z_tool`` (N, 3): the probe points along its tool frame's z, out of
    the flange as URDF tool frames such as tool0 do, so it comes from the side the normal points
    to, a ball tip's centre lies at +probe_radius and d is the touched surface's offset); a
    sphere's centre by the algebraic fit ``|p|^2 = 2 p . c + k``, else from the centroid along
    the fitted cap's normal when the rows are too few or coplanar."""
    K = len(data.features)
    values, refs = np.zeros((K, 3)), np.tile(np.eye(3), (K, 1, 1))
    for k, f in enumerate(data.features):
        P = p_tool[data.rows_of(k)]
        m = P.mean(axis=0)
        if f.kind == "point":
            values[k] = m
        elif f.kind == "plane":
            n = np.linalg.svd(P - m)[2][-1] if len(P) >= 3 else np.array([0.0, 0.0, 1.0])
            if z_tool is not None and np.sum(z_tool[data.rows_of(k)] @ n) > 0:
                n = -n
            refs[k] = frame_with_normal(n)
            values[k] = (0.0, 0.0, float(n @ m) - data.probe_radius)
        else:
            values[k] = _sphere_centre(P, f.radius)
    return FeatureStart(values.reshape(-1), refs)


def _sphere_centre(P: np.ndarray, radius: float) -> np.ndarray:
    m = P.mean(axis=0)
    if len(P) >= 4:
        A = np.column_stack([2 * P, np.ones(len(P))])
        sol, _, rank, _ = np.linalg.lstsq(A, np.sum(P ** 2, axis=1), rcond=None)
        if rank == 4 and abs(np.linalg.norm(P - sol[:3], axis=1).mean() - radius) < 0.5 * radius:
            return sol[:3]
    n = np.linalg.svd(P - m)[2][-1] if len(P) >= 3 else np.array([0.0, 0.0, 1.0])
    spread = np.sqrt(max(radius ** 2 - np.mean(np.sum((P - m) ** 2, axis=1)), 0.0))
    return m - n * spread


@dataclass(frozen=True, eq=False)
class FeatureFit:
    """The features' unknowns identified by a calibration from touch data (the
    :class:`calib.CalibrationResult`'s ``features``).

    features : the touched features; values, std : (3 K,) SI, feature by feature (see the module
    docstring: a point's or a sphere's centre x, y, z; a plane's a, b about its reference and its
    offset d); plane_refs : (K, 3, 3) the planes' reference rotations (identity for the others).
    """

    features: tuple[Feature, ...]
    values: np.ndarray = field(repr=False)
    std: np.ndarray = field(repr=False)
    plane_refs: np.ndarray = field(repr=False)

    @property
    def names(self) -> tuple[str, ...]:
        """(3 K,) the unknowns' names: ``point_<id>_x``, ``plane_<id>_a``, ``sphere_<id>_z`` ..."""
        return feature_parameter_names(self.features)

    @property
    def normals(self) -> np.ndarray:
        """(K, 3) each plane's unit normal (zeros for the other kinds)."""
        F = np.asarray(self.values, float).reshape(-1, 3)
        out = np.zeros((len(self.features), 3))
        planes = [k for k, f in enumerate(self.features) if f.kind == "plane"]
        if planes:
            out[planes] = plane_normals(self.plane_refs[planes], F[planes, 0], F[planes, 1])[0]
        return out

    def to_dict(self) -> list[dict]:
        """One entry per unknown: name, value and std (mm, or rad for a plane's angles), unit."""
        scale = [1.0 if FEATURE_UNITS[n.rsplit("_", 1)[1]] == "rad" else 1e3 for n in self.names]
        return [{"name": n, "value": float(v) * f, "std": float(s) * f, "unit": "rad" if f == 1.0 else "mm"}
                for n, v, s, f in zip(self.names, self.values, self.std, scale)]

    def format(self) -> list[str]:
        return [f"  {d['name']:<24} {d['value']:12.4f} +- {d['std']:.4f} {d['unit']}" for d in self.to_dict()]
