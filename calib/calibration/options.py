"""The options of :func:`calib.calibration.pipeline.calibrate`: the method and parameter-set names, the
thresholds the stages use, and the checks of every option before any work.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from calib.checks import check_int, check_number
from calib.choices import ESTIMATORS as _ESTIMATORS, LM_VARIANTS as _VARIANTS, LOSSES, METHODS as _METHODS
from calib.errors import DataError, ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.measurements import Measurements
from calib.model.measurements import is_touch_data
from calib.model.robot import RobotModel
from calib.solvers.lm import LMOptions

#: The methods (:data:`calib.solvers.dispatch.METHODS`) and LM variants ("calib": calib's LM; "paper":
#: Eq. (27)-(28) as printed, :mod:`calib.solvers.paper_lm`) that calibrate runs.
METHODS = _METHODS
LM_VARIANTS = _VARIANTS
PARAM_SETS = ("base", "paper", "all", "auto")
#: The estimators of calibrate: "auto" (the default: "map" for data that do not swamp the model,
#: least squares on the identifiable set for data that do), "map" (EB-MAP,
#: :mod:`calib.calibration.estimators.regularised`), "ls" (least squares on a parameter set).
ESTIMATORS = _ESTIMATORS
#: Parameters that Section 4.2 of the paper leaves out when the frames are well known.
PAPER_EXCLUDED = ("u_z", "u_alpha", "v_x", "v_z", "v_alpha", "v_gamma")
#: The closed-form frame estimate replaces the nominal frames beyond these distances.
FRAME_REBASE_M = 0.010
FRAME_REBASE_RAD = 0.02
#: Without ``params``, model selection ("auto") is used when the calibration rows hold fewer
#: residual components per identifiable parameter than this (scripts/bench_holdout.py).
AUTO_BELOW_COMPONENTS_PER_PARAM = 10.0
#: Variance-component estimation: at most this many re-weighted fits, stopping when both noise
#: levels change by less than VCE_RTOL.
VCE_MAX_ITERATIONS = 12
VCE_RTOL = 1e-3
#: The first fit of a noise estimate only places the residuals the estimate is made from: it
#: stops when an iteration lowers the cost by less than this fraction (the noise levels it
#: yields are then exact to ~1e-6, far inside VCE_RTOL); the re-weighted fits converge fully.
VCE_FIRST_FTOL = 1e-5
#: Damping at the start of a re-fit from a solution of the same rows (re-weighted, rows
#: removed): the solution is near, and the default start (LMOptions.mu0) would only slow the
#: first steps down; a rejected step raises it as usual.
WARM_MU0 = 1e-6
#: Damping at the start of a fit from a Gauss-Newton step of the same model on the same rows
#: (fit_stage's ``warm``: the joint terms' choice linearised the chosen model at the geometric
#: solution and stepped to where its own noise levels put it): the re-fit's WARM_MU0 shortened
#: that first step along the weakly determined terms, and the 1,402 real iiwa rows took one
#: iteration (a Jacobian pass of 68 parameters) more.
STEP_START_MU0 = 1e-8
#: An explicit lm / c-lm fit is called a local minimum when an angle search from it, then LM,
#: reaches a cost below this fraction of its own.
LOCAL_MINIMUM_RATIO = 0.9
#: Measured positions farther than the robot's reach plus this from the measurement frame's
#: origin are refused (wrong units or gross errors): the longest-range laser trackers measure
#: to 160 m (Leica AT403, 320 m diameter), so 200 m bounds any tracker or camera set-up.
TRACKER_RANGE_M = 200.0
#: Below this many residual components per free parameter (a mean leverage above 10 %), the
#: outlier check always judges the rows against a robust (Huber) fit: a least-squares fit of
#: few rows spreads gross errors over the others and inflates the noise estimate until none
#: stands out (2 rows 4 mm off among 25 position-only UR10 rows of 0.05 mm noise, 2.8
#: components per parameter: the fit's true error was 0.81 mm RMS, 0.053 mm without them).
#: Above it a gross row keeps most of its residual and the least-squares residuals suffice (the
#: robust fit, ~70 Huber LM iterations, would cost 60 % more per calibration at 100 full poses).
ROBUST_CHECK_BELOW_COMPONENTS_PER_PARAM = 10
#: The robust fit of the outlier check and the noise levels of its residuals are iterated at
#: most this many times (until the levels change by less than 10 %).
ROBUST_CHECK_ITERATIONS = 3
#: The fits of the outlier check (the Huber fit, the trimmed fit's concentration steps and its
#: refits of the inliers) stop when an iteration lowers the cost by less than this fraction:
#: they only say which rows lie beyond outlier_k sigma and at what noise (the least-squares
#: refit without the flagged rows converges fully), and the Huber iterations converge linearly
#: (the real iiwa rows: 6 passes at 1e-12, each changing the residuals by 1e-7 of their size).
ROBUST_CHECK_FTOL = 1e-6
#: Above that, a least-squares noise level more than this factor above the robust one (1.4826
#: MAD of the residual components at the least-squares fit) in either group means many gross
#: rows: a least-squares fit spread over 20-40 % of rows 5 mm off leaves none of them above the
#: threshold (100 full poses of 0.02 mm noise: noise estimated 1.3-1.8 mm, 0.5-1 mm off the
#: truth, none flagged), and the rows are judged against a trimmed fit instead. Clean simulated
#: data give about 0.9-1.1, real motion-capture data (examples/tiago_qualisys) 1.2, 5-40 % of
#: rows 5 mm off about 2-4; clean data never pay for the trimmed fit.
ROBUST_CHECK_INFLATION = 1.5
#: The trimmed fit (least trimmed squares by concentration steps: the least-squares fit of the
#: half of the rows it explains best, repeated until that half stops changing) takes at most
#: this many steps.
TRIMMED_FIT_STEPS = 10
#: Rows flagged against the trimmed fit are outliers up to this share of the kept rows (its
#: breakdown point); against the other fits, up to a quarter (more mean noise levels too small).
TRIMMED_MAX_OUTLIER_SHARE = 0.5
#: Joint readings that agree to this (rad / m) are one configuration when counting distinct poses.
DISTINCT_Q_TOL = 1e-9
#: Residual components beyond the number of free parameters needed to estimate the noise.
MIN_REDUNDANCY = 6
#: Default number of cross-validation folds.
CV_FOLDS = 5
#: Model selection cross-validates leave-one-out below this many calibration rows.
LOO_BELOW_ROWS = 80


def _check_touch_options(opts: CalibrationOptions, data, validation) -> None:
    """Refuse the options a calibration from touch data does not take (least squares by LM,
    geometry only, the parameter sets "auto" and "tool"), naming the option."""
    defaults = (("method", ("search-lm", "lm")), ("loss", ("linear",)), ("estimator", ("auto", "ls")),
                ("compliance", (False,)), ("periodic", (False,)), ("lm_variant", ("calib",)))
    for name, allowed in defaults:
        if getattr(opts, name) not in allowed:
            raise ParameterError(f"{name} {getattr(opts, name)!r} does not apply to touch data (least squares by "
                                 f"LM of the geometry; {name} {allowed[0]!r})")
    if validation is not None:
        raise ParameterError("validation does not apply to touch data (their held-out error is cross-validated)")
    if opts.init_frames is False:
        raise ParameterError("init_frames=False does not apply to touch data (their meas frame starts at the "
                             "measured rows' registration; without measured rows it stays nominal)")
    if opts.params is not None and not (isinstance(opts.params, str) and opts.params in ("auto", "tool")):
        raise ParameterError(f"params for touch data: 'auto' or 'tool', got {opts.params!r:.60}")
    m = data.measured
    if opts.sigma_rot is not None and (m is None or m.rotation is None):
        raise ParameterError("sigma_rot weights measured orientations; these touch data have none")
    if opts.sigma_pos is not None and m is None:
        raise ParameterError("sigma_pos weights measured positions; these touch data have none (the touch "
                             "noise is sigma_touch)")


# ====================================================================== stages
def check_compatible(robot: RobotModel, m: Measurements) -> None:
    if m.n_joints != robot.n_joints:
        raise DataError(f"the measurements have {m.n_joints} joint values per pose, the robot "
                        f"{robot.n_joints} joints ({', '.join(robot.joint_names)})")


@dataclass(frozen=True, eq=False, repr=False)     # (checked once, passed down: nothing compares, hashes or prints them)
class CalibrationOptions:
    """The options of :func:`calib.calibrate`, checked once (:func:`resolve_options`); see its
    docstring for each. sigma_pos (m) / sigma_rot (rad) / sigma_touch (m, touch rows): given
    noise levels, None to estimate. method is lower-case; lm is the LM's options (defaults when
    none were given). nominal_scale : touch data with no known length: the scale held nominal."""

    method: str
    params: str | Sequence[str] | None
    sigma_pos: float | None
    sigma_rot: float | None
    init_frames: bool | str
    max_rounds: int
    fixed_rounds: int | None
    lm: LMOptions
    loss: str
    loss_scale: float
    outlier_k: float | None
    cv: int | None
    compliance: bool
    lm_variant: str
    estimator: str = "auto"
    periodic: bool = False
    sigma_touch: float | None = None
    nominal_scale: bool = False

    @property
    def map_clash(self) -> str | None:
        """The option that keeps the regularised estimator (EB-MAP) from these options, as the
        error message names it; None when it applies (estimator "auto" then chooses it on few
        rows, "map" always)."""
        if self.params is not None:
            return ("params (a least-squares parameter set; the MAP estimate frees every structural "
                    "parameter under its prior)")
        if self.loss != "linear":
            return f"loss {self.loss!r} (MAP is least squares with a prior)"
        if self.lm_variant == "paper":
            return "lm_variant 'paper'"
        if self.compliance or self.periodic:
            return "compliance or periodic terms (they have no prior group yet)"
        return None

    @property
    def folds(self) -> int:
        """Cross-validation folds (0: off)."""
        return CV_FOLDS if self.cv is None else self.cv

    @property
    def weights(self) -> tuple[float, float]:
        """(position m, rotation rad) noise levels that weight the identifiability analysis:
        the given ones, else the defaults of :mod:`calib.model.identifiability`."""
        return self.sigma_pos or SIGMA_POS_M, self.sigma_rot or SIGMA_ROT_RAD


def resolve_options(robot, measurements, validation=None, *, method="search-lm", params=None, sigma_pos=None,
                    sigma_rot=None, init_frames="auto", max_rounds=20, fixed_rounds=None, options=None,
                    loss="linear", loss_scale=3.0, outlier_k=5.0, cv=None, compliance=False,
                    lm_variant="calib", estimator="auto", periodic=False, sigma_touch=None,
                    nominal_scale=False) -> CalibrationOptions:
    """Every option of :func:`calib.calibrate` and the types of its inputs checked before any work
    (as scipy's least_squares does), each error naming the option; the frozen options. Touch data
    (:class:`calib.model.touch.TouchData`) take the options of :func:`_check_touch_options`."""
    if not isinstance(method, str) or method.lower() not in METHODS:
        raise ParameterError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    check_number(sigma_pos, "sigma_pos", minimum=0.0, strict=True, allow_none=True)
    check_number(sigma_rot, "sigma_rot", minimum=0.0, strict=True, allow_none=True)
    for value, name in ((sigma_pos, "sigma_pos"), (sigma_rot, "sigma_rot")):
        if value is not None and not 1e-12 <= value <= 1.0:
            raise ParameterError(f"{name} must be between 1e-12 and 1 (metres / radians), got {value!r}")
    if not isinstance(init_frames, (bool, str)) or init_frames not in (True, False, "auto"):
        raise ParameterError(f"init_frames must be True, False or 'auto', got {init_frames!r}")
    check_int(max_rounds, "max_rounds", minimum=1)
    check_int(fixed_rounds, "fixed_rounds", minimum=1, allow_none=True)
    if not isinstance(loss, str) or loss not in LOSSES:
        raise ParameterError(f"unknown loss {loss!r}: expected one of {', '.join(LOSSES)}")
    check_number(loss_scale, "loss_scale", minimum=0.0, strict=True)
    check_number(outlier_k, "outlier_k", minimum=0.0, strict=True, allow_none=True)
    if cv is not None and (isinstance(cv, bool) or not isinstance(cv, (int, np.integer)) or cv < 0 or cv == 1):
        raise ParameterError(f"cv must be 0 (off) or a number of folds >= 2, got {cv!r}")
    method = method.lower()
    if not isinstance(lm_variant, str) or lm_variant not in LM_VARIANTS:
        raise ParameterError(f"unknown lm_variant {lm_variant!r}: expected one of {', '.join(LM_VARIANTS)}")
    if lm_variant == "paper" and method == "search-lm":
        raise ParameterError("lm_variant 'paper' is the paper's LM for methods 'lm' and 'c-lm'; "
                             "search-lm runs calib's LM")
    if lm_variant == "paper" and loss != "linear":
        raise ParameterError("lm_variant 'paper' fits unweighted least squares: loss must be 'linear'")
    if options is not None and not isinstance(options, LMOptions):
        raise ParameterError(f"options must be an LMOptions, got {type(options).__name__}")
    if not isinstance(robot, RobotModel):
        raise ParameterError(f"robot must be a RobotModel (calib.load_robot), got {type(robot).__name__}")
    touch = is_touch_data(measurements)
    if not isinstance(measurements, Measurements) and not touch:
        raise ParameterError(f"measurements must be a Measurements (calib.read_measurements) or TouchData "
                             f"(calib.read_touch), got {type(measurements).__name__}")
    if validation is not None and not isinstance(validation, Measurements):
        raise ParameterError(f"validation must be a Measurements, got {type(validation).__name__}")
    if not isinstance(compliance, bool):
        raise ParameterError(f"compliance must be True or False, got {compliance!r}")
    if not isinstance(estimator, str) or estimator.lower() not in ESTIMATORS:
        raise ParameterError(f"unknown estimator {estimator!r}: expected one of {', '.join(ESTIMATORS)}")
    estimator = estimator.lower()
    if not isinstance(periodic, bool):
        raise ParameterError(f"periodic must be True or False, got {periodic!r}")
    check_number(sigma_touch, "sigma_touch", minimum=1e-12, maximum=1.0, allow_none=True)
    if not isinstance(nominal_scale, bool):
        raise ParameterError(f"nominal_scale must be True or False, got {nominal_scale!r}")
    opts = CalibrationOptions(method, params, sigma_pos, sigma_rot, init_frames, max_rounds, fixed_rounds,
                              options or LMOptions(), loss, loss_scale, outlier_k, cv, compliance, lm_variant,
                              estimator, periodic, sigma_touch, nominal_scale)
    if touch:
        _check_touch_options(opts, measurements, validation)
        opts = replace(opts, method="lm")       # (LM: the angle search of search-lm takes pose rows)
    elif sigma_touch is not None or nominal_scale:
        raise ParameterError(f"{'sigma_touch' if sigma_touch is not None else 'nominal_scale'} applies to touch "
                             f"data (calib.read_touch), not to measurements")
    if estimator == "map" and opts.map_clash:
        raise ParameterError(f"estimator 'map' cannot be combined with {opts.map_clash}: use estimator 'ls'")
    return opts
