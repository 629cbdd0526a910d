"""The identifiability report: which parameters the measurements identify, how the others are
tied to them, and the observability indices (:func:`analyze_identifiability`,
:class:`IdentifiabilityReport`). The method is described in :mod:`calib.model.identifiability`,
which holds the selection alone (what every calibration needs) and the cache of both.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from calib.model.identifiability import (RANK_TOL, SIGMA_POS_M, SIGMA_ROT_RAD, ANALYSES, analysis_key, checked_rows,
                                         no_effect, observability_indices, select_identifiable,
                                         weighted_jacobian)
from calib.model.robot import RobotModel


@dataclass(frozen=True)
class Relation:
    """An unidentifiable parameter and the identifiable ones it is tied to.

    ``partners``: (name, coefficient) pairs, coefficients in physical units
    (metres per metre, metres per radian, ...): a change ``delta`` of ``parameter`` moves the
    measurements as changes ``coefficient * delta`` of the partners would. Empty when the
    parameter has no effect at all on the measured quantities.
    """

    parameter: str
    partners: tuple[tuple[str, float], ...]
    reason: str

    def describe(self) -> str:
        if not self.partners:
            return f"{self.parameter}: {self.reason}"
        terms = " ".join(f"{c:+.4g}*{n}" for n, c in self.partners)
        return f"{self.parameter} ~ {terms}"


@dataclass(frozen=True)
class IdentifiabilityReport:
    """Result of :func:`analyze_identifiability`. Names follow ``robot.parameters``."""

    measure: str
    n_poses: int
    n_params: int
    rank: int
    identifiable: tuple[str, ...]
    unidentifiable: tuple[Relation, ...]
    singular_values: np.ndarray = field(repr=False)
    condition_number: float
    O1: float
    O3: float
    O4: float
    tol: float
    sigma_pos: float
    sigma_rot: float

    def to_dict(self) -> dict:
        """A JSON-ready dict (keys n_params, rank, identifiable, unidentifiable, condition_number...)."""
        return {
            "measure": self.measure,
            "n_poses": self.n_poses,
            "n_params": self.n_params,
            "rank": self.rank,
            "identifiable": list(self.identifiable),
            "unidentifiable": [
                {"name": r.parameter, "tied_to": [{"name": n, "coefficient": c} for n, c in r.partners],
                 "reason": r.reason} for r in self.unidentifiable],
            "condition_number": self.condition_number,
            "observability": {"O1": self.O1, "O3": self.O3, "O4": self.O4},
            "singular_values": [float(s) for s in self.singular_values],
            "tolerance": self.tol,
            "sigma_pos_m": self.sigma_pos,
            "sigma_rot_rad": self.sigma_rot,
        }

    def to_json(self) -> str:
        import json

        return json.dumps(self.to_dict(), indent=2)

    def format(self) -> str:
        """A report for a person."""
        lines = [f"Identifiability ({self.measure} data, {self.n_poses} poses): rank {self.rank} of "
                 f"{self.n_params} parameters",
                 f"identifiable ({len(self.identifiable)}): {', '.join(self.identifiable)}",
                 f"unidentifiable ({len(self.unidentifiable)}):"]
        lines += [f"  {r.describe()}" + ("" if not r.partners else f"   ({r.reason})")
                  for r in self.unidentifiable]
        lines += [f"condition number {self.condition_number:.4g}   "
                  f"(noise-weighted rows: sigma_pos {self.sigma_pos * 1e3:g} mm, sigma_rot "
                  f"{self.sigma_rot:g} rad; unit-norm columns)",
                  f"observability O1 {self.O1:.4g}   O3 {self.O3:.4g}   O4 {self.O4:.4g}"]
        return "\n".join(lines)


def analyze_identifiability(robot: RobotModel, Q: np.ndarray | None = None, *, measure: str = "pose",
                            n_poses: int = 100, seed: int | None = 0, tol: float = RANK_TOL,
                            sigma_pos: float = SIGMA_POS_M, sigma_rot: float = SIGMA_ROT_RAD,
                            priority: Sequence[str] | None = None,
                            max_poses: int | None = 500,
                            targets: np.ndarray | None = None) -> IdentifiabilityReport:
    """Identifiable parameter set, relations and observability of ``robot``'s parameters.

    Parameters
    ----------
    robot : the model, linearised at its current values.
    Q : (N, n) configurations (rad / m); default ``n_poses`` uniform random ones within the
        joint limits drawn with ``seed``.
    measure : "pose" (position and orientation) or "position".
    tol : relative tolerance of the rank decision (see the module docstring).
    sigma_pos, sigma_rot : noise for row weighting, metres and radians.
    priority : parameter names in the order in which they should be kept (default: Eq. 23 order);
        names not listed follow in the default order.
    max_poses : analyse at most this many of the configurations (an evenly spaced subset): which
        parameters are tied does not depend on the number of poses once there are a few dozen,
        and the cost grows with it. None for all.
    targets : (N,) int, the target index (into ``robot.targets``) measured at each configuration;
        default for a multi-target model: every target at every configuration (``n_poses`` counts
        the rows).

    The reports of the last ``CACHE_SIZE`` analyses are kept: a repeated call with the same
    model values, configurations and options (as a calibration repeated on the same data makes)
    returns the same report without recomputing it.
    """
    Q, targets = checked_rows(robot, Q, measure, n_poses, seed, tol, sigma_pos, sigma_rot, priority, max_poses,
                               targets)
    key = analysis_key(robot, Q, measure, tol, sigma_pos, sigma_rot, priority, targets)
    return ANALYSES.kept(key, lambda: _analyze(robot, Q, measure, tol, sigma_pos, sigma_rot, priority, targets))


def _analyze(robot: RobotModel, Q: np.ndarray, measure: str, tol: float, sigma_pos: float,
             sigma_rot: float, priority, targets) -> IdentifiabilityReport:
    J = weighted_jacobian(robot, Q, measure, sigma_pos, sigma_rot, targets)
    order = list(robot.indices(priority)) if priority else []
    order += [k for k in range(robot.n_params) if k not in order]
    kept, dropped = select_identifiable(J, order, tol)

    relations = []
    norms = np.linalg.norm(J, axis=0)
    pose_norms = None
    for j in dropped:
        if no_effect(norms, j):
            reason = "no effect on the measured quantities at these configurations"
            if measure == "position":
                if pose_norms is None:
                    pose_norms = np.linalg.norm(
                        weighted_jacobian(robot, Q, "pose", sigma_pos, sigma_rot, targets), axis=0)
                if not no_effect(pose_norms, j):
                    reason = ("rotates the tool about the tool point only: observable with "
                              "orientation data, not with positions")
            relations.append(Relation(robot.names[j], (), reason))
            continue
        coef, *_ = np.linalg.lstsq(J[:, kept], J[:, j], rcond=None)
        scale = np.linalg.norm(J[:, kept], axis=0) / np.linalg.norm(J[:, j])
        partners = tuple((robot.names[k], float(c)) for k, c, s in zip(kept, coef, scale)
                         if abs(c * s) > 1e-4)
        relations.append(Relation(robot.names[j], partners,
                                  "its effect equals that of the listed parameters"))

    Jk = J[:, kept] / np.linalg.norm(J[:, kept], axis=0)
    idx = observability_indices(Jk)
    idx["singular_values"].setflags(write=False)   # the report is shared through the cache
    return IdentifiabilityReport(
        measure=measure, n_poses=len(Q), n_params=robot.n_params, rank=len(kept),
        identifiable=tuple(robot.names[k] for k in sorted(kept)),
        unidentifiable=tuple(relations), singular_values=idx["singular_values"],
        condition_number=idx["condition_number"], O1=idx["O1"], O3=idx["O3"], O4=idx["O4"],
        tol=tol, sigma_pos=sigma_pos, sigma_rot=sigma_rot)
