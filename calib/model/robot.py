"""The robot model: a serial chain read from a URDF with Pinocchio, described by TM-MDH parameters.

A :class:`RobotModel` is immutable. It holds the chain's joints (names, types, limits) and one
value per TM-MDH parameter:

    T_meas_tool(q) = T_meas_base_ref . T(u) . prod_i L_i(q_i) . T(v) . T_flange_tool_ref

with ``L_i`` the link transform of Eq. (1) (:func:`calib.model.mdh.link_transform`), ``T(u)`` and
``T(v)`` the ZYX transforms of Eq. (3) (:func:`calib.model.spatial.zyx_transform`), and two constant
reference transforms. ``meas`` is the chosen base frame of the URDF (the measurement frame),
``base`` is MDH frame 0 (z on axis 1), ``flange`` is MDH frame n, ``tool`` the chosen tool frame.
For a URDF derived model u = v = 0 and the reference transforms carry the nominal geometry; for the
bundled BRTIRUS0707A both references are the identity, as in the paper.

Parameters are named ``theta1``, ``d1``, ``a1``, ``alpha1``, ``beta2`` (only for joints whose
axis is parallel to the next one), ``u_x``, ``u_y``, ``u_z``, ``u_alpha``, ``u_beta``,
``u_gamma`` and ``v_x`` ... ``v_gamma`` (alpha = yaw about z, beta = pitch about y, gamma = roll
about x, as in Eq. (3)). Lengths in metres, angles in radians.

Several targets (reflectors) on the tool: a model with ``targets`` (two or more ids) has one
flange->target transform per target, ``T(v_k) . T_flange_tool_ref_k``, with parameters named
``v_x@<id>`` ... ``v_gamma@<id>``; the chain and the measurement frame are shared. A model with
one tool frame (``targets == ()``) keeps the names ``v_x`` ... ``v_gamma``.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from calib.checks import (check_array, check_configurations, check_instance, check_int, check_names, check_number,
                          check_rng, check_transform)
from calib.errors import ParameterError
from calib.memo import content_digest
from calib.model.chain import (U_NAMES, ChainJoint, Parameter, UrdfSource,
                               make_parameters, v_names)
from calib.model.mdh import PARALLEL_THRESHOLD_RAD, link_transform
from calib.model.periodic import PERIODIC_GROUP, PERIODIC_KINDS, periodic_name, periodic_offsets
from calib.model.spatial import zyx_parameters, zyx_transform

log = logging.getLogger(__name__)

#: The most configurations :meth:`RobotModel.random_configurations` draws at once (800 MB for six
#: joints): a count beyond is a mistake, not a study.
MAX_CONFIGURATIONS = 100_000_000


def _checked_values(values, parameters) -> np.ndarray:
    """``values`` as a read-only float array of one finite number per parameter, or a
    :class:`ParameterError` naming what is wrong."""
    try:
        vals = np.array(values, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"values must be {len(parameters)} numbers (SI units), got "
                             f"{values!r:.60}") from None
    if vals.shape != (len(parameters),):
        raise ParameterError(f"expected {len(parameters)} parameter values, got {vals.shape}")
    if not np.isfinite(vals).all():
        bad = [p.name for p, x in zip(parameters, vals) if not math.isfinite(x)]
        raise ParameterError(f"parameter values must be finite (SI units); {', '.join(bad)} "
                             f"{'is' if len(bad) == 1 else 'are'} not")
    vals.setflags(write=False)
    return vals


#: The cached properties of a :class:`RobotModel` computed from its parameter values.
_VALUE_CACHES = ("frame_memo", "content_key")


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A serial arm described by TM-MDH parameters (immutable; see the module docstring).

    Attributes
    ----------
    joints : the moving joints from base to tool, in chain order.
    parameters : the TM-MDH parameters, in the order of Eq. (23).
    values : (n_params,) float, metres / radians: one value per parameter (read-only array).
    T_meas_base_ref, T_flange_tool_ref : (4, 4) constant reference transforms (of the first
        target for a multi-target model).
    base_frame, tool_frame : names of the URDF frames the chain runs between.
    source : what was parsed from the URDF the model was read from (:class:`UrdfSource`: the
        document and Pinocchio model, used by the writer, compliance and messages instead of
        the file), or None for a model built in code. Derived models keep it.
    urdf_path : (read-only) the URDF the model was read from, ``source.path`` (None without).
    targets : ids of the targets on the tool (two or more), or () for one tool frame.
    T_flange_target_refs : (K, 4, 4) the reference flange->target transform of each target
        (K = len(targets)), or None for one tool frame; default: ``T_flange_tool_ref`` for each.
    """

    joints: tuple[ChainJoint, ...]
    parameters: tuple[Parameter, ...]
    values: np.ndarray
    T_meas_base_ref: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_flange_tool_ref: np.ndarray = field(default_factory=lambda: np.eye(4))
    base_frame: str = "meas"
    tool_frame: str = "tool"
    source: UrdfSource | None = field(default=None, repr=False)
    parallel_threshold: float = PARALLEL_THRESHOLD_RAD
    #: :class:`calib.model.compliance.GravityModel` of a model with compliance parameters, else None.
    gravity: object | None = None
    targets: tuple[str, ...] = ()
    T_flange_target_refs: np.ndarray | None = None

    def __post_init__(self):
        for name, cls in (("joints", ChainJoint), ("parameters", Parameter)):
            value = getattr(self, name)
            if not isinstance(value, (list, tuple)) or not all(isinstance(x, cls) for x in value):
                raise ParameterError(f"{name} must be a tuple of {cls.__name__}, got {value!r:.60}")
            object.__setattr__(self, name, tuple(value))
        if not isinstance(self.targets, (list, tuple)):
            raise ParameterError(f"targets must be a tuple of ids (strings), got {self.targets!r:.60}")
        targets = tuple(self.targets)
        if len(targets) == 1 or len(set(targets)) != len(targets) or \
                not all(isinstance(t, str) and t for t in targets):
            raise ParameterError(f"targets must be two or more distinct non-empty ids, or () for one "
                                 f"tool frame; got {targets!r}")
        object.__setattr__(self, "targets", targets)
        refs = None
        if targets:
            try:
                refs = np.array(np.broadcast_to(self.T_flange_tool_ref, (len(targets), 4, 4))
                                if self.T_flange_target_refs is None else self.T_flange_target_refs, float)
            except (TypeError, ValueError, OverflowError):
                raise ParameterError(f"T_flange_target_refs must be ({len(targets)}, 4, 4) transforms") from None
            if refs.shape != (len(targets), 4, 4) or not np.isfinite(refs).all():
                raise ParameterError(f"T_flange_target_refs must be ({len(targets)}, 4, 4), got {refs.shape}")
            if not np.array_equal(np.asarray(self.T_flange_tool_ref, float), refs[0]) and \
                    not np.array_equal(np.asarray(self.T_flange_tool_ref, float), np.eye(4)):
                raise ParameterError("T_flange_tool_ref of a multi-target model is that of its first "
                                     "target: change T_flange_target_refs instead")
            object.__setattr__(self, "T_flange_tool_ref", refs[0].copy())
            refs.setflags(write=False)
        elif self.T_flange_target_refs is not None:
            raise ParameterError("T_flange_target_refs needs targets")
        object.__setattr__(self, "T_flange_target_refs", refs)
        object.__setattr__(self, "values", _checked_values(self.values, self.parameters))
        for name in ("T_meas_base_ref", "T_flange_tool_ref"):
            T = check_transform(getattr(self, name), name)
            T.setflags(write=False)
            object.__setattr__(self, name, T)
        object.__setattr__(self, "_index", {p.name: k for k, p in enumerate(self.parameters)})

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_mdh(cls, joints: Sequence[ChainJoint], theta, d, a, alpha, beta=None, u=None, v=None,
                 T_meas_base_ref=None, T_flange_tool_ref=None, **kwargs) -> "RobotModel":
        """A model from MDH tables (arrays of length n; ``beta`` may hold NaN where a joint has no
        beta parameter, or be None for none), and optional u, v (6 each, Eq. 3 order)."""
        if not isinstance(joints, (list, tuple)) or not joints or \
                not all(isinstance(j, ChainJoint) for j in joints):
            raise ParameterError(f"joints must be a non-empty list of ChainJoint, got {joints!r:.60}")
        n = len(joints)
        theta, d, a, alpha = (check_array(x, k, (n,), unit=unit) for x, k, unit in
                              ((theta, "theta", "rad"), (d, "d", "m"), (a, "a", "m"), (alpha, "alpha", "rad")))
        if beta is None:
            beta = np.full(n, np.nan)
        else:
            try:
                beta = np.asarray(beta, float)
            except (TypeError, ValueError, OverflowError):
                beta = None
            if beta is None or beta.shape != (n,) or np.isinf(beta).any():
                raise ParameterError(f"beta must be ({n},) radians, NaN where a joint has none")
        unknown = set(kwargs) - {f.name for f in fields(cls)}
        if unknown:
            raise ParameterError(f"unknown RobotModel fields {', '.join(sorted(unknown))}")
        u, v = (np.zeros(6) if x is None else check_array(x, k, (6,), unit="m and rad") for x, k in ((u, "u"), (v, "v")))
        beta_joints = [i + 1 for i in range(n) if not np.isnan(beta[i])]
        params = make_parameters(n, beta_joints)
        vals = np.concatenate([theta, d, a, alpha, beta[~np.isnan(beta)], u, v])
        return cls(joints=tuple(joints), parameters=params, values=vals,
                   T_meas_base_ref=np.eye(4) if T_meas_base_ref is None else T_meas_base_ref,
                   T_flange_tool_ref=np.eye(4) if T_flange_tool_ref is None else T_flange_tool_ref,
                   **kwargs)

    def with_targets(self, targets: Sequence[str],
                     T_flange_target_refs: np.ndarray | None = None) -> "RobotModel":
        """This model with the given targets on the tool (a new model).

        targets : two or more ids (one id or () gives a one-tool-frame model with the first
        target's transform). Each target starts with the v values and reference of the target of
        this model of the same id, else of the first target; ``T_flange_target_refs`` (K, 4, 4)
        replaces the references.
        """
        targets = check_names(targets, "targets")
        if T_flange_target_refs is not None:
            T_flange_target_refs = check_array(T_flange_target_refs, "T_flange_target_refs",
                                               (len(targets), 4, 4), unit="flange->target transforms")
        if targets == self.targets and T_flange_target_refs is None:
            return self
        if self.has_joint_terms:    # the joint terms stay last: targets on the geometry, then them
            return self._terms_onto(self.geometry().with_targets(targets, T_flange_target_refs))
        if len(targets) < 2:
            return self.for_target(targets[0] if targets and targets[0] in self.targets else None)
        vals = [x for x, p in zip(self.values, self.parameters) if p.group != "v"]
        refs = []
        for t in targets:
            src = t if t in self.targets else None
            vals += list(self.v(src))
            refs.append(self.T_flange_tool_ref_of(src))
        if T_flange_target_refs is not None:
            refs = T_flange_target_refs
        beta_joints = [p.joint for p in self.parameters if p.kind == "beta" and p.group == "joint"]
        return replace(self, parameters=make_parameters(self.n_joints, beta_joints, targets),
                       values=np.array(vals), targets=targets, T_flange_target_refs=np.array(refs),
                       T_flange_tool_ref=np.array(refs[0]))

    def with_target_offsets(self, offsets) -> "RobotModel":
        """This model with targets at known points of the tool: ``offsets`` maps each id to its
        position (3,) in metres in the tool frame (of the first target, for a multi-target model);
        each target's frame is the tool frame moved there. Two or more targets."""
        if not isinstance(offsets, Mapping):
            raise ParameterError(f"offsets must map each target id to its position (x, y, z) in metres, "
                                 f"got {type(offsets).__name__}")
        bad = [t for t in offsets if not isinstance(t, str) or not t]
        if bad:
            raise ParameterError(f"with_target_offsets: target ids are non-empty strings (the ids of the "
                                 f"measurements' target column, e.g. {{'A': (0.1, 0, 0.05), 'B': ...}}), got "
                                 f"{bad[0]!r} ({type(bad[0]).__name__}); expected keys such as "
                                 f"{', '.join(repr(str(t)) for t in list(offsets)[:4])}")
        ids = tuple(offsets)
        if len(ids) < 2:
            raise ParameterError(f"with_target_offsets: give two or more targets (got {len(ids)}); one "
                                 f"target is the tool frame itself (move it with the tool frame's URDF "
                                 f"link or with_changes(v_x=...))")
        refs = []
        for t in ids:
            try:
                p = np.asarray(offsets[t], float)
            except (TypeError, ValueError, OverflowError):
                p = None
            if p is None or p.shape != (3,) or not np.isfinite(p).all():
                raise ParameterError(f"target {t!r}: expected a finite position (x, y, z) in metres, "
                                     f"got {offsets[t]!r:.60}")
            T = np.eye(4)
            T[:3, 3] = p
            refs.append(self.T_flange_tool_ref_of(0) @ T)
        return self.for_target(0).with_targets(ids, np.array(refs))

    def for_target(self, target: str | int | None = None) -> "RobotModel":
        """The one-tool-frame model of one target (default the first): its v values (named
        ``v_x`` ...) and reference (the tool frame name stays that of the chain)."""
        if not self.targets:
            return self
        if self.has_joint_terms:
            return self._terms_onto(self.geometry().for_target(target))
        k = self.target_index(target)
        vals = np.concatenate([[x for x, p in zip(self.values, self.parameters) if p.group != "v"],
                               self.v(k)])
        beta_joints = [p.joint for p in self.parameters if p.kind == "beta" and p.group == "joint"]
        return replace(self, parameters=make_parameters(self.n_joints, beta_joints), values=vals,
                       targets=(), T_flange_target_refs=None,
                       T_flange_tool_ref=np.array(self.T_flange_target_refs[k]))

    def with_values(self, values: np.ndarray) -> "RobotModel":
        """A copy of this model with other parameter values (full vector, same order, finite)."""
        # (everything else was checked when this model was made and is immutable: only the
        # values are checked again, not the joints, parameters and transforms)
        state = {k: v for k, v in self.__dict__.items() if k not in _VALUE_CACHES}   # (of the old values)
        state["values"] = _checked_values(values, self.parameters)
        out = object.__new__(type(self))        # (a new instance's state, as copy.copy sets it)
        out.__dict__.update(state)
        return out

    def with_changes(self, **deltas: float) -> "RobotModel":
        """A copy with parameter values changed by the given amounts: ``with_changes(d2=1e-4)``
        (finite numbers, SI units)."""
        vals = self.values.copy()
        for name, delta in deltas.items():
            vals[self.index(name)] += check_number(delta, name)
        return self.with_values(vals)

    def with_compliance(self, gravity, values: Sequence[float] | None = None) -> "RobotModel":
        """A copy with one compliance parameter ``c<i>`` per joint (group "compliance", after the
        geometric parameters; rad/(N m), or m/N for a prismatic joint) and the gravity model
        (:class:`calib.model.compliance.GravityModel`) that gives the joint torques. ``values`` (n,)
        defaults to the model's current compliances, else zeros. See :mod:`calib.model.compliance`."""
        if gravity is None or not callable(getattr(gravity, "torques", None)):
            raise ParameterError("a model with compliance needs a gravity model (calib.model.compliance.GravityModel), "
                                 f"got {type(gravity).__name__}")
        geo = self.geometry()
        n = self.n_joints
        old = self.compliances() if self.has_compliance else np.zeros(n)
        vals = old if values is None else check_array(values, "values", (n,), unit="rad/(N m) or m/N")
        params = tuple(Parameter(f"c{i}", "compliance", "c", i, "m/N" if j.is_prismatic else "rad/(N m)")
                       for i, j in enumerate(self.joints, start=1))
        out = replace(geo, parameters=geo.parameters + params,
                      values=np.concatenate([geo.values, vals]), gravity=gravity)
        return out.with_periodic(self.periodic_values()) if self.has_periodic else out

    def with_periodic(self, values: Sequence[float] | None = None) -> "RobotModel":
        """A copy with the periodic joint-angle errors (:mod:`calib.model.periodic`): four
        coefficients ``q<i>_sin1``, ``q<i>_cos1``, ``q<i>_sin2``, ``q<i>_cos2`` (rad) per
        revolute joint i (group "periodic", last). ``values`` (4 n_revolute,) in that order
        defaults to the model's current coefficients, else zeros. :class:`calib.ParameterError`
        for a chain of prismatic joints only."""
        rev = [i for i, j in enumerate(self.joints, start=1) if not j.is_prismatic]
        if not rev:
            raise ParameterError("periodic joint errors need a revolute joint: the chain has prismatic joints only")
        old = self.periodic_values() if self.has_periodic else np.zeros(4 * len(rev))
        vals = old if values is None else check_array(values, "values", (4 * len(rev),),
                                                      unit="periodic coefficients, rad, 4 per revolute joint")
        params = tuple(Parameter(periodic_name(i, k), PERIODIC_GROUP, k, i, "rad") for i in rev for k in PERIODIC_KINDS)
        base = self._strip((PERIODIC_GROUP,))
        return replace(base, parameters=base.parameters + params, values=np.concatenate([base.values, vals]))

    def geometry(self) -> "RobotModel":
        """This model without its joint terms, compliance and periodic (itself if it has none)."""
        if not self.has_joint_terms:
            return self
        return replace(self._strip(("compliance", PERIODIC_GROUP)), gravity=None)

    def _strip(self, groups) -> "RobotModel":
        keep = [k for k, p in enumerate(self.parameters) if p.group not in groups]
        return replace(self, parameters=tuple(self.parameters[k] for k in keep), values=self.values[keep])

    def _terms_onto(self, geo: "RobotModel") -> "RobotModel":
        """``geo`` (a model of the same joints, no joint terms) with this model's joint terms."""
        if self.has_compliance:
            geo = geo.with_compliance(self.gravity, self.compliances())
        return geo.with_periodic(self.periodic_values()) if self.has_periodic else geo

    @property
    def has_periodic(self) -> bool:
        return any(p.group == PERIODIC_GROUP for p in self.parameters)

    @property
    def has_joint_terms(self) -> bool:
        """Whether the model has compliance or periodic terms (joint errors before the chain)."""
        return self.has_compliance or self.has_periodic

    @property
    def periodic_names(self) -> tuple[str, ...]:
        """Names of the periodic coefficients (empty without them)."""
        return tuple(p.name for p in self.parameters if p.group == PERIODIC_GROUP)

    def periodic_values(self) -> np.ndarray:
        """(4 n_revolute,) periodic coefficients, rad, in parameter order; empty without them."""
        return self.values[self.indices(self.periodic_names)] if self.has_periodic else np.zeros(0)

    def joint_errors(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) the joint terms' deviations q_eff - q at commanded Q (N, n) (rad / m): the
        gravity deflection C tau(q) plus the periodic errors; zeros for a model without them."""
        Q = check_configurations(Q, self.n_joints)
        out = np.zeros(Q.shape)
        if self.has_compliance:
            out += self.gravity.torques(Q) * self.compliances()
        if self.has_periodic:
            joints = np.array([self.parameters[self.index(n)].joint - 1 for n in self.periodic_names])
            out += periodic_offsets(Q, joints, self.periodic_values(), self.n_joints)
        return out

    @property
    def has_compliance(self) -> bool:
        return self.gravity is not None

    @property
    def compliance_names(self) -> tuple[str, ...]:
        """Names of the compliance parameters (empty without compliance)."""
        return tuple(p.name for p in self.parameters if p.group == "compliance")

    def compliances(self) -> np.ndarray:
        """(n,) joint compliances, rad/(N m) (m/N prismatic); zeros without compliance."""
        if not self.has_compliance:
            return np.zeros(self.n_joints)
        return self.values[self.indices(self.compliance_names)]

    # ------------------------------------------------------------------ lookup
    @property
    def urdf_path(self) -> Path | None:
        """The URDF the model was read from (``source.path``), or None for a model built in code."""
        return None if self.source is None else Path(self.source.path)

    n_joints = property(lambda self: len(self.joints))
    n_params = property(lambda self: len(self.parameters))
    names = property(lambda self: tuple(p.name for p in self.parameters), doc="The parameter names, in order.")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower(self) -> np.ndarray:
        """(n,) lower joint limits (rad or m)."""
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        """(n,) upper joint limits (rad or m)."""
        return np.array([j.upper for j in self.joints])

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) bool: which joints are prismatic."""
        return np.array([j.is_prismatic for j in self.joints])

    def index(self, name: str) -> int:
        """Position of the parameter ``name`` in :attr:`values`."""
        try:
            return self._index[name]
        except (KeyError, TypeError):
            raise ParameterError(f"unknown parameter {name!r}; known: {', '.join(self.names)}") from None

    def indices(self, names: Iterable[str]) -> np.ndarray:
        """Positions of the parameters ``names`` (a list of names) in :attr:`values`."""
        if type(names) not in (tuple, list):        # (the usual ones, without the Iterable check's cost)
            if isinstance(names, (str, bytes)) or not isinstance(names, Iterable):
                raise ParameterError(f"names must be a list of parameter names, got {names!r:.60}")
            names = list(names)
        try:        # (the table itself: a call of index() per name cost more than the rest)
            return np.array([self._index[n] for n in names], dtype=int)
        except (KeyError, TypeError):
            return np.array([self.index(n) for n in names], dtype=int)    # (raises, naming it)

    def value(self, name: str) -> float:
        return float(self.values[self.index(name)])

    def has_beta(self, joint: int) -> bool:
        return f"beta{joint}" in self._index

    def mdh_table(self) -> dict[str, np.ndarray]:
        """Arrays theta, d, a, alpha, beta (NaN where absent), each (n,), SI units."""
        n = self.n_joints
        table = {k: np.array([self.value(f"{k}{i}") for i in range(1, n + 1)])
                 for k in ("theta", "d", "a", "alpha")}
        table["beta"] = np.array([self.value(f"beta{i}") if self.has_beta(i) else np.nan
                                  for i in range(1, n + 1)])
        return table

    @property
    def n_targets(self) -> int:
        """Number of flange->tool transforms (1 for a one-tool-frame model)."""
        return max(1, len(self.targets))

    def target_index(self, target: str | int | None = None) -> int:
        """Position of a target (id, or index) in :attr:`targets`; None is the first."""
        if target is None:
            return 0
        if isinstance(target, (int, np.integer)) and not isinstance(target, bool):
            if not 0 <= target < self.n_targets:
                raise ParameterError(f"target index {target} out of range for {self.n_targets} target(s)")
            return int(target)
        try:
            return self.targets.index(target)
        except ValueError:
            known = ", ".join(self.targets) if self.targets else "none: the model has one tool frame"
            raise ParameterError(f"unknown target {target!r}; targets of the model: {known}") from None

    def target_rows(self, target_ids: Sequence[str] | None) -> np.ndarray | None:
        """(N,) int: the target index of each row's target id (from ``Measurements.target``), or
        None for a one-tool-frame model. Raises :class:`calib.DataError` for an unknown id."""
        if not self.targets:
            return None
        from calib.errors import DataError

        if target_ids is None:
            raise DataError(f"the model has {self.n_targets} targets ({', '.join(self.targets)}): the "
                            f"measurements need a target column")
        lookup = {t: k for k, t in enumerate(self.targets)}
        out = np.empty(len(target_ids), int)
        for i, t in enumerate(target_ids):
            if t not in lookup:
                raise DataError(f"row {i + 1}: target {t!r} is not a target of the model "
                                f"({', '.join(self.targets)})")
            out[i] = lookup[t]
        return out

    @property
    def T_flange_tool_refs(self) -> np.ndarray:
        """(K, 4, 4) the reference flange->tool transform of each target (K = n_targets)."""
        return self.T_flange_target_refs if self.targets else self.T_flange_tool_ref[None]

    def T_flange_tool_ref_of(self, target: str | int | None = None) -> np.ndarray:
        """(4, 4) the reference flange->tool transform of one target (default the first)."""
        return self.T_flange_tool_refs[self.target_index(target)]

    def v_names(self, target: str | int | None = None) -> tuple[str, ...]:
        """Names of the six v parameters of one target (default the first)."""
        return v_names(self.targets[self.target_index(target)] if self.targets else None)

    def u(self) -> np.ndarray:
        """(6,) u = (x, y, z, alpha, beta, gamma), metres / radians."""
        return self.values[self.indices(U_NAMES)]

    def v(self, target: str | int | None = None) -> np.ndarray:
        """(6,) v = (x', y', z', alpha', beta', gamma') of one target (default the first),
        metres / radians."""
        return self.values[self.indices(self.v_names(target))]

    # ------------------------------------------------------------------ kinematics (reference)
    def T_meas_base(self) -> np.ndarray:
        """(4, 4) pose of MDH frame 0 (base) in the meas frame."""
        frames = self.frame_memo
        if "base" not in frames:
            frames["base"] = self.T_meas_base_ref @ zyx_transform(*self.u())
        return frames["base"].copy()

    def T_flange_tool(self, target: str | int | None = None) -> np.ndarray:
        """(4, 4) pose of the tool frame (of one target, default the first) in MDH frame n (flange)."""
        frames, k = self.frame_memo, self.target_index(target)
        if k not in frames:
            frames[k] = zyx_transform(*self.v(k)) @ self.T_flange_tool_ref_of(k)
        return frames[k].copy()

    @cached_property
    def frame_memo(self) -> dict:
        """The flange->target frames of this (immutable) model's values, by target index."""
        return {}

    @cached_property
    def content_key(self) -> tuple:
        """What results computed from this model depend on (memo keys): a digest of its values,
        frames and joint limits, its structure and the gravity load of a model with compliance."""
        refs = self.T_flange_target_refs if self.T_flange_target_refs is not None else self.T_flange_tool_ref
        digest = content_digest(np.asarray(self.values, float), np.asarray(self.T_meas_base_ref, float),
                                np.asarray(refs, float), np.stack([self.lower, self.upper]))
        structure = (self.names, tuple((j.name, j.kind) for j in self.joints), self.targets)
        gm = getattr(self, "gravity", None)
        # (a torque model of another kind, which with_compliance accepts: by identity, held)
        load = None if gm is None else getattr(gm, "content_key", ("object", gm))
        return digest, structure, load

    def T_base_flange(self, q: np.ndarray) -> np.ndarray:
        """(4, 4) pose of the flange in the base frame at one commanded configuration q (n,),
        rad / m, with the model's joint terms (gravity deflection, periodic errors:
        :meth:`joint_errors`) applied to q first.

        A direct product of Eq. (1) matrices, kept simple on purpose: it is the reference that
        the Pinocchio-based batch kinematics (:mod:`calib.model.kinematics`) is tested against.
        """
        q = check_array(q, "q", (self.n_joints,), unit="one configuration, rad / m")
        if self.has_joint_terms:
            q = q + self.joint_errors(q[None])[0]
        t = self.mdh_table()
        T = np.eye(4)
        for i, joint in enumerate(self.joints):
            beta = 0.0 if np.isnan(t["beta"][i]) else t["beta"][i]
            if joint.is_prismatic:
                T = T @ link_transform(t["theta"][i], t["d"][i] + q[i], t["a"][i], t["alpha"][i], beta)
            else:
                T = T @ link_transform(t["theta"][i] + q[i], t["d"][i], t["a"][i], t["alpha"][i], beta)
        return T

    def T_meas_tool(self, q: np.ndarray, target: str | int | None = None) -> np.ndarray:
        """(4, 4) pose of the tool (of one target, default the first) in the meas frame at one
        commanded configuration q (n,), rad / m: the whole fitted model, joint terms included
        (the gravity deflection of a model with compliance, the periodic joint errors)."""
        return self.T_meas_base() @ self.T_base_flange(q) @ self.T_flange_tool(target)

    def random_configurations(self, n: int, rng: np.random.Generator | int | None = None,
                              unlimited_range: float = math.pi) -> np.ndarray:
        """(n, n_joints) configurations uniform within the joint limits (radians / metres).

        Unlimited (continuous) joints are drawn in [-unlimited_range, unlimited_range] (radians,
        or metres for an unlimited prismatic joint). n : at most MAX_CONFIGURATIONS.
        """
        n = check_int(n, "n", maximum=MAX_CONFIGURATIONS)
        rng = check_rng(rng)
        unlimited_range = check_number(unlimited_range, "unlimited_range", minimum=0.0)
        lo = np.where(np.isfinite(self.lower), self.lower, -unlimited_range)
        hi = np.where(np.isfinite(self.upper), self.upper, unlimited_range)
        return rng.uniform(lo, hi, size=(n, self.n_joints))

    def describe(self) -> str:
        """A human-readable table of the MDH parameters (mm, rad) and the two frame transforms."""
        t = self.mdh_table()
        lines = [f"{'joint':<16}{'type':<11}{'theta/rad':>11}{'d/mm':>11}{'a/mm':>11}"
                 f"{'alpha/rad':>11}{'beta/rad':>11}"]
        for i, j in enumerate(self.joints):
            beta = "/" if np.isnan(t["beta"][i]) else f"{t['beta'][i]:.6f}"
            lines.append(f"{j.name:<16}{j.kind:<11}{t['theta'][i]:>11.6f}{t['d'][i] * 1e3:>11.4f}"
                         f"{t['a'][i] * 1e3:>11.4f}{t['alpha'][i]:>11.6f}{beta:>11}")
        frames = [("meas->base", self.T_meas_base())]
        frames += [(f"flange->{'tool' if not self.targets else t}", self.T_flange_tool(k))
                   for k, t in enumerate(self.targets or ("tool",))]
        for label, T in frames:
            x = zyx_parameters(T)
            lines.append(f"{label:<14} x,y,z/mm = {x[0] * 1e3:.4f}, {x[1] * 1e3:.4f}, {x[2] * 1e3:.4f};"
                         f"  alpha,beta,gamma/rad = {x[3]:.6f}, {x[4]:.6f}, {x[5]:.6f}")
        if self.has_compliance:
            lines.append("compliance/(urad/(N m) or um/N): " + ", ".join(
                f"{n} {v * 1e6:.4g}" for n, v in zip(self.compliance_names, self.compliances())))
        if self.has_periodic:
            lines.append("periodic joint errors/urad: " + ", ".join(
                f"{n} {v * 1e6:.4g}" for n, v in zip(self.periodic_names, self.periodic_values())))
        return "\n".join(lines)


def check_robot(value: Any, name: str = "robot") -> RobotModel:
    """``value`` if it is a :class:`RobotModel`, else :class:`calib.ParameterError` naming ``name``."""
    return check_instance(value, name, RobotModel, "from calib.load_robot")
