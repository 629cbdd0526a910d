"""Vendor conventions: how each controller names and scales the columns of its exports, as data.

:data:`CONVENTIONS` is the one table: for each ``--convention`` name, the joint column names
(with their default unit) and the other columns, each mapped onto one of calib's quantities
(``x``, ``qw``, ``rz``, ``rvx``, ``e1``, ...) with its default unit. A column of such a file is
read in that unit when its name has no unit suffix, and in the suffix's unit when it has one
(``rx_deg`` under ``ur`` is a rotation vector in degrees). calib's own names stay valid under
every convention. :func:`format_help` prints calib's own column rules and this table (``calib
formats``); :func:`markdown_table` is the table in docs/formats.md (a test checks that they agree).

This module imports nothing heavy: the command line builds its ``--convention`` choices from it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass



__all__ = ["Convention", "ControllerBase", "CONVENTIONS", "CONVENTION_NAMES", "UR_JOINT_NAMES", "ORIENTATION_READINGS",
           "ambiguous_candidates", "format_help", "markdown_table"]

#: Universal Robots' joint names in chain order (URScript, the teach pendant's log).
UR_JOINT_NAMES = ("base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3")


@dataclass(frozen=True, eq=False, repr=False)     # (table rows: nothing compares or prints them)
class ControllerBase:
    """Where a controller's own base frame (the frame of the poses it prints and its programs
    hold) sits in a robot's URDF, as the vendor's ROS-Industrial support package defines it.

    ROS-Industrial names that frame ``base`` ("The *base* frame shall match exactly the *base*
    defined by the robot controller", the tutorial "Create a URDF for an Industrial Robot";
    ur_description's doc/robot_frames.rst: "``base`` - This is the frame that is used by the robot
    controller to represent the robot's *Base* feature ... This follows the REP proposal 199").

    link : the URDF link of that frame (``base``). parent : the link it is placed from
        (``base_link``). rpy, xyz : its origin there (radians, metres) when the vendor's packages
        place it the same way for every model, else None (the URDF's own ``link`` is needed).
    what : the vendor's name of the frame. source : the published lines followed.
    """

    link: str
    parent: str
    rpy: tuple[float, float, float] | None
    xyz: tuple[float, float, float] | None
    what: str
    source: str


@dataclass(frozen=True, eq=False, repr=False)     # (table rows, looked up by name: nothing compares or prints them)
class Convention:
    """One vendor's column names.

    name : the ``--convention`` value. vendor : who writes such files, and where.
    joints : ((pattern, ...), unit): joint i (from 0) is named ``pattern.format(i=i + 1, i0=i)``,
        or, for a tuple of names (:data:`UR_JOINT_NAMES`), its i-th name; unit ``deg`` or ``rad``
        (prismatic joints: ``mm`` for ``deg``, ``m`` for ``rad``).
    columns : ((name, calib quantity, unit or ""), ...) for positions and orientations; names
        are matched case-insensitively.
    euler : the scipy Euler sequence of ``e1, e2, e3`` when the convention maps columns onto
        them, else None.
    orientation : what the orientation columns are, in words.
    """

    name: str
    vendor: str
    joints: tuple
    columns: tuple
    euler: str | None
    orientation: str
    #: regular expression (full match, lower case) of the vendor's other columns: ignored like
    #: any column calib does not know, but never taken for a misspelt calib name
    others: str = ""
    #: the controller's base frame in the robot's URDF (:class:`ControllerBase`), or None: pose
    #: targets written for that controller are in that frame (``calib compensate``)
    controller: ControllerBase | None = None

    def joint_names(self, n: int) -> list[tuple[str, int]]:
        """(lower-case name, joint index) of every joint column name of an n-joint robot."""
        out = []
        for pattern in self.joints[0]:
            if isinstance(pattern, tuple):
                out += [(pattern[i].lower(), i) for i in range(min(n, len(pattern)))]
            else:
                out += [(pattern.format(i=i + 1, i0=i).lower(), i) for i in range(n)]
        return out

    def joint_text(self) -> str:
        parts = []
        for pattern in self.joints[0]:
            if isinstance(pattern, tuple):
                parts.append(", ".join(pattern))
            else:
                a, b = pattern.format(i=1, i0=0), pattern.format(i="n", i0="n-1")
                parts.append(f"{a}..{b}")
        return f"{' or '.join(parts)} ({self.joints[1]})"

    def position_text(self) -> str:
        pos = [(n, u) for n, q, u in self.columns if q in ("x", "y", "z")]
        groups: dict[str, list[str]] = {}
        for n, u in pos:
            groups.setdefault(u, []).append(n)
        return "; ".join(f"{', '.join(ns)} ({u})" for u, ns in groups.items())

    def orientation_text(self) -> str:
        rot = [n for n, q, u in self.columns if q not in ("x", "y", "z")]
        return f"{', '.join(rot)}: {self.orientation}" if rot else self.orientation


_XYZ = "x", "y", "z"
#: ROS-Industrial's rule for the ``base`` link, for vendors without one published placement.
_ROS_I_BASE = ("ROS-Industrial, \"Create a URDF for an Industrial Robot\": \"The *base* frame shall match "
               "exactly the *base* defined by the robot controller. The transform between *base* and "
               "*base_link* can be defined in any way, as long as the transform is fixed between the two\"")
CONVENTIONS: dict[str, Convention] = {c.name: c for c in (
    Convention("calib", "calib's own format, stated", ((), ""), (), None,
               "rx, ry, rz with a unit suffix in any column order are calib's ZYX angles "
               "(R = Rz(rz) Ry(ry) Rx(rx))"),
    Convention("kuka", "KUKA KRL ($AXIS_ACT, $POS_ACT), KUKA.RSI / WorkVisual traces",
               (("A{i}",), "deg"),
               tuple((n, q, "mm") for n, q in zip("XYZ", _XYZ))
               + (("A", "rz", "deg"), ("B", "ry", "deg"), ("C", "rx", "deg")), None,
               "ZYX Euler angles, deg: A about Z, B about Y', C about X'' (R = Rz(A) Ry(B) Rx(C))",
               controller=ControllerBase(
                   "base", "base_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "KUKA's $ROBROOT",
                   "ros-industrial/kuka_experimental, kuka_kr16_support/urdf/kr16_2_macro.xacro (and every "
                   "support package there): \"ROS base_link to KUKA $ROBROOT coordinate system transform\", "
                   "<joint name=\"${prefix}base_link-base\" type=\"fixed\"> <origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>")),
    Convention("abb", "ABB RAPID (CJointT, CRobT), RobotStudio signal logs",
               (("rax_{i}",), "deg"),
               tuple((n, q, "mm") for n, q in zip("xyz", _XYZ))
               + (("q1", "qw", ""), ("q2", "qx", ""), ("q3", "qy", ""), ("q4", "qz", "")), None,
               "unit quaternion, scalar first (q1, q2, q3, q4) = (w, x, y, z)",
               controller=ControllerBase(
                   "base", "base_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "ABB's base coordinate system",
                   "ros-industrial/abb, abb_irb2400_support/urdf/irb2400_macro.xacro (and the other support "
                   "packages): \"ROS base_link to ABB World Coordinates transform\", <joint "
                   "name=\"${prefix}base_link-base\" type=\"fixed\"> <origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>")),
    Convention("ur", "Universal Robots: waypoint logs (URScript) and RTDE recordings",
               ((UR_JOINT_NAMES, "actual_q_{i0}"), "rad"),
               tuple((n, q, "m") for n, q in zip("xyz", _XYZ))
               + tuple((f"actual_TCP_pose_{k}", q, "m") for k, q in enumerate(_XYZ))
               + (("rx", "rvx", "rad"), ("ry", "rvy", "rad"), ("rz", "rvz", "rad"))
               + tuple((f"actual_TCP_pose_{k + 3}", q, "rad") for k, q in enumerate(("rvx", "rvy", "rvz"))),
               None, "rotation vector (axis times angle), rad",
               others=r"timestamp|(actual|target|joint|tool|safety|robot|runtime|speed|output|input|"
                      r"standard|payload|tcp|ft|elbow|euromap|script)_\w*",
               controller=ControllerBase(
                   "base", "base_link", (0.0, 0.0, math.pi), (0.0, 0.0, 0.0), "the UR controller's Base frame",
                   "Universal_Robots_ROS2_Description 2.4.5, urdf/ur_macro.xacro: <joint "
                   "name=\"${tf_prefix}base_link-base_fixed_joint\" type=\"fixed\"> <origin xyz=\"0 0 0\" "
                   "rpy=\"0 0 ${pi}\"/> <parent link=\"${tf_prefix}base_link\"/> <child "
                   "link=\"${tf_prefix}base\"/>, \"this is needed to correctly align 'base' with the "
                   "'Base' coordinate system of the UR controller\"")),
    Convention("fanuc", "FANUC (position registers, TP / KAREL exports)",
               (("J{i}",), "deg"),
               tuple((n, q, "mm") for n, q in zip("XYZ", _XYZ))
               + (("W", "rx", "deg"), ("P", "ry", "deg"), ("R", "rz", "deg")), None,
               "fixed-axis XYZ angles, deg: W about x, then P about y, then R about z, all of the "
               "base (R = Rz(R) Ry(P) Rx(W))",
               controller=ControllerBase(
                   "base", "base_link", None, None, "FANUC's World frame",
                   "ros-industrial/fanuc, fanuc_lrmate200id_support/urdf/lrmate200id_macro.xacro: \"ROS "
                   "base_link to Fanuc World Coordinates transform\", <joint name=\"${prefix}base_link-base\" "
                   "type=\"fixed\"> <origin xyz=\"0 0 0.330\" rpy=\"0 0 0\"/>: the height of J2's zero plane, "
                   "another for each model")),
    Convention("staubli", "Staubli VAL3 (jointRx, pointRx / trsf)",
               (("J{i}",), "deg"),
               tuple((n, q, "mm") for n, q in zip("XYZ", _XYZ))
               + (("Rx", "e1", "deg"), ("Ry", "e2", "deg"), ("Rz", "e3", "deg")), "XYZ",
               "XYZ Euler angles, deg: Rx about X, then Ry about the new Y', then Rz about Z'' "
               "(R = Rx(Rx) Ry(Ry) Rz(Rz))",
               controller=ControllerBase("base", "base_link", None, None, "the Staubli controller's World frame",
                                         _ROS_I_BASE)),
    Convention("yaskawa", "Yaskawa Motoman (robot-coordinate position variables, MotoPlus / "
                          "FS100-YRC1000 exports)",
               (("J{i}",), "deg"),
               tuple((n, q, "mm") for n, q in zip("XYZ", _XYZ))
               + (("Rx", "rx", "deg"), ("Ry", "ry", "deg"), ("Rz", "rz", "deg")), None,
               "fixed-axis XYZ angles, deg: Rx about x, then Ry about y, then Rz about z, all of "
               "the base (R = Rz(Rz) Ry(Ry) Rx(Rx))",
               controller=ControllerBase("base", "base_link", None, None, "the Yaskawa controller's robot "
                                         "coordinates", _ROS_I_BASE)),
)}
CONVENTION_NAMES = tuple(CONVENTIONS)

#: Ambiguous rx, ry, rz are read as one reading when its score (median |difference| of the
#: rotation angles between consecutive rows from the nominal model's, rad) is at most DECIDE_MAX
#: and every other reading's at least MARGIN times it (:mod:`calib.io.csv.orientation`).
DECIDE_MAX = 0.05
MARGIN = 5.0

#: How three orientation columns named rx, ry, rz can be read, with the convention that states
#: each reading (the candidates named when such a file states none).
ORIENTATION_READINGS = (
    ("ZYX angles, calib's R = Rz Ry Rx", "calib"),
    ("a rotation vector (UR)", "ur"),
    ("fixed-axis XYZ angles, the same R (Yaskawa)", "yaskawa"),
    ("XYZ Euler angles R = Rx Ry Rz (Staubli)", "staubli"),
)


def ambiguous_candidates() -> str:
    """The readings of rx, ry, rz columns and the flag that chooses each, in one clause."""
    return "; ".join(f"{text}: --convention {name}" for text, name in ORIENTATION_READINGS)


# ====================================================================== help page and docs/formats.md table
def markdown_table() -> str:
    """The conventions as a Markdown table (the one in docs/formats.md)."""
    lines = ["| `--convention` | written by | joints | position | orientation |",
             "|---|---|---|---|---|"]
    for c in CONVENTIONS.values():
        if c.name == "calib":
            continue
        lines.append(f"| `{c.name}` | {c.vendor} | {c.joint_text()} | {c.position_text()} | "
                     f"{c.orientation_text()} |")
    return "\n".join(lines) + "\n"


#: calib's own column rules, as ``calib formats`` prints them (one rule a paragraph).
RULES = """\
calib's measurement, poses and targets files (CSV):

File: UTF-8 text (a byte-order mark is accepted); lines starting with # and blank lines are
  skipped anywhere; row numbers in messages are line numbers of the file.
Header: the first line that names known columns (a preamble before it, such as an instrument's
  export header, is skipped with a note), or the line given by --header-line N; a file without a
  header line is refused unless --columns NAMES (or an --instrument preset) names its columns.
Delimiter: the one of comma, semicolon, tab or whitespace (runs of spaces) that splits the header
  into the most fields; with semicolon, tab or whitespace a decimal comma (441,5) is accepted.
Names: matched case-insensitively; 'X (mm)' and 'X [mm]' read as x_mm; --rename OLD=NEW maps a
  file's names onto calib's first (OLD= drops a column). Columns calib does not know are ignored
  with a note; near-misses of a known name (x_mn) are errors with a "did you mean".
Joints: one column per joint of the chain, named after the URDF joint (joint1_deg) or q1..qn,
  J1..Jn, A1..An in chain order (one style per file), with the unit suffix _deg or _rad (_mm or _m
  for prismatic joints). Values beyond a joint limit by more than --limit-tolerance are errors.
Position: x, y, z with _mm or _m: the tool frame's origin in the measurement frame.
Orientation (optional), of the tool frame in the measurement frame, one of:
  qw, qx, qy, qz       unit quaternion, scalar first, no suffix, any column order
  rz, ry, rx           ZYX angles R = Rz(rz) Ry(ry) Rx(rx), _deg or _rad, written in this order
                       (written rx, ry, rz they are ambiguous and refused; see below)
  e1, e2, e3           Euler angles of the sequence given by --euler SEQ (scipy notation)
  rvx, rvy, rvz        rotation vector (axis times angle), _deg or _rad
  r11 ... r33          rotation matrix, rij = row i, column j
Labels: set (cal or val), target (the reflector's id), pose_id (rows of one id are repeated
  visits of one configuration: the report's ISO 9283 repeatability), name (a column point, name
  or waypoint: the row's name, kept in the report's residuals and in files written back); with
  --tracker, the --key column.
Extra quantities (optional, read only with a unit): time with _s, _min or _h; temperature with
  _c or _degc. Empty cells are allowed; the report plots the residuals against them (drift).
Touch rows (calibration without a tracker): instead of x, y, z a row names what the tool point
  touched: point ID (the same unknown point in every row of that id), plane ID (a point of an
  unknown plane; --probe-radius-mm R for a ball tip), or sphere ID with radius_mm or radius_m (a
  known distance from an unknown centre). Rows with x, y, z and no feature in the same file are
  poses measured by an instrument; a row gives a feature or a measured pose, never both. A point
  column on rows that all give a measured pose is their name, not a feature.
Two files joined (--tracker POSES.csv): the joint file holds the joints, the tracker file the
  measured poses. --key COLUMN joins rows with the same value in both (--key JOINT=TRACKER when
  the files name the column differently, as --time JOINT=TRACKER); a key may repeat in the
  tracker file when each of its rows names its reflector: a target column, --target-column COL,
  or the point name split by --target-from REGEX (named groups key and target, matching the whole
  name, e.g. (?P<key>P\\d+)_(?P<target>SMR\\d+) for P001_SMR2). --join nearest-time --time COLUMN
  --max-gap S joins each measured row to the joint row of nearest timestamp (at most S seconds
  away; numbers with _s, _ms, _us, _ns or --time-unit, times of day, or ISO 8601 in both files);
  two joint rows equally near with different joints, or none within S, are errors.
Literals in one cell (read in any delimiter; quote them in comma-separated files):
  pose column (named pose, tcp_pose or robtarget):
    p[x,y,z,rx,ry,rz]                      URScript pose: m and a rotation vector in rad
    [[x,y,z],[q1,q2,q3,q4],[cf..],[ext..]] RAPID robtarget: mm and a quaternion (w first)
  joints column (named joints, q or jointtarget):
    [q1,...,qn]                            URScript joint list, rad
    [[j1,...,j6],[e1,...,e6]]              RAPID jointtarget, deg (revolute) / mm
Ambiguous orientation names: rx, ry, rz written in that order (or without a unit) may be ZYX
  angles (the same as fixed-axis XYZ), a rotation vector or XYZ Euler angles. With a unit and
  joint values in the file, the rows decide when exactly one reading agrees with the nominal
  model (the rotation angles between consecutive rows, which no frame changes: at most
  {decide_max:g} rad off, the others at least {margin:g} times more; a note gives the figures);
  otherwise the file is refused with the flag that chooses: {candidates}.
"""


def format_help() -> str:
    """The built-in help page of ``calib formats``: calib's own column rules, the vendor
    conventions and the instrument presets (:func:`calib.io.csv.instruments.format_help`), as plain
    text (an installed wheel needs no documentation)."""
    import textwrap

    from calib.io.csv.instruments import format_help as instruments_help

    out = [RULES.format(candidates=ambiguous_candidates(), decide_max=DECIDE_MAX, margin=MARGIN), "",
           "Vendor conventions (--convention NAME): the names and units each controller writes.",
           "A column without a unit suffix is read in the unit shown; with a suffix, in the suffix's.",
           "calib's own names stay valid under every convention.", ""]
    for c in CONVENTIONS.values():
        out.append(f"{c.name}: {c.vendor}")
        if c.name == "calib":
            out.append(f"  orientation: {c.orientation}")
            out.append("")
            continue
        out.append(f"  joints:      {c.joint_text()}")
        out.append(f"  position:    {c.position_text()}")
        out.append(f"  orientation: {c.orientation_text()}")
        out.append("")
    lines = []
    for line in "\n".join(out).splitlines():
        indent = len(line) - len(line.lstrip())
        lines += textwrap.wrap(line, 98, subsequent_indent=" " * (indent + 2)) or [""]
    return "\n".join(lines) + "\n\n" + instruments_help()
