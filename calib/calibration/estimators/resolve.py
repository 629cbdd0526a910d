"""The one place that decides which estimator a calibration runs (:func:`resolve_estimator`)."""
from __future__ import annotations

import numpy as np

from calib.calibration.estimators.base import Estimator
from calib.calibration.estimators.least_squares import LeastSquares
from calib.calibration.options import CalibrationOptions
from calib.calibration.parameters import ParameterChoice
from calib.calibration.prepare import Setup
from calib.calibration.terms import TermsChoice, warm_start


def resolve_estimator(setup: Setup, choice: ParameterChoice, options: CalibrationOptions,
                      terms: TermsChoice | None = None, source=None) -> Estimator:
    """The estimator for the parameter choice ``choice`` (:func:`calib.calibration.parameters.
    choose_parameters`, which decided "map", "auto" or a set from ``options`` and the data):

    * "auto": :class:`~calib.calibration.estimators.selection.SelectBest` over least squares;
    * "map": :class:`~calib.calibration.estimators.regularised.EBMap` (``source``, the
      measurements' file, named in its errors);
    * any other set: :class:`LeastSquares`, started where the joint terms' choice ``terms``
      left the chosen model (a few LM iterations instead of the method's scheme), without the
      rows its geometric fit's outlier check flagged (taken back when the chosen model explains
      them), when the terms were judged and the set is identifiable.

    EB-MAP and model selection are imported only here, when they run (EB-MAP's modules are 4 ms
    of a start-up that does not use them)."""
    if choice.auto:
        from calib.calibration.estimators.selection import SelectBest

        return SelectBest(LeastSquares())
    if choice.label == "map":
        from calib.calibration.estimators.regularised import EBMap

        return EBMap(source)
    if terms is None or choice.deficit:
        return LeastSquares()
    gross = np.isin(setup.cal.rows, terms.outlier_rows)
    suspect = gross if setup.suspect is None else (setup.suspect | gross)
    return LeastSquares(start=warm_start(setup.start, terms.start, choice.free),
                        suspect=suspect if suspect.any() else None)
