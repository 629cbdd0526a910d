"""Plots of a calibration: per-pose tool pose errors before and after, and their histograms.

:func:`render_plots` draws, with matplotlib's Agg canvas (no display needed; pyplot and the
global backend are left alone):

- ``position_errors.png`` (as Figure 7 of the paper): per pose, the position error |p_model -
  p_measured| and its x, y, z components in the meas frame, millimetres; one panel for the
  nominal model (before) and one for the calibrated model (after). Calibration rows come first,
  then validation rows, separated by a dashed line.
- ``orientation_errors.png`` (as Figure 8): per pose, the angle of ``R_model R_measured^T`` and
  the components of its rotation vector about the meas frame's x, y, z axes, radians (not drawn
  for position-only data).
- ``error_histograms.png``: histograms of the position (mm) and orientation (rad) errors, before
  and after, calibration and validation rows apart.

The rows are split as :func:`calib.calibrate` splits them: the ``cal`` rows of the measurements
(all rows without a set column) for identification; their ``val`` rows and the extra validation
measurements for validation.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from .calibration import CalibrationResult
from .kinematics import ChainKinematics
from .measurements import Measurements
from .robot import RobotModel
from .spatial import log3_batch

__all__ = ["PoseDeviations", "pose_deviations", "render_plots"]

#: File names of the plots, in the order :func:`render_plots` returns them.
PLOT_FILES = ("position_errors.png", "orientation_errors.png", "error_histograms.png")


@dataclass(frozen=True)
class PoseDeviations:
    """Per-pose deviations of a model's tool pose from measured ones, in the meas frame.

    position : (N, 3) float, metres: p_model - p_measured.
    rotation : (N, 3) float, radians: rotation vector of R_model R_measured^T, or None for
        position-only data.
    """

    position: np.ndarray
    rotation: np.ndarray | None

    @property
    def position_errors(self) -> np.ndarray:
        """(N,) metres: the length of each position deviation."""
        return np.linalg.norm(self.position, axis=1)

    @property
    def rotation_errors(self) -> np.ndarray | None:
        """(N,) radians: the rotation angle of each orientation deviation."""
        return None if self.rotation is None else np.linalg.norm(self.rotation, axis=1)


def pose_deviations(robot: RobotModel, measurements: Measurements) -> PoseDeviations:
    """Deviations of ``robot``'s tool poses from ``measurements`` (both in the meas frame)."""
    R, p = ChainKinematics(robot).frame_poses(measurements.q)
    rot = None
    if measurements.rotation is not None:
        rot = log3_batch(R @ np.transpose(measurements.rotation, (0, 2, 1)))
    return PoseDeviations(p - measurements.position, rot)


def _split(measurements: Measurements, validation: Measurements | None):
    """(calibration rows, validation rows or None), as calibrate() splits them."""
    cal = measurements.calibration()
    parts = [m for m in (measurements.validation(), validation) if m is not None and m.n_poses]
    return cal, parts


def _deviations(robot: RobotModel, cal: Measurements, val_parts) -> tuple[PoseDeviations, PoseDeviations | None]:
    dc = pose_deviations(robot, cal)
    if not val_parts:
        return dc, None
    dv = [pose_deviations(robot, m) for m in val_parts]
    rot = None if any(d.rotation is None for d in dv) else np.concatenate([d.rotation for d in dv])
    return dc, PoseDeviations(np.concatenate([d.position for d in dv]), rot)


def _figure_bytes(fig) -> bytes:
    """The figure as PNG, drawn by the Agg canvas (pyplot and the global backend are not used)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def render_plots(result: CalibrationResult, measurements: Measurements,
                 validation: Measurements | None = None) -> dict[str, bytes]:
    """PNG images of the calibration's pose errors, by file name (see the module docstring).

    Parameters
    ----------
    result : what :func:`calib.calibrate` returned for these measurements.
    measurements, validation : the arguments given to :func:`calib.calibrate`.

    Returns ``{file name: PNG bytes}``; ``orientation_errors.png`` is left out for position-only
    data. Nothing is written: the caller decides where the images go.
    """
    from matplotlib.figure import Figure

    cal, val_parts = _split(measurements, validation)
    before = _deviations(result.nominal, cal, val_parts)
    after = _deviations(result.robot, cal, val_parts)
    n_cal = cal.n_poses
    has_rot = before[0].rotation is not None and (before[1] is None or before[1].rotation is not None)

    def stack(pair, attr):
        parts = [getattr(d, attr) for d in pair if d is not None]
        return np.concatenate(parts)

    images: dict[str, bytes] = {}
    colors = ("tab:red", "tab:green", "tab:blue")

    def per_pose(kind: str, scale: float, unit: str, title: str) -> bytes:
        fig = Figure(figsize=(10, 7), layout="constrained")
        axes = fig.subplots(2, 1)
        for ax, (label, dev) in zip(axes, (("before calibration (nominal model)", before),
                                           ("after calibration", after))):
            comp = stack(dev, kind) * scale
            norm = np.linalg.norm(comp, axis=1)
            idx = np.arange(1, len(norm) + 1)
            ax.plot(idx, norm, color="black", lw=1.2, marker=".", ms=3, label="error (norm)")
            for c, axis_name, color in zip(comp.T, "xyz", colors):
                ax.plot(idx, c, color=color, lw=0.7, alpha=0.8,
                        label=f"{'about ' if kind == 'rotation' else ''}{axis_name}")
            ax.axhline(0.0, color="grey", lw=0.5)
            if len(norm) > n_cal:
                ax.axvline(n_cal + 0.5, color="grey", ls="--", lw=1.0)
                ax.text(n_cal + 0.5, 1.0, "  validation rows", transform=ax.get_xaxis_transform(),
                        va="top", ha="left", fontsize=8, color="grey")
                ax.text(n_cal + 0.5, 1.0, "calibration rows  ", transform=ax.get_xaxis_transform(),
                        va="top", ha="right", fontsize=8, color="grey")
            ax.set_title(f"{title}, {label}: mean {norm.mean():.4g} {unit}, max {norm.max():.4g} {unit} "
                         f"over all {len(norm)} rows",
                         fontsize=10)
            ax.set_xlabel("pose")
            ax.set_ylabel(f"{title.split(' ')[0]} error / {unit}")
            ax.set_xlim(0.5, len(norm) + 0.5)
            ax.legend(fontsize=8, ncol=4, loc="lower right")
            ax.grid(alpha=0.3)
        fig.suptitle(f"Tool {title} in the meas frame per pose ({result.method.upper()}, "
                     f"parameter set {result.param_set!r})")
        return _figure_bytes(fig)

    images["position_errors.png"] = per_pose("position", 1e3, "mm", "position deviation")
    if has_rot:
        images["orientation_errors.png"] = per_pose("rotation", 1.0, "rad", "orientation deviation")

    fig = Figure(figsize=(10, 7 if has_rot else 3.8), layout="constrained")
    rows = 2 if has_rot else 1
    axes = np.atleast_2d(fig.subplots(rows, 2))
    quantities = [("position_errors", 1e3, "position error / mm")]
    if has_rot:
        quantities.append(("rotation_errors", 1.0, "orientation error / rad"))
    for r, (attr, scale, xlabel) in enumerate(quantities):
        for c, (label, dev) in enumerate((("before calibration", before), ("after calibration", after))):
            ax = axes[r, c]
            data = [(name, getattr(d, attr) * scale) for name, d in (("calibration rows", dev[0]),
                                                                     ("validation rows", dev[1]))
                    if d is not None]
            hi = max(float(e.max()) for _, e in data)
            bins = np.linspace(0.0, hi * 1.0001 if hi > 0 else 1.0, 31)
            for (name, e), color in zip(data, ("tab:blue", "tab:orange")):
                ax.hist(e, bins=bins, alpha=0.6, color=color, label=f"{name} ({len(e)})")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("poses")
            ax.set_title(label, fontsize=10)
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
    fig.suptitle("Distribution of the tool pose errors")
    images["error_histograms.png"] = _figure_bytes(fig)
    return images
