"""One entry point to the solvers: :func:`solve` runs a method on a weighted residual problem.

The method names are those of :func:`calib.calibrate`: ``"lm"`` (:func:`calib.solvers.lm.levenberg_marquardt`),
``"c-lm"`` (:func:`calib.solvers.schemes.cross_lm`, the paper's cross-identification scheme) and
``"search-lm"`` (:func:`calib.solvers.schemes.search_lm`, the closed-form angle search then LM).
``variant="paper"`` runs the paper's LM of Eq. (27)-(28) as printed instead of calib's
(:mod:`calib.solvers.paper_lm`; methods "lm" and "c-lm").

Which method a calibration runs (position-only data, several targets, re-fits from a near
solution) is the caller's decision; this module only dispatches.
"""
from __future__ import annotations

import numpy as np

from calib.choices import LM_VARIANTS as VARIANTS, METHODS
from calib.solvers.lm import LMOptions, LMTrace, levenberg_marquardt
from calib.solvers.problem import Problem
from calib.solvers.schemes import cross_lm, search_lm

#: The methods :func:`solve` runs (METHODS) and its LM variants (VARIANTS): :mod:`calib.choices`.


def solve(problem: Problem, x0: np.ndarray, method: str, *, angular: np.ndarray | None = None,
          chain=None, options: LMOptions = LMOptions(), trace: LMTrace | None = None,
          max_rounds: int = 20, fixed_rounds: int | None = None, max_escapes: int | None = None,
          variant: str = "calib", paper_options=None, translation: str = "differential"):
    """Minimise ``problem`` from ``x0`` with ``method``.

    Parameters
    ----------
    problem : the weighted residual problem; x0 : (m,) start values of its free parameters, SI
        units (metres, radians), in the order of ``problem.free``.
    method : "lm", "c-lm" or "search-lm" (see the module docstring).
    angular : (m,) bool, which free parameters are angles (needed by "c-lm", "search-lm" and the
        paper's LM). chain : the :class:`calib.solvers.angles.RotationChain` of the problem's
        model ("search-lm" only).
    options, trace : calib's LM options and iteration trace (variant "calib").
    max_rounds, fixed_rounds : C-LM rounds at most, or exactly ``fixed_rounds``.
    max_escapes : "search-lm": angle searches from an LM solution above the noise level at most
        (None: the scheme's default).
    variant : "calib" or "paper"; paper_options : the :class:`calib.solvers.paper_lm.PaperLMOptions`
        of the paper's LM; translation : its translation rows for plain LM ("differential" or
        "position").

    Returns a :class:`calib.solvers.lm.SolverResult` (variant "calib") or a
    :class:`calib.solvers.paper_lm.PaperLMResult` (variant "paper": its cost is the paper's
    unweighted 1/2 |Delta P|^2 in mm and rad). Raises ValueError for an unknown method or variant.
    """
    if variant == "paper":
        from calib.solvers.paper_lm import PaperLMOptions, paper_cross_lm, paper_lm

        popts = paper_options if paper_options is not None else PaperLMOptions()
        if method == "lm":
            return paper_lm(problem, x0, angular, options=popts, translation=translation)
        if method == "c-lm":
            return paper_cross_lm(problem, x0, angular, options=popts, max_rounds=max_rounds,
                                  fixed_rounds=fixed_rounds)
        raise ValueError(f"the paper's LM runs methods 'lm' and 'c-lm', not {method!r}")
    if variant != "calib":
        raise ValueError(f"unknown variant {variant!r}: expected one of {', '.join(VARIANTS)}")
    if method == "lm":
        return levenberg_marquardt(problem, x0, "pose", options, trace)
    if method == "c-lm":
        return cross_lm(problem, x0, angular, max_rounds=max_rounds, fixed_rounds=fixed_rounds,
                        options=options, trace=trace)
    if method == "search-lm":
        extra = {} if max_escapes is None else {"max_escapes": max_escapes}
        return search_lm(problem, x0, angular, chain, options=options, trace=trace, **extra)
    raise ValueError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")


__all__ = ["METHODS", "VARIANTS", "solve"]
