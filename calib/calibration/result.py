"""The calibration result (:class:`CalibrationResult`): the parameter table, accuracy before and after,
its text, dict and JSON forms, and the calibrated URDF.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib.calibration.accuracy.errors import AccuracyStats
from calib.calibration.accuracy.validation import consistency_dict
from calib.calibration.accuracy.workspace import workspace_dict
from calib.calibration.estimators.base import NoiseEstimate
from calib.calibration.result_text import format_result, frames_table
from calib.units import display_unit, display_value
from calib.errors import ParameterError
from calib.model.chain import U_NAMES
from calib.model.robot import RobotModel
from calib.model.spatial import zyx_parameters

if TYPE_CHECKING:           # (calib.calibration.base_frame is loaded when a calibration reports the frame)
    from calib.calibration.base_frame import MeasurementFrame
    from calib.calibration.estimators.base import GroupFit
    from calib.calibration.parameters import TouchIdentifiability
    from calib.model.touch import FeatureFit
    from calib.calibration.accuracy.cross_validation import CrossValidation, ModelSelection
    from calib.calibration.estimators.outlier import Outlier
    from calib.calibration.accuracy.errors import TargetAccuracy


# ====================================================================== result
@dataclass(frozen=True)
class ParameterEstimate:
    """One row of the parameter table. Values in SI units (``unit``: m or rad).

    For u and v rows, ``nominal`` and ``identified`` are the Eq. (3) values of the whole
    transform (T_meas_base or T_flange_tool), so that they read the same whatever reference the
    model uses internally. ``std`` is NaN for parameters held fixed, and for free parameters in a
    rank-deficient set (``all``, ``paper``) it comes from the pseudo-inverse.
    """

    name: str
    unit: str
    nominal: float
    identified: float
    free: bool
    std: float

    @property
    def deviation(self) -> float:
        d = self.identified - self.nominal
        if self.unit == "rad":
            d = (d + math.pi) % (2 * math.pi) - math.pi
        return d


@dataclass(frozen=True, eq=False)     # (array fields: compared by identity; nothing compares them)
class CalibrationResult:
    """What :func:`calibrate` returns (compare scipy's ``OptimizeResult``).

    robot : the calibrated model; nominal : the model calibration started from.
    parameters : the parameter table; free : names of the identified parameters.
    status : "converged", "max_iterations", "diverged", "local_minimum" (an explicit lm / c-lm
    fit that a search from another start beats) or "implausible" (converged, but to a result no
    robot and instrument give, or far above given noise levels:
    :func:`calib.calibration.estimators.least_squares.implausibility`, ``message`` says why); success : status ==
    "converged".
    before, after : accuracy on the calibration rows (outliers included); after_without_outliers :
    the same without the rows flagged as outliers (None when none were); validation_before/after
    on the validation rows (None without validation data); before_registered /
    validation_before_registered : the nominal model after a best-fit registration of the
    measurement frame, with the tool (or target) frames at their closed-form estimates when those
    were far from the nominal ones (None unless a frame was: the nominal model's errors otherwise).
    noise : the noise levels of the fit (:class:`NoiseEstimate`); sigma_pos, sigma_rot : the same
    numbers (sigma_rot is that of the weighting also for position-only data).
    predicted : the Cramer-Rao prediction of the calibrated model's RMS error against the true
    poses (position_rms m, rotation_rms rad, where); predicted_holdout : the RMS error expected on
    new measured rows (:class:`Statistics`). cross_validation, selection : see
    :class:`CrossValidation`, :class:`ModelSelection` (None when not run).
    covariance : (n_free, n_free) covariance of the free parameters (SI units).
    measurement_frame : when the calibration estimated the measurement frame, the robot's base
    frame in it with its covariance (:class:`calib.calibration.base_frame.MeasurementFrame`):
    ``robot`` predicts tool poses in the meas frame; :meth:`base_robot` in the robot's base frame,
    which is what the calibrated URDF holds; None otherwise (meas frame = base frame).
    nominal_registered : the nominal model that ``before_registered`` is of: its measurement
    frame registered by a best fit, its tool or targets where the closed-form estimate put them
    (None unless the frames were estimated).
    estimated_frames : the frames estimated in closed form because the data put them far from the
    nominal ones ("measurement->base", "flange->tool" or "flange-><id>" per target; () if none):
    the calibrated model's base frame is then the instrument's, its tool the measured point.
    targets : per target of a multi-target calibration, its accuracy (:class:`TargetAccuracy`;
    the overall figures are ``before``/``after``); () for one target.
    predicted_workspace : the RMS error expected on new measured rows at random configurations
    within the joint limits (position_rms m, rotation_rms rad; model_position_rms /
    model_rotation_rms against the true poses; joint_coverage: the fraction of each joint's range
    the calibration poses span; :func:`calib.calibration.accuracy.workspace.predict_workspace`), None when
    not computed. consistency : when more than a tenth of the calibration rows were flagged as
    outliers, the held-out error of all rows (flagged ones included) beside the prediction for
    rows like the kept ones, and the likely causes
    (:func:`calib.calibration.accuracy.validation.data_consistency`; its note comes first in ``notes``);
    None otherwise.
    estimator : how the parameters were estimated: ``{"kind": "least-squares", "param_set": ...}``
    or, for the regularised estimate (:mod:`calib.calibration.estimators.regularised`), ``{"kind": "eb-map",
    "prior_scales": {group: tau} (theta, twist rad; length mm), "effective_parameters",
    "log_evidence", ...}`` (:meth:`calib.calibration.estimators.eb_map.EBMapResult.to_dict`).
    Touch data (:class:`calib.model.touch.TouchData`): features : the features' unknowns
    (:class:`calib.model.touch.FeatureFit`: names such as ``point_<id>_x``, values, std); groups :
    each residual group's figures (:class:`~calib.calibration.estimators.base.GroupFit`: touch,
    and the measured rows' position and rotation); identifiability : the robot parameters the
    rows determine and those held nominal (:class:`~calib.calibration.parameters.TouchIdentifiability`);
    nominal_scale : no length fixed the scale and it was held nominal; ``predicted`` is the tool
    positions' error over the workspace after a best-fit registration (``meas_frame_rms``: in the
    meas frame); ``before`` / ``after`` hold every row's error (a touch row's distance to its
    feature, a measured row's position error). None, (), None and False otherwise.
    """

    robot: RobotModel
    nominal: RobotModel
    method: str
    param_set: str
    parameters: tuple[ParameterEstimate, ...]
    free: tuple[str, ...]
    status: str
    message: str
    iterations: int
    rounds: int
    wall_time: float
    cost: float
    reduced_chi2: float
    covariance: np.ndarray = field(repr=False)
    before: AccuracyStats = field(repr=False)
    after: AccuracyStats = field(repr=False)
    validation_before: AccuracyStats | None = field(repr=False)
    validation_after: AccuracyStats | None = field(repr=False)
    predicted: dict = field(repr=False)
    sigma_pos: float
    sigma_rot: float
    notes: tuple[str, ...] = ()
    outliers: tuple[Outlier, ...] = ()
    loss: str = "linear"
    noise: NoiseEstimate | None = None
    predicted_holdout: dict | None = field(default=None, repr=False)
    cross_validation: CrossValidation | None = field(default=None, repr=False)
    selection: ModelSelection | None = field(default=None, repr=False)
    before_registered: AccuracyStats | None = field(default=None, repr=False)
    validation_before_registered: AccuracyStats | None = field(default=None, repr=False)
    targets: tuple[TargetAccuracy, ...] = field(default=(), repr=False)
    after_without_outliers: AccuracyStats | None = field(default=None, repr=False)
    estimated_frames: tuple[str, ...] = ()
    predicted_workspace: dict | None = field(default=None, repr=False)
    consistency: dict | None = field(default=None, repr=False)
    estimator: dict | None = None
    measurement_frame: MeasurementFrame | None = field(default=None, repr=False)
    nominal_registered: RobotModel | None = field(default=None, repr=False)
    features: FeatureFit | None = field(default=None, repr=False)
    groups: tuple[GroupFit, ...] = field(default=(), repr=False)
    identifiability: TouchIdentifiability | None = field(default=None, repr=False)
    nominal_scale: bool = False

    def group(self, name: str) -> GroupFit | None:
        """The residual group ``name`` ("touch", "position", "rotation") of a fit of touch data, or None."""
        if not isinstance(name, str):
            raise ParameterError(f"name must be a residual group's name (a string), got {name!r:.60}")
        return next((g for g in self.groups if g.name == name), None)

    def base_robot(self) -> RobotModel:
        """The calibrated model with its tool poses in the robot's base frame: ``robot`` itself,
        or, when the calibration estimated the measurement frame (:attr:`measurement_frame`),
        ``T_base_tool(q) = T_meas_base^-1 T_meas_tool(q)`` (what the calibrated URDF holds;
        :mod:`calib.calibration.base_frame`)."""
        if self.measurement_frame is None:
            return self.robot
        from calib.calibration.base_frame import in_base_frame

        return in_base_frame(self.robot, self.measurement_frame)

    def flange_robot(self) -> RobotModel:
        """The one-tool-frame model of the tool frame the calibrated URDF holds, in the robot's
        base frame like :meth:`base_robot`: for a calibration of several targets the URDF's tool
        frame at the flange (its nominal transform from the calibrated chain, the last link's
        parameters that the targets cannot separate from their offsets at the nominal values:
        :mod:`calib.model.flange`), without the targets; :meth:`base_robot` itself otherwise.
        What compensation aims at: ``calib.compensate(result.flange_robot(),
        calib.load_robot(URDF), q)``."""
        robot = self.base_robot()
        if not robot.targets:
            return robot
        from calib.io.urdf.reader import nominal_tool_model
        from calib.model.flange import flange_robot, with_nominal_last_link

        tool = nominal_tool_model(self.nominal)
        if self._nominal_flange():
            robot = with_nominal_last_link(robot, tool)
        return flange_robot(robot, tool.T_flange_tool_ref)

    def _nominal_flange(self) -> bool:
        """Whether the targets were placed by the fit (a v parameter of each free): the last
        link's parameters then trade against their offsets and are written at the nominal."""
        free = set(self.free)
        return bool(self.robot.targets) and all(any(n in free for n in self.robot.v_names(t))
                                                for t in self.robot.targets)

    @property
    def success(self) -> bool:
        return self.status == "converged"

    @property
    def x(self) -> np.ndarray:
        """Identified values of the free parameters (SI)."""
        return self.robot.values[self.robot.indices(self.free)]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def parameter(self, name: str) -> ParameterEstimate:
        """The estimate of the parameter ``name``."""
        if not isinstance(name, str):
            raise ParameterError(f"name must be a parameter name (a string), got {name!r:.60}")
        for p in self.parameters:
            if p.name == name:
                return p
        raise ParameterError(f"unknown parameter {name!r}")

    def write_urdf(self, path: str | Path, *, measurement_link: str | None = None):
        """Write the calibrated model as a URDF (see :func:`calib.io.urdf.writer.write_calibrated_urdf`),
        rooted where the input was: :meth:`base_robot`, with the measurement->base transform
        recorded (and, with ``measurement_link``, added as a fixed link above the root).
        Returns the frames written (:class:`calib.io.urdf.document.RecordedFrames`).

        The URDF holds the geometry; with joint terms (compliance, periodic errors) these go to the
        sidecar :func:`calib.io.compliance_file.sidecar_path` beside it
        (:func:`calib.io.compliance_file.write_sidecar`): the URDF read with the sidecar
        (:func:`calib.io.compliance_file.apply_record`, torques from the nominal URDF) is
        ``self.robot``."""
        frames = self.write_urdf_only(path, measurement_link=measurement_link)
        if self.robot.has_joint_terms:
            from calib.io.compliance_file import sidecar_path, write_sidecar

            write_sidecar(sidecar_path(path), self.compliance_record())
        return frames

    def write_urdf_only(self, path: str | Path, *, measurement_link: str | None = None):
        """The URDF of :meth:`write_urdf` without the compliance sidecar; returns its frames."""
        from calib.io.urdf.writer import write_calibrated_urdf

        return write_calibrated_urdf(self.base_robot().geometry(), path, **self._urdf_arguments(measurement_link))

    def urdf_text(self, *, measurement_link: str | None = None):
        """(the text :meth:`write_urdf_only` writes, the frames it records), without a file."""
        from calib.io.urdf.writer import calibrated_urdf_text

        return calibrated_urdf_text(self.base_robot().geometry(), **self._urdf_arguments(measurement_link))

    def _urdf_arguments(self, measurement_link: str | None) -> dict:
        mf = self.measurement_frame
        if mf is None and measurement_link is not None:
            raise ParameterError("measurement_link: this calibration did not estimate a measurement frame "
                                 "(its measurements are in the robot's base frame)")
        return dict(nominal=self.nominal.geometry(), estimated=self.estimated_frames,
                    T_meas_base=None if mf is None else mf.T_meas_base,
                    meas_covariance=None if mf is None else mf.covariance, measurement_link=measurement_link,
                    orientation_measured=self.before.rotation is not None or self.group("rotation") is not None,
                    nominal_flange=self._nominal_flange())

    def compliance_record(self) -> dict | None:
        """The compliances and periodic terms with their std, payload and gravity
        (:func:`calib.io.compliance_file.compliance_record`), None for a model without them."""
        if not self.robot.has_joint_terms:
            return None
        from calib.io.compliance_file import compliance_record

        return compliance_record(self.robot, {p.name: p.std for p in self.parameters if p.free})

    def to_dict(self) -> dict:
        """JSON-ready report: keys status, before, after, validation, parameters, noise, ..."""
        has_rot = self.predicted.get("rotation_rms") is not None
        ph = self.predicted_holdout
        return {
            "status": self.status,
            "success": self.success,
            "message": self.message,
            "data_consistency": consistency_dict(self.consistency),
            "method": self.method,
            "param_set": self.param_set,
            "estimator": self.estimator,
            "iterations": self.iterations,
            "rounds": self.rounds,
            "wall_time_s": self.wall_time,
            "cost": self.cost,
            "reduced_chi2": self.reduced_chi2,
            "sigma_pos_mm": self.sigma_pos * 1e3,
            "sigma_rot_rad": self.sigma_rot,
            "noise": None if self.noise is None else self.noise.to_dict(),
            "notes": list(self.notes),
            "loss": self.loss,
            "outliers": [{"row": o.row, "position_error_mm": o.position_error * 1e3,
                          "rotation_error_rad": None if math.isnan(o.rotation_error) else o.rotation_error,
                          "sigmas": o.sigmas} for o in self.outliers],
            "before": self.before.to_dict(),
            "after": self.after.to_dict(),
            "estimated_frames": list(self.estimated_frames),
            "measurement_frame": None if self.measurement_frame is None else self.measurement_frame.to_dict(),
            "frame_transforms": frames_table(self),
            "after_without_outliers": None if self.after_without_outliers is None
            else self.after_without_outliers.to_dict(),
            "before_registered": None if self.before_registered is None else {
                "calibration": self.before_registered.to_dict(),
                "validation": None if self.validation_before_registered is None
                else self.validation_before_registered.to_dict()},
            "validation": None if self.validation_after is None else {
                "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()},
            "targets": {t.target: t.to_dict() for t in self.targets} or None,
            "predicted_rms": {"position_mm": self.predicted["position_rms"] * 1e3,
                              "rotation_rad": self.predicted.get("rotation_rms"),
                              "where": self.predicted.get("where")},
            "predicted_holdout_rms": None if ph is None else {
                "position_mm": ph["position_rms"] * 1e3,
                "rotation_rad": ph["rotation_rms"] if has_rot else None},
            "predicted_workspace_rms": workspace_dict(self.predicted_workspace),
            "cross_validation": None if self.cross_validation is None else self.cross_validation.to_dict(),
            "model_selection": None if self.selection is None else self.selection.to_dict(),
            "compliance": self.compliance_record(),
            "parameters": [{"name": p.name, "unit": display_unit(p.unit),
                            "nominal": display_value(p.nominal, p.unit), "identified": display_value(p.identified, p.unit),
                            "deviation": display_value(p.deviation, p.unit),
                            "std": None if math.isnan(p.std) else display_value(p.std, p.unit),
                            "free": p.free} for p in self.parameters],
            **({} if self.features is None else {"touch": self.touch_dict()}),
        }

    def touch_dict(self) -> dict:
        """The touch data's part of :meth:`to_dict` (features, groups, identifiability, predictions)."""
        pr = self.predicted
        return {"features": self.features.to_dict(), "groups": [g.to_dict() for g in self.groups],
                "plane_normals": {f"plane_{f.id}": [float(v) for v in n]
                                  for f, n in zip(self.features.features, self.features.normals) if f.kind == "plane"},
                "identifiability": None if self.identifiability is None else self.identifiability.to_dict(),
                "nominal_scale": self.nominal_scale,
                "predicted_tool_error_mm": pr["position_rms"] * 1e3, "registration": pr["registration"],
                "predicted_tool_error_meas_frame_mm": None if pr.get("meas_frame_rms") is None
                else pr["meas_frame_rms"] * 1e3, "nominal_expected_error_mm": pr["nominal_rms"] * 1e3}

    def to_json(self) -> str:
        import json

        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    def format(self) -> str:
        """The report for a person: parameter table, accuracy before/after, status
        (:func:`calib.calibration.result_text.format_result`)."""
        return format_result(self)


def parameter_table(nominal: RobotModel, calibrated: RobotModel, free, cov) -> tuple[ParameterEstimate, ...]:
    """One row per parameter of ``nominal``: the joint parameters' values, the measurement and
    tool frames' as the ZYX parameters of the whole transform (reference and deviation), with
    the standard deviations of what is shown: a frame's are propagated from the covariance of its
    six deviation parameters (a tool's x, y, z move with a free angle when the reference places
    the tool away from the flange: a marker measured by position only, held x and z, free beta
    and gamma, was shown as "fixed" in x and z; the measurement frame's angles mix when its
    reference is rotated)."""
    std = dict(zip(free, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist()))
    fitted = set(free)
    free = {n: k for k, n in enumerate(free)}      # (name -> row of cov, for both frames)
    frame_vals = {("u", None): (zyx_parameters(nominal.T_meas_base()), zyx_parameters(calibrated.T_meas_base()))}
    std.update(_frame_std(calibrated.T_meas_base_ref, calibrated.u(), np.eye(4), U_NAMES, free, cov))
    for t in nominal.targets or (None,):
        frame_vals["v", t] = (zyx_parameters(nominal.T_flange_tool(t)), zyx_parameters(calibrated.T_flange_tool(t)))
        std.update(_frame_std(np.eye(4), calibrated.v(t), calibrated.T_flange_tool_ref_of(t), calibrated.v_names(t),
                              free, cov))
    kinds = {k: i for i, k in enumerate(("x", "y", "z", "alpha", "beta", "gamma"))}
    # (Python floats once: indexing numpy arrays per parameter costs more than the table)
    frame_vals = {key: (a.tolist(), b.tolist()) for key, (a, b) in frame_vals.items()}
    nominal_values, calibrated_values = nominal.values.tolist(), calibrated.values.tolist()
    rows = []
    for k, p in enumerate(nominal.parameters):
        if p.group in ("u", "v"):
            i = kinds[p.kind]
            nom, ide = frame_vals[p.group, p.target][0][i], frame_vals[p.group, p.target][1][i]
        else:
            nom, ide = nominal_values[k], calibrated_values[k]
        rows.append(ParameterEstimate(p.name, p.unit, nom, ide, p.name in fitted, std.get(p.name, math.nan)))
    return tuple(rows)


def _frame_std(T_left: np.ndarray, p: np.ndarray, T_right: np.ndarray, names, free, cov) -> dict:
    """Name -> standard deviation of each ZYX parameter of the frame ``T_left @ zyx(p) @ T_right``
    (the measurement frame: reference @ zyx(u); a tool frame: zyx(v) @ reference), ``names``
    its six parameters, from the covariance ``cov`` of the parameters ``free``; none where the
    frame does not move or its angles are at gimbal lock."""
    from calib.model.spatial import zyx_parameters_jacobian

    where = free if isinstance(free, dict) else {n: k for k, n in enumerate(free)}
    cols = [k for k, n in enumerate(names) if n in where]
    if not cols:
        return {}
    idx = [where[names[k]] for k in cols]
    J = zyx_parameters_jacobian(T_left, p, T_right)[:, cols]
    var = ((J @ np.asarray(cov)[idx][:, idx]) * J).sum(axis=1).tolist()    # diag(J C J^T)
    return {n: math.sqrt(v) for n, v in zip(names, var) if math.isfinite(v) and v > 0.0}
