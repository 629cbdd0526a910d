"""Likely causes of a calibration that does not describe its data: the common ways a file is
misread, tried on the calibration rows (:func:`misreadings`).

A file with Euler angles of extrinsic ``xyz`` read as ``--euler XYZ``, a rotation vector read
as ZYX or Euler angles (UR's ``rx, ry, rz`` under calib's ``rz, ry, rx``), two joint columns
swapped, joint angles in degrees labelled radians, positions in metres labelled millimetres, or
a quaternion written (x, y, z, w) under (qw, qx, qy, qz) headers gives data that the model fits
badly, but not always beyond the implausibility thresholds (on a UR5: 103-352 mm, status
converged). Each misreading is undone on the calibration rows and the fit stage run again on
the result; when one makes the data fit far better (:data:`MISREADING_GAIN` times smaller noise
estimates, and a plausible fit), the sentence naming it is a reason to refuse the calibration.

The check runs only when the fit is already implausible or its estimated noise is beyond what
instruments of robot calibration give (:data:`SUSPECT_POS_M`, :data:`SUSPECT_ROT_RAD`): clean
data do not pay for it.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from calib.calibration.accuracy.errors import pose_errors, target_rows
from calib.calibration.estimators.base import Fit
from calib.calibration.estimators.least_squares import fit_with
from calib.calibration.plausibility import chain_implausibility, implausibility, length_notes
from calib.calibration.frames import median
from calib.calibration.options import CalibrationOptions
from calib.calibration.prepare import Setup, prepare
from calib.errors import CalibError
from calib.model.measurements import Measurements

#: A misreading is named when undoing it divides the estimated noise (position or orientation,
#: neither growing by more than 20 %) by at least this factor.
MISREADING_GAIN = 5.0
#: Fits with estimated noise above these (or implausible ones) are checked for misreadings:
#: trackers measure to 0.01-0.1 mm, cameras and motion capture to 0.1-2 mm (FIGAROH's TIAGo
#: data: 1.6 mm, checked and found read right).
SUSPECT_POS_M = 0.5e-3
SUSPECT_ROT_RAD = 0.01
#: At most this many screened misreadings are fitted.
MAX_FITS = 2


def _euler_alternatives(m: Measurements, seq: str):
    """(sentence, rotations) for Euler angles read with ``seq`` but written with the sequence
    of the other case (intrinsic <-> extrinsic) or in reverse order."""
    from scipy.spatial.transform import Rotation

    angles = Rotation.from_matrix(m.rotation).as_euler(seq)
    kind = {True: "extrinsic", False: "intrinsic"}
    for other in dict.fromkeys((seq.swapcase(), seq[::-1])):
        if other == seq:
            continue
        yield (f"the Euler angles look written in sequence {other!r} ({kind[other.islower()]}) but were read as "
               f"{seq!r} ({kind[seq.islower()]}): read them with --euler {other}",
               Rotation.from_euler(other, angles).as_matrix())


def _quaternion_alternatives(m: Measurements):
    """(sentence, rotations) for quaternions written (x, y, z, w) or (z, w, x, y) under the
    (qw, qx, qy, qz) headers: the scalar in another column."""
    from scipy.spatial.transform import Rotation

    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    for shift, order in ((1, "x, y, z, w"), (-1, "z, w, x, y")):
        yield (f"the quaternion columns look written in the order ({order}) under headers read as "
               f"(qw, qx, qy, qz): rename the columns", Rotation.from_quat(np.roll(wxyz, shift, axis=1),
                                                                           scalar_first=True).as_matrix())


def _angle_triples(R: np.ndarray, seq: str) -> list[np.ndarray]:
    """The (N, 3) angle triples of sequence ``seq`` that a file may have held for rotations R:
    scipy's (middle angle within [-pi/2, pi/2] for three distinct axes, [0, pi] otherwise) and
    the other solution, wrapped to (-pi, pi] (a rotation vector's components can be beyond
    scipy's range, each within [-pi, pi])."""
    import warnings

    from scipy.spatial.transform import Rotation

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # gimbal lock: any split is as good
        a = Rotation.from_matrix(R).as_euler(seq)
    tait_bryan = len(set(seq.lower())) == 3
    b = a + np.array([math.pi, math.pi, math.pi]) if not tait_bryan else a.copy()
    if tait_bryan:
        b[:, 0] += math.pi
        b[:, 1] = math.pi - a[:, 1]
        b[:, 2] += math.pi
    else:
        b[:, 1] = -a[:, 1]
    b = (b + math.pi) % (2 * math.pi) - math.pi
    return [a, b]


def _rotvec_alternatives(m: Measurements):
    """(sentence, rotations) for a rotation vector (UR's rx, ry, rz: axis times angle) read as
    ZYX angles (columns rz, ry, rx) or as Euler angles (e1, e2, e3): the values of the columns
    recovered from the rotations as read (both angle solutions), taken as a rotation vector
    in the columns' x, y, z order."""
    from calib.model.spatial import rotation_from_rotvec

    if m.orientation == "zyx":
        seq, order, read_as = "ZYX", [2, 1, 0], "ZYX angles (rz, ry, rx)"
    else:
        seq = m.orientation.split(":", 1)[1]
        order, read_as = [0, 1, 2], f"Euler angles {seq!r} (e1, e2, e3)"
    for triple in _angle_triples(m.rotation, seq):
        yield (f"the orientation columns look like a rotation vector (axis times angle, as UR's rx, ry, rz) "
               f"but were read as {read_as}: read them with --convention ur, or name them rvx, rvy, rvz",
               rotation_from_rotvec(triple[:, order]))


def alternatives(m: Measurements, conventions: bool = False):
    """(sentence, measurements, length scale) for each common misreading of ``m`` undone: the
    orientation (by how it was read: :attr:`Measurements.orientation`), two joint columns of the
    same kind swapped, with ``conventions`` a revolute joint counted the other way (another
    convention's sign) or from another zero (+-90, 180 degrees), revolute joint units (degrees <->
    radians), position units (metres <-> mm; the length scale is the factor the positions were
    multiplied by, else 1)."""
    if m.rotation is not None and m.orientation is not None:
        rot = []
        if m.orientation.startswith("euler:"):
            rot = list(_euler_alternatives(m, m.orientation.split(":", 1)[1])) + \
                list(_rotvec_alternatives(m))
        elif m.orientation == "zyx":
            rot = _rotvec_alternatives(m)
        elif m.orientation == "quaternion":
            rot = _quaternion_alternatives(m)
        for sentence, R in rot:
            yield sentence, replace(m, rotation=R), 1.0
    names, pr = m.joint_names, m.prismatic
    for i in range(m.n_joints):
        for j in range(i + 1, m.n_joints):
            if pr[i] == pr[j]:
                q = m.q.copy()
                q[:, [i, j]] = q[:, [j, i]]
                yield (f"the joint columns {names[i]!r} and {names[j]!r} look swapped: check the joint "
                       f"order of the file against the URDF's chain", replace(m, q=q), 1.0)
    if conventions:
        for i in np.flatnonzero(~pr):
            q = m.q.copy()
            q[:, i] = -q[:, i]
            yield (f"the values of joint {names[i]!r} look counted the other way than the URDF's axis (another "
                   f"convention's sign): negate that column", replace(m, q=q), 1.0)
        for i in np.flatnonzero(~pr):
            for deg in (90, -90, 180):
                q = m.q.copy()
                q[:, i] += math.radians(deg)
                yield (f"the values of joint {names[i]!r} look counted from another zero than the URDF's "
                       f"(another convention's, {-deg:+d} deg from it): add {deg:+d} deg to that column",
                       replace(m, q=q), 1.0)
    if not pr.all():
        for factor, sentence in ((math.pi / 180, "the revolute joint values look in degrees but were read as "
                                  "radians: name the columns <joint>_deg"),
                                 (180 / math.pi, "the revolute joint values look in radians but were read as "
                                  "degrees: name the columns <joint>_rad")):
            yield sentence, replace(m, q=np.where(pr, m.q, m.q * factor)), 1.0
    for factor, sentence in ((1e3, "the positions look in metres but were read as millimetres: name the "
                              "columns x_m, y_m, z_m"),
                             (1e-3, "the positions look in millimetres but were read as metres: name the "
                              "columns x_mm, y_mm, z_mm")):
        yield sentence, replace(m, position=m.position * factor), factor


def _noise(fit: Fit) -> tuple[float, float]:
    """The fit's noise levels (m, rad; rad 0 for position-only data) as its residuals give them
    (the given levels scaled by the square root of their reduced chi-square)."""
    nz = fit.noise
    pos = nz.position if nz.estimated else nz.position * math.sqrt(nz.chi2_pos)
    if nz.rotation is None:
        return pos, 0.0
    return pos, nz.rotation if nz.estimated or nz.chi2_rot is None else nz.rotation * math.sqrt(nz.chi2_rot)


def _screen(setup: Setup, m: Measurements) -> tuple[Setup, tuple[float, float]]:
    """The prepare stage of rows ``m`` with the frames estimated in closed form, and the median
    position (m) and rotation (rad; 0 without) errors of the nominal model with those frames:
    a misreading undone brings them down to the model's own error (millimetres) at the cost of
    one kinematics pass, before any fit."""
    alt_setup, _ = prepare(setup.nominal, m, None, True)
    e = pose_errors(alt_setup.start, alt_setup.cal.q, alt_setup.cal.position, alt_setup.cal.rotation,
                    targets=target_rows(alt_setup.start, alt_setup.cal))
    rot = 0.0 if e.rotation_errors is None else median(e.rotation_errors)
    return alt_setup, (median(e.position_errors), rot)


def misreadings(setup: Setup, fit: Fit, options: CalibrationOptions, *, implausible: bool) -> list[str]:
    """Sentences naming the misreadings of the calibration rows that make them fit far better
    (best first; empty when none does, or when the fit is neither implausible nor suspect).

    Each misreading undone is screened by the nominal model's error with frames estimated in
    closed form (:data:`MISREADING_GAIN` times smaller than the rows as read in position or
    rotation, neither larger; positions compared in the units of the rows as read); the
    survivors (at most :data:`MAX_FITS`, best first) are fitted. A fit of the rows as read that
    moved link lengths far from the URDF's (positions in metres named _mm shrink the robot and
    fit to the noise), or whose chain is not the URDF's robot (a joint counted the other way:
    the fit flips axes and fits to the noise), is also checked; there a misreading is named
    when its fit keeps the chain the URDF's at no larger noise."""
    if setup.touch is not None:
        return []
    pos, rot = _noise(fit)
    far = bool(length_notes(setup.nominal, fit.model)) or \
        (implausible and bool(chain_implausibility(setup.nominal, fit.model, setup.measure)))
    if not (implausible or far or pos > SUSPECT_POS_M or rot > SUSPECT_ROT_RAD):
        return []
    opts = replace(options, cv=0, sigma_pos=None, sigma_rot=None)
    _, (p0, r0) = _screen(setup, setup.cal)
    screened = []
    # (a joint's sign and zero only for a refused fit: the chain rule finds what they do; noisy
    # data, a camera's, do not pay 4 screens per joint)
    for sentence, alt, scale in alternatives(setup.cal, conventions=implausible):
        try:
            alt_setup, (p1, r1) = _screen(setup, alt)
        except CalibError:
            continue        # (the undone reading is no reading at all)
        p1 /= scale
        gain = max(p0 / max(p1, 1e-300), r0 / max(r1, 1e-300) if r1 else 1.0)
        if gain >= MISREADING_GAIN and p1 <= 1.2 * p0 and r1 <= 1.2 * r0:
            screened.append((gain, sentence, alt_setup, scale))
    found = []
    for _, sentence, alt_setup, scale in sorted(screened, key=lambda g: -g[0])[:MAX_FITS]:
        try:
            alt_fit, _ = fit_with(alt_setup, fit.free, opts, outlier_k=opts.outlier_k)
        except (CalibError, np.linalg.LinAlgError):
            continue
        a_pos, a_rot = _noise(alt_fit)
        gain = max(pos * scale / max(a_pos, 1e-300), rot / max(a_rot, 1e-300) if a_rot else 1.0)
        better = gain >= MISREADING_GAIN or far     # (the chain of a plausible fit: checked below)
        worse = a_pos > 1.2 * pos * scale or a_rot > 1.2 * rot
        if not better or worse or alt_fit.solver.status != "converged" or \
                implausibility(setup.nominal, alt_fit, sigma_pos_given=False, sigma_rot_given=False):
            continue
        shown = f"{a_pos * 1e3:.3g} mm" + (f", {a_rot:.3g} rad" if a_rot else "")
        was = f"{pos * 1e3:.3g} mm" + (f", {rot:.3g} rad" if a_rot else "")
        if scale != 1.0:
            was += " in the units as read"
        if far:
            shown += " with the URDF's chain"
            was += (", " if scale != 1.0 else " ") + "with a chain far from the URDF's"
        found.append((gain, f"likely cause: {sentence} (the data then fit to {shown} instead of {was})"))
    return [s for _, s in sorted(found, key=lambda g: -g[0])]
