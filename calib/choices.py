"""The names (and one default) that calib's options take, in one module without imports: the
library validates against them and the command line offers them as choices, so that building
the parser (``calib --help``) loads neither numpy nor Pinocchio."""

#: Identification methods (:func:`calib.solvers.dispatch.solve`).
METHODS = ("search-lm", "c-lm", "lm")
#: "calib": calib's LM (:mod:`calib.solvers.lm`); "paper": Eq. (27)-(28) as printed (:mod:`calib.solvers.paper_lm`).
LM_VARIANTS = ("calib", "paper")
#: Losses on each pose's whitened residual (:class:`calib.solvers.problem.Problem`).
LOSSES = ("linear", "huber", "soft_l1")
#: How a joint file and a tracker file are joined (:mod:`calib.io.csv.join`), and the units of a
#: time column (``--time-unit``).
JOINS = ("key", "nearest-time")
TIME_UNITS = ("s", "ms", "us", "ns")
#: Estimators of :func:`calib.calibrate` (:mod:`calib.calibration.options`).
ESTIMATORS = ("auto", "map", "ls")
#: The features a touch row names, each its column (:mod:`calib.model.touch`, :mod:`calib.io.csv.touch`);
#: ``calib simulate --constraint`` takes them too.
FEATURE_KINDS = ("point", "plane", "sphere")
#: Pose-selection criteria (:mod:`calib.design.poses`).
POSE_CRITERIA = ("D", "O1", "O4")
#: Compensation: a configuration whose smallest singular value of the scaled pose Jacobian is
#: below this is singular (:mod:`calib.compensation.compensate`).
SINGULAR_THRESHOLD = 1e-2
#: Formats of ``calib export`` (:func:`calib.io.exports.export.export_calibration`).
EXPORT_FORMATS = ("ur-yaml", "joint-origins-yaml", "mdh-csv")
#: Universal Robots types whose joint limits calib holds (``--ur-type``;
#: :data:`calib.io.urdf.ur_description.JOINT_LIMITS`: ur_description's config/<type>/joint_limits.yaml).
UR_TYPES = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e", "ur20", "ur30")
#: How the joints are taken at an instrument stamp of a ROS bag (:mod:`calib.io.bag.rows`, ``--joint-sampling``).
BAG_SAMPLINGS = ("linear", "nearest")
