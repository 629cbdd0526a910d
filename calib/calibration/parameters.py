"""The parameter-set choice: the identifiable set, the named sets, the nested candidate sets of
model selection, and the compliance filter.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from calib.calibration.accuracy import target_rows
from calib.calibration.options import PAPER_EXCLUDED, PARAM_SETS
from calib.calibration.prepare import Setup
from calib.errors import ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, analyze_identifiability
from calib.model.robot import RobotModel


# ---------------------------------------------------------------- parameter sets
def _idealised(robot: RobotModel) -> RobotModel:
    """The model with its small deviations removed: angles within 0.05 rad of a multiple of pi/2
    and lengths within 1 mm of zero snapped there. Which parameters tie to which is decided on
    this model, so that it does not depend on where a perturbed model happens to be linearised."""
    v = robot.values
    angle = np.array([p.unit == "rad" for p in robot.parameters], bool)
    snapped = np.where(angle, np.round(v / (math.pi / 2)) * (math.pi / 2), 0.0)
    near = np.abs(v - snapped) < np.where(angle, 0.05, 1e-3)
    return robot.with_values(np.where(near, snapped, v))


def _set_rank_deficit(setup: Setup, free: Sequence[str], weights: tuple[float, float]) -> int:
    """How many directions the parameter set ``free`` leaves undetermined at the start model on
    the calibration rows: its size minus the identifiable parameters a greedy selection with
    ``free`` first keeps (a maximal independent part of it)."""
    kept = set(analyze_identifiability(setup.start, setup.cal.q, measure=setup.measure, sigma_pos=weights[0],
                                       sigma_rot=weights[1], priority=free,
                                       targets=target_rows(setup.start, setup.cal)).identifiable)
    return len(free) - sum(name in kept for name in free)


def identifiable_set(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                     sigma_rot: float = SIGMA_ROT_RAD, targets: np.ndarray | None = None) -> tuple[str, ...]:
    """The identifiable parameter names at configurations Q (N, n) (see
    :func:`calib.model.identifiability.analyze_identifiability`), chosen start-independently: the
    partners to hold fixed are picked on the idealised model (:func:`_idealised`) and kept when
    they are also a valid choice at ``robot``; the rank is ``robot``'s. targets: (N,) each
    row's target index for a multi-target model.

    With several targets, their v parameters come first in the priority: the last joint's
    parameters they are tied to are held instead (a rigid motion of the flange that every
    target's v absorbs exactly), never coordinates of single targets (a gauge that turns singular
    as the fit moves)."""
    first = [p.name for p in robot.parameters if p.group == "v"] if robot.targets else None
    ideal = analyze_identifiability(_idealised(robot), Q, measure=measure, sigma_pos=sigma_pos,
                                    sigma_rot=sigma_rot, targets=targets, priority=first).identifiable
    return analyze_identifiability(robot, Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                                   priority=ideal, targets=targets).identifiable


def select_parameters(robot: RobotModel, params, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                      sigma_rot: float = SIGMA_ROT_RAD,
                      targets: np.ndarray | None = None) -> tuple[str, tuple[str, ...]]:
    """(set label, free parameter names) for a ``params`` choice other than "auto"; see
    :func:`calibrate`."""
    if isinstance(params, str):
        key = params.strip().lower()
        if key == "base":
            return "base", identifiable_set(robot, Q, measure, sigma_pos, sigma_rot, targets)
        if key == "paper":
            return "paper", tuple(p.name for p in robot.parameters
                                  if p.name.split("@")[0] not in PAPER_EXCLUDED)
        if key == "all":
            return "all", robot.names
        names = [s.strip() for s in params.split(",") if s.strip()]
        if not names:
            raise ParameterError(f"empty parameter list {params!r}: expected {', '.join(PARAM_SETS)} "
                                 f"or a comma-separated list of parameter names")
        if len(names) == 1 and names[0] not in robot.names:
            raise ParameterError(f"unknown parameter set {params!r}: expected {', '.join(PARAM_SETS)} or a "
                                 f"comma-separated list of parameter names ({', '.join(robot.names)})")
        params = names
    if isinstance(params, (bytes, dict)) or not hasattr(params, "__iter__"):
        raise ParameterError(f"params must be a set name or a list of parameter names, got {params!r}")
    names = tuple(params)
    if not names:
        raise ParameterError("params is an empty list: name at least one parameter")
    if not all(isinstance(n, str) for n in names):
        raise ParameterError(f"params must be parameter names (strings), got {params!r}")
    robot.indices(names)  # raises ParameterError for unknown names
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise ParameterError(f"parameter listed twice: {', '.join(twice)}")
    return "list", tuple(n for n in robot.names if n in names)


def candidate_sets(robot: RobotModel, identifiable: Sequence[str]) -> list[tuple[str, tuple[str, ...]]]:
    """Nested parameter sets for ``params="auto"``, smallest first, each within the identifiable
    set: joint offsets (theta, or d of a prismatic joint) with the measurement and tool frames;
    + lengths (d, a); + twists (alpha, beta); the whole identifiable set. Duplicates dropped."""
    ident = set(identifiable)

    def offset(p) -> bool:
        if p.group != "joint":
            return False
        prismatic = robot.joints[p.joint - 1].is_prismatic
        return p.kind == ("d" if prismatic else "theta")

    steps = [("offsets+frames", lambda p: p.group in ("u", "v", "compliance") or offset(p)),
             ("+lengths", lambda p: p.kind in ("d", "a")),
             ("+twists", lambda p: p.kind in ("alpha", "beta"))]
    out, chosen = [], set()
    for label, pick in steps:
        chosen |= {p.name for p in robot.parameters if pick(p)}
        names = tuple(n for n in robot.names if n in chosen and n in ident)
        if names and (not out or names != out[-1][1]) and set(names) != ident:
            out.append((label, names))
    out.append(("identifiable set", tuple(n for n in robot.names if n in ident)))
    return out


def _compliance_filter(robot: RobotModel, free: Sequence[str], compliance: bool,
                       notes: list) -> tuple[str, ...]:
    """``free`` without the compliance parameters unless ``compliance``; with it, a note naming
    the compliances not in ``free`` (the identifiable set leaves out those the data cannot see)."""
    comp = set(robot.compliance_names)
    if not comp:
        return tuple(free)
    if not compliance:
        return tuple(n for n in free if n not in comp)
    unseen = [n for n in robot.compliance_names if n not in free]
    note = (f"compliance not identifiable from these poses (no gravity torque, or tied to "
            f"the geometry), held at its value: {', '.join(unseen)}")
    if unseen and note not in notes:
        notes.append(note)
    return tuple(free)
