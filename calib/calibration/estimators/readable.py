"""What a user reads in the identified parameters (issue 39, item 3): :func:`parameter_notes`.

A calibration's parameter table is read as the robot's: link lengths and joint offsets as built.
Two things make it misleading without a line saying so:

* a structural parameter moved beyond what a robot is built to (:data:`MOVED_LENGTH_M`,
  :data:`MOVED_ANGLE_RAD`) or far beyond its prior scale (:data:`MOVED_PRIOR_SCALES` times the
  scale EB-MAP's evidence chose for its group): such a move stands for an error the model does
  not hold, or a tie among parameters, more often than for the robot (a TIAGo's d6 +9.5 mm under
  a 4.4 mm prior);
* a prior group that EB-MAP's evidence held at about zero (:data:`NOT_CALIBRATED_SCALE`): those
  parameters were not calibrated at all (two real sets' joint offsets, at 1e-7 rad, said
  nothing).

Which side of a tie between a frame offset and a link length takes the value is decided where
the parameter set is chosen (:func:`calib.calibration.parameters.identifiable_set`: the frame);
:func:`tied_length_notes` names the lengths held for it.
"""
from __future__ import annotations

import math

import numpy as np

from calib.calibration.estimators.base import Fit
from calib.model.identifiability import identifiable_names
from calib.model.robot import RobotModel

#: A link length (d, a) moved further than this from its nominal value is named (m): several
#: millimetres, beyond the build tolerances of any arm calibrated here.
MOVED_LENGTH_M = 3e-3
#: A joint offset or twist moved further than this is named (rad; about 1.1 degrees).
MOVED_ANGLE_RAD = 0.02
#: ... or, under EB-MAP, further than this many times its group's prior scale (a Gaussian prior
#: puts a parameter there once in 16,000).
MOVED_PRIOR_SCALES = 4.0
#: A prior group whose scale the evidence chose below this (m or rad) was not calibrated.
NOT_CALIBRATED_SCALE = 1e-5
#: The groups of EB-MAP's prior as a user names them, and their parameter kinds.
GROUP_NAMES = {"theta": "joint offsets", "length": "link lengths", "twist": "twists (alpha, beta)"}
GROUP_KINDS = {"theta": ("theta",), "length": ("d", "a"), "twist": ("alpha", "beta")}


def _scales_si(record: dict) -> dict[str, float]:
    """EB-MAP's prior scales by group in SI units (its record gives lengths in mm), {} else."""
    scales = record.get("prior_scales") or {}
    return {g: (t * 1e-3 if g == "length" else t) for g, t in scales.items()}


def parameter_notes(nominal: RobotModel, fit: Fit, record: dict, skip=()) -> list[str]:
    """The notes of :mod:`this module <calib.calibration.estimators.readable>` on ``fit`` (the
    estimate, its free parameters and covariance) against ``nominal`` (the model the calibration
    started from), ``record`` the estimator's (EB-MAP's prior scales and the groups it pinned);
    ``skip``: names another note already names (far from the URDF)."""
    notes = []
    scales = _scales_si(record)
    quiet = [g for g, t in scales.items() if t < NOT_CALIBRATED_SCALE or g in record.get("pinned", ())]
    for g in quiet:
        unit = "m" if g == "length" else "rad"
        notes.append(f"{GROUP_NAMES[g]} not calibrated: the data do not support them (EB-MAP's evidence held "
                     f"their prior scale at {scales[g]:.3g} {unit}, so they stay at their nominal values)")
    std = dict(zip(fit.free, np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))))
    kind_group = {k: g for g, kinds in GROUP_KINDS.items() for k in kinds}
    moved = []
    for p, a, b in zip(nominal.parameters, nominal.values, fit.model.values):
        if p.name not in std or p.group != "joint" or p.name in skip:
            continue
        if p.kind == "d" and nominal.prismatic[p.joint - 1]:
            continue            # (a slide's offset: any)
        dev = b - a
        if p.unit == "rad":
            dev = (dev + math.pi) % (2 * math.pi) - math.pi
        limit = MOVED_LENGTH_M if p.unit == "m" else MOVED_ANGLE_RAD
        tau = scales.get(kind_group.get(p.kind, ""))
        beyond_prior = tau is not None and tau >= NOT_CALIBRATED_SCALE and abs(dev) > MOVED_PRIOR_SCALES * tau
        if abs(dev) > limit or beyond_prior:
            shown = f"{dev * 1e3:+.3g} mm" if p.unit == "m" else f"{dev:+.3g} rad"
            why = [f"{abs(dev) / std[p.name]:.1f} std"] if std[p.name] > 0 else []
            why += [f"{abs(dev) / tau:.1f} prior scales"] if beyond_prior else []
            moved.append(f"{p.name} {shown}" + (f" ({', '.join(why)})" if why else ""))
    if moved:
        notes.append(f"parameters moved beyond what a robot is built to ({MOVED_LENGTH_M * 1e3:g} mm, "
                     f"{MOVED_ANGLE_RAD:g} rad) or {MOVED_PRIOR_SCALES:g} times their prior scale: "
                     f"{', '.join(moved)}. Such a move stands for an error the model does not hold (unmodelled "
                     f"joint errors, a flexible tool, the instrument) or a tie among parameters more often than "
                     f"for the robot: the calibrated model predicts the poses, but read these values with care")
    return notes


def tied_length_notes(robot: RobotModel, Q: np.ndarray, measure: str, weights: tuple[float, float],
                      targets: np.ndarray | None, free) -> list[str]:
    """A note naming the link lengths that the identifiable set ``free`` (frames' offsets first:
    :func:`identifiable_set`) holds at their nominal values because a frame offset is tied to
    them and takes their share, where the structural parameters first would have freed them
    instead (robot, Q (N, n), measure, weights (m, rad), targets: as for the identifiable set)."""
    lengths = {p.name for p in robot.parameters if p.group == "joint" and p.unit == "m"
               and not (p.kind == "d" and robot.prismatic[p.joint - 1])}
    held = lengths - set(free)
    if not held:
        return []
    structural_first = identifiable_names(robot, Q, measure=measure, sigma_pos=weights[0], sigma_rot=weights[1],
                                          targets=targets)
    tied = [n for n in robot.names if n in held and n in structural_first]
    if not tied:
        return []
    return [f"link lengths tied to a frame offset held at their nominal values, the frame taking their "
            f"share (the calibrated lengths read as the robot's): {', '.join(tied)} (the data cannot tell "
            f"them from the base and tool frames' offsets, which carry the difference: the written base "
            f"and tool joints, not the arm's own links)"]
