"""Joining a joint file and a tracker file (issue 25, item 3): one joint row to several measured
rows (3 SMRs measured at each pose) by a key and target ids, and a timestamped joint log joined to
a timestamped tracker file by the nearest time; and the refusals of both.

The files are written here as a tracker and a controller write them (``;`` and decimal commas,
compound point names, a 100 Hz log), from simulated measurements of the paper's "true" robot
carrying three reflectors, so the rows they must give are known.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import calib
from calib import MeasurementFormatError, ParameterError, ReadOptions
from calib.cli.main import main

from conftest import BUNDLED_URDF, urdf_numbers

#: Reflectors on the tool, metres in the tool frame (docs/formats.md's "several targets" example).
OFFSETS = {"SMR1": [0.1, 0.0, 0.05], "SMR2": [-0.05, 0.08, 0.05], "SMR3": [0.0, -0.07, 0.1]}
N_POSES = 15
REGEX = r"(?P<key>P\d+)_(?P<target>SMR\d+)"
JOINT_HEADER = [f"A{i}_deg" for i in range(1, 7)]


def _r(v) -> str:
    return repr(float(v))


@pytest.fixture(scope="module")
def robot():
    return calib.load_robot(BUNDLED_URDF)


@pytest.fixture(scope="module")
def smr(robot):
    """(configurations (N, 6) rad, measurements of 3 SMRs at each, one row per SMR)."""
    true = calib.apply_deviations(robot, calib.PAPER_DEVIATIONS).with_target_offsets(OFFSETS)
    Q = robot.random_configurations(N_POSES, 11)
    ids = list(OFFSETS) * N_POSES
    meas = calib.simulate_measurements(true, np.repeat(Q, 3, axis=0), sigma_pos=1e-5,
                                       position_only=True, targets=ids, rng=4)
    return Q, meas


def _write_pair(d, Q, meas, *, regex_names=True):
    """A joint log (one row per pose, point names P001 ...) and a Leica-style tracker export
    (``;``, decimal comma, brackets for units, point names P001_SMR1 ...: 3 rows per pose, in
    the tracker's own order), and calib's own multi-target file of the same rows."""
    n = len(Q)
    deg = [[_r(v) for v in np.degrees(q)] for q in Q]
    mm = [[_r(v) for v in p * 1e3] for p in meas.position]
    (d / "joints.csv").write_text(
        "Point," + ",".join(JOINT_HEADER) + "\n"
        + "".join(f"P{k + 1:03d}," + ",".join(deg[k]) + "\n" for k in range(n)))
    point = (lambda k: f"P{k // 3 + 1:03d}_{meas.target[k]}") if regex_names else \
        (lambda k: f"P{k // 3 + 1:03d};{meas.target[k]}")
    head = "Point;X [mm];Y [mm];Z [mm];Date\n" if regex_names else \
        "Point;Reflector;X [mm];Y [mm];Z [mm];Date\n"
    (d / "tracker.csv").write_text(
        head + "".join(f"{point(k)};" + ";".join(x.replace(".", ",") for x in mm[k]) + ";25.11.2026\n"
                       for k in range(len(mm))))
    (d / "own.csv").write_text(
        ",".join(JOINT_HEADER) + ",x_mm,y_mm,z_mm,target\n"
        + "".join(",".join(deg[k // 3] + mm[k] + [meas.target[k]]) + "\n" for k in range(len(mm))))
    return d / "joints.csv", d / "tracker.csv", d / "own.csv"


def _same_rows(a, b):
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.position, b.position)
    assert a.target == b.target and a.rotation is None and b.rotation is None


# ====================================================================== many-to-one by key
def test_tracker_export_with_compound_point_names_calibrates_as_calibs_own_format(tmp_path, robot, smr,
                                                                                  capsys):
    Q, meas = smr
    joints, tracker, own = _write_pair(tmp_path, Q, meas)
    a, b = tmp_path / "joined.urdf", tmp_path / "own.urdf"
    assert main(["calibrate", str(BUNDLED_URDF), str(joints), "--tracker", str(tracker), "--key",
                 "Point", "--target-from", REGEX, "-o", str(a)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"calib: note: {tracker}: ignored columns (not calib's): Date\n")
    assert main(["calibrate", str(BUNDLED_URDF), str(own), "-o", str(b)]) == 0
    ra, rb = calib.load_robot(a), calib.load_robot(b)
    assert ra.names == rb.names and ra.targets == ("SMR1", "SMR2", "SMR3")
    # the same rows in the same order: the same calibration, to far below 1e-9 m / rad
    np.testing.assert_allclose(ra.values, rb.values, rtol=0, atol=1e-9)
    # and the data itself: each measured row with its pose's joints and its own target
    m = calib.read_measurements(joints, robot, tracker=tracker,
                                options=ReadOptions(key="Point", target_from=REGEX))
    _same_rows(m, calib.read_measurements(own, robot))
    np.testing.assert_array_equal(m.rows, np.arange(2, 3 * N_POSES + 2))   # lines of the tracker file
    assert m.source == tracker and m.n_poses == 3 * N_POSES


def _leica_kuka_pair(d, Q, meas):
    """Issue 25's acceptance file pair as written: a tracker export with a 3-line preamble, ``;``
    and decimal commas, unsuffixed X, Y, Z, P001_SMR1..3; a KUKA joint log with A1..A6 (deg);
    and calib's own multi-target file of the same rows."""
    joints, tracker, own = _write_pair(d, Q, meas)
    joints.write_text(joints.read_text().replace("_deg", ""))
    lines = tracker.read_text().splitlines()
    tracker.write_text("Leica Absolute Tracker AT960 export\nJob: cell 3;Operator: A. N.\nUnits: mm\n"
                       + "\n".join([lines[0].replace(" [mm]", "")] + lines[1:]) + "\n")
    return joints, tracker, own


def test_leica_export_with_preamble_joined_to_a_kuka_log_by_point_name(tmp_path, robot, smr):
    """Read with --convention kuka and the join flags alone (no --rename): the rows of calib's own
    multi-target file."""
    joints, tracker, own = _leica_kuka_pair(tmp_path, *smr)
    m = calib.read_measurements(joints, robot, tracker=tracker, options=ReadOptions(
        convention="kuka", key="Point", target_from=REGEX))
    _same_rows(m, calib.read_measurements(own, robot))
    np.testing.assert_array_equal(m.rows, np.arange(5, 3 * N_POSES + 5))   # after the preamble


def test_leica_export_joined_to_a_kuka_log_calibrates_to_the_urdf_of_calibs_own_format(tmp_path, smr,
                                                                                        capsys):
    """Acceptance of issue 25 for the tracker export: `calib calibrate` with --convention kuka and
    the join flags only gives the calibrated URDF of calib's own file, every number to 1e-9, and
    says what it skipped and ignored (the preamble, the Date column)."""
    joints, tracker, own = _leica_kuka_pair(tmp_path, *smr)
    a, b = tmp_path / "joined.urdf", tmp_path / "own.urdf"
    assert main(["calibrate", str(BUNDLED_URDF), str(joints), "--tracker", str(tracker), "--convention",
                 "kuka", "--key", "Point", "--target-from", REGEX, "-o", str(a)]) == 0
    err = capsys.readouterr().err
    assert f"{tracker}: 3 lines before the header (line 4) skipped as a preamble" in err
    assert f"{tracker}: ignored columns (not calib's): Date" in err
    assert main(["calibrate", str(BUNDLED_URDF), str(own), "-o", str(b)]) == 0
    capsys.readouterr()
    ta, na = urdf_numbers(a.read_text())
    tb, nb = urdf_numbers(b.read_text())
    assert ta == tb and len(na) > 100
    np.testing.assert_allclose(na, nb, rtol=0, atol=1e-9)


def test_target_column_and_any_order_give_the_same_rows(tmp_path, robot, smr):
    """The reflector id in its own column (--target-column), the tracker rows shuffled: the rows
    come out in the joint file's order, the SMRs of one pose in the tracker file's order."""
    Q, meas = smr
    joints, tracker, own = _write_pair(tmp_path, Q, meas, regex_names=False)
    lines = tracker.read_text().splitlines()
    perm = np.random.default_rng(0).permutation(len(lines) - 1)
    tracker.write_text("\n".join([lines[0]] + [lines[1 + i] for i in perm]) + "\n")
    m = calib.read_measurements(joints, robot, tracker=tracker,
                                options=ReadOptions(key="point", target_column="reflector"))
    ref = calib.read_measurements(own, robot)
    # reorder the reference: pose by pose, SMRs in the order the shuffled file lists them
    pose, line = np.arange(3 * N_POSES) // 3, np.argsort(perm)     # line: where each row went
    order = np.lexsort((line, pose))
    _same_rows(m, ref.subset(order))
    np.testing.assert_array_equal(m.rows, line[order] + 2)


# ====================================================================== nearest time
def _timed_pair(d, Q, meas, *, iso=False, rng=5):
    """A 100 Hz joint log of the robot stopping 2 s at each pose and moving 1 s between them, and
    a tracker measuring the 3 SMRs of each stop at irregular times within it (ms resolution)."""
    rng = np.random.default_rng(rng)
    n = len(Q)
    t_stop = 0.5 + 3.0 * np.arange(n)             # each stop: [t_stop, t_stop + 2]
    t = np.arange(int(round((t_stop[-1] + 2.5) * 100))) / 100
    q = np.empty((len(t), 6))
    for k in range(n):
        prev = Q[k - 1] if k else Q[0]
        s = np.clip((t - (t_stop[k] - 1.0)) / 1.0, 0, 1)[:, None]   # moving in the second before
        inside = t >= t_stop[k] - 1.0
        q[inside] = np.where(s < 1, prev + s * (Q[k] - prev), Q[k])[inside]   # stopped: Q[k] exactly
    stamp = (lambda x: np.datetime_as_string(np.datetime64("2026-11-25T10:00:00") +
                                             np.timedelta64(int(round(x * 1e6)), "us"), unit="ms")) \
        if iso else (lambda x: f"{x:.3f}")
    if iso == "clock":              # hh:mm:ss.fff, and hh:mm:ss,fff as a European tracker writes it
        stamp = lambda x: f"10:{int(x // 60):02d}:{x % 60:06.3f}"  # noqa: E731
    col = "time" if iso else "time_s"
    (d / "log.csv").write_text(
        f"{col}," + ",".join(JOINT_HEADER) + "\n"
        + "".join(f"{stamp(t[i])}," + ",".join(_r(v) for v in np.degrees(q[i])) + "\n"
                  for i in range(len(t))))
    # within the stops (0.2 s after it begins to 0.2 s before it ends), to the millisecond
    times = np.round(t_stop[np.arange(3 * n) // 3] + 0.2
                     + np.sort(rng.uniform(0, 1.6, (n, 3)), axis=1).ravel(), 3)
    (d / "timed.csv").write_text(
        f"{col};Reflector;X [mm];Y [mm];Z [mm]\n"
        + "".join(f"{stamp(times[k]).replace('.', ',')};{meas.target[k]};"
                  + ";".join(_r(v).replace(".", ",") for v in meas.position[k] * 1e3) + "\n"
                  for k in range(3 * n)))
    return d / "log.csv", d / "timed.csv", col


@pytest.mark.parametrize("iso", [False, True, "clock"], ids=["seconds", "iso-8601", "time-of-day"])
def test_nearest_time_join_gives_the_rows_of_an_exact_join(tmp_path, robot, smr, iso):
    Q, meas = smr
    log, tracker, col = _timed_pair(tmp_path, Q, meas, iso=iso)
    joints, keyed, _ = _write_pair(tmp_path, Q, meas, regex_names=False)
    m = calib.read_measurements(log, robot, tracker=tracker,
                                options=ReadOptions(join="nearest-time", time=col, max_gap=0.006,
                                                    target_column="reflector"))
    exact = calib.read_measurements(joints, robot, tracker=keyed,
                                    options=ReadOptions(key="point", target_column="reflector"))
    _same_rows(m, exact)
    np.testing.assert_array_equal(m.rows, exact.rows)     # the tracker files' lines, in both
    assert m.source == tracker and m.n_poses == 3 * N_POSES


def test_nearest_time_join_picks_the_nearest_row_as_a_brute_force_search(tmp_path, robot):
    """A log of 1,000 rows at random times (written out of order), each with its own joints
    (joint1 = 0.01 deg times its index), and 300 measured rows at random times: each joined to
    the joint row of the smallest |t_joint - t_measured| (np.argmin over all rows)."""
    rng = np.random.default_rng(8)
    tj = np.round(rng.uniform(0, 100, 1000), 6)
    tt = np.round(rng.uniform(-0.5, 100.5, 300), 6)
    order = rng.permutation(1000)
    (tmp_path / "log.csv").write_text(
        "t_s," + ",".join(JOINT_HEADER) + "\n"
        + "".join(f"{tj[i]:.6f},{0.01 * i:.2f},0,0,0,0,0\n" for i in order))
    (tmp_path / "trk.csv").write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(f"{t:.6f},441,0,-36.5\n" for t in tt))
    m = calib.read_measurements(tmp_path / "log.csv", robot, tracker=tmp_path / "trk.csv",
                                options=ReadOptions(join="nearest-time", time="t_s", max_gap=1.0))
    nearest = np.argmin(np.abs(tj[None, :] - tt[:, None]), axis=1)
    k = m.rows - 2                                              # the measured rows, by line
    assert m.n_poses == 300 and sorted(k) == list(range(300))
    np.testing.assert_allclose(np.degrees(m.q[:, 0]), 0.01 * nearest[k], rtol=0, atol=1e-9)
    # in the order of the joint file's rows
    line = np.argsort(order)[nearest[k]]
    assert (np.diff(line) >= 0).all()
    assert len(m.notes) == 1 and "timestamps not in time order" in m.notes[0]


# ====================================================================== refusals
def _err(call):
    with pytest.raises(MeasurementFormatError) as info:
        call()
    assert "\n" not in str(info.value)
    return info.value


def test_a_key_missing_on_one_side_names_the_key_and_both_files(tmp_path, robot, smr):
    Q, meas = smr
    joints, tracker, _ = _write_pair(tmp_path, Q, meas)
    options = ReadOptions(key="Point", target_from=REGEX)
    text = tracker.read_text()
    tracker.write_text("\n".join(l for l in text.splitlines() if not l.startswith("P004_")) + "\n")
    e = _err(lambda: calib.read_measurements(joints, robot, tracker=tracker, options=options))
    assert (e.path, e.row, e.column) == (joints, 5, "Point")
    assert str(e) == f"{joints}, row 5, column 'Point': key 'P004' is not in {tracker}"
    tracker.write_text(text.replace("P002_SMR3", "P099_SMR3"))
    e = _err(lambda: calib.read_measurements(joints, robot, tracker=tracker, options=options))
    assert str(e) == (f"{tracker}, row 7, column 'Point': key 'P099' (of 'P099_SMR3', by --target-from) "
                      f"is not in {joints}")


@pytest.mark.parametrize("cell,fragment", [
    ("P002-SMR3", "'P002-SMR3' does not match --target-from"),
    ("P002_SMR3x", "'P002_SMR3x' does not match --target-from"),
    ("P002_SMR2", "duplicated point 'P002_SMR2': key 'P002' and target 'SMR2' (also in row 6)"),
])
def test_a_point_name_the_regex_does_not_split_names_the_row(tmp_path, robot, smr, cell, fragment):
    Q, meas = smr
    joints, tracker, _ = _write_pair(tmp_path, Q, meas)
    tracker.write_text(tracker.read_text().replace("P002_SMR3", cell))
    e = _err(lambda: calib.read_measurements(joints, robot, tracker=tracker,
                                             options=ReadOptions(key="Point", target_from=REGEX)))
    assert (e.path, e.row, e.column) == (tracker, 7, "Point") and fragment in str(e)


def test_several_rows_per_key_without_target_ids_are_refused_with_the_way_to_give_them(tmp_path, robot,
                                                                                        smr):
    Q, meas = smr
    joints, tracker, _ = _write_pair(tmp_path, Q, meas, regex_names=False)
    e = _err(lambda: calib.read_measurements(joints, robot, tracker=tracker,
                                             options=ReadOptions(key="Point")))
    assert (e.path, e.row) == (tracker, 3)
    assert "duplicated key 'P001' (also in row 2); several measured rows of one joint row need a " \
           "target id each: a target column (--target-column)" in str(e)
    e = _err(lambda: calib.read_measurements(joints, robot, tracker=tracker,
                                             options=ReadOptions(key="Point", target_column="Prism")))
    assert str(e) == f"{tracker}, row 1: no target column 'Prism' (given by --target-column)"


@pytest.mark.parametrize("kwargs,fragment", [
    (dict(key="p", target_from=r"(P\d+)_(SMR\d+)"), "has no named groups key and target"),
    (dict(key="p", target_from=r"(?P<key>P\d+)_SMR\d+"), "has no named group target"),
    (dict(key="p", target_from=r"(?P<key>P\d+"), "is not a regular expression"),
    (dict(key="p", target_from=REGEX, target_column="smr"), "from one place"),
    (dict(key="p", target_column="P"), "is the key column"),
    (dict(join="nearest-time", time="time_s", max_gap=-0.01), "max_gap must be a finite number of seconds >= 0"),
    (dict(join="nearest-time", time="time_s", max_gap=math.nan), "max_gap must be a finite number"),
    (dict(join="nearest-time", time="time_s"), "needs --max-gap S"),
    (dict(join="nearest-time", max_gap=0.01), "needs the time column"),
    (dict(join="nearest-time", time="time_s", max_gap=0.01, key="p"), "not both"),
    (dict(join="nearest-time", time="time_s", max_gap=0.01, time_unit="ms"), "says its unit is s"),
    (dict(join="nearest-time", time="t", max_gap=0.01, target_from=REGEX), "splits the key column (--key)"),
    (dict(time="time_s", max_gap=0.01), "--time, --max-gap join by time: give --join nearest-time"),
    (dict(target_from=REGEX), "give it too (--key COLUMN)"),
    (dict(join="closest"), "join must be one of key, nearest-time"),
    (dict(join="nearest-time", time="t", max_gap=0.01, time_unit="min"), "time_unit must be one of"),
])
def test_join_options_are_checked_up_front(kwargs, fragment):
    with pytest.raises(ParameterError) as info:
        ReadOptions(**kwargs)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def _log(d, times, joints, tracker_times, col="time_s"):
    (d / "log.csv").write_text(f"{col}," + ",".join(JOINT_HEADER) + "\n"
                               + "".join(f"{t},{a},0,0,0,0,0\n" for t, a in zip(times, joints)))
    (d / "trk.csv").write_text(f"{col};x_mm;y_mm;z_mm\n"
                               + "".join(f"{t};441;0;-36,5\n" for t in tracker_times))
    return d / "log.csv", d / "trk.csv"


@pytest.mark.parametrize("times,joints,measured,row,fragment", [
    # 0.015 is as near 0.01 as 0.02, whose joint values differ
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["0,015"], 2,
     "rows 3 and 4 of {j} ('0.01' and '0.02') are equally near '0,015', with different joint values: "
     "the join by nearest time is ambiguous"),
    (["0.00", "0.01", "0.01", "0.02"], [0, 1, 2, 3], ["0,011"], 2,
     "rows 3 and 4 of {j} have the same timestamp '0.01', with different joint values"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["0,01", "0,5"], 3,
     "no joint row within --max-gap 0.006 s of '0,5': the nearest is row 4 of {j}, 0.48 s away"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["-0,01"], 2, "the nearest is row 2 of {j}, 0.01 s away"),
    (["0.00", "", "0.02"], [0, 1, 2], ["0,01"], 3, "empty timestamp"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["0,01", "x"], 3, "'x' is not a timestamp, expected a number like row 2's"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["10:00:00", "10:00:0x"], 3,
     "'10:00:0x' is not a timestamp, expected a time of day like row 2's"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["10:00:00,013"], 2,
     "timestamps are times of day here but numbers in {j}"),
    (["0.00", "0.01", "0.02"], [0, 1, 2], ["2026-11-25T10:00:00"], 2,
     "timestamps are dates and times here but numbers in {j}"),
])
def test_nearest_time_refusals_name_file_row_and_column(tmp_path, robot, times, joints, measured, row,
                                                        fragment):
    j, t = _log(tmp_path, times, joints, measured)
    e = _err(lambda: calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="time_s", max_gap=0.006)))
    path = j if "empty" in fragment else t
    assert (e.path, e.row, e.column) == (path, row, "time_s"), str(e)
    assert fragment.format(j=j) in str(e)


def test_nearest_time_ties_of_equal_joints_and_an_unsorted_log_are_joined(tmp_path, robot):
    """A tie between two rows of the robot standing still is no ambiguity; a log out of time order
    is joined all the same, with a note; a unit from --time-unit."""
    j, t = _log(tmp_path, ["20", "0", "10", "30"], [1, 0, 1, 2], ["15", "1", "29"], col="t")
    m = calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="t", time_unit="ms", max_gap=0.005))
    np.testing.assert_allclose(np.degrees(m.q[:, 0]), [0, 1, 2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.rows, [3, 2, 4])        # the tracker's rows, in joint time order
    assert m.notes == (f"{j}: timestamps not in time order (row 3 is earlier than row 2); joined to "
                       f"the nearest time all the same",)
    e = _err(lambda: calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="t", max_gap=0.005)))
    assert (e.path, e.row, e.column) == (j, 1, "t") and "numbers without a unit" in str(e)
    e = _err(lambda: calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="time_s", max_gap=0.005)))
    assert str(e) == f"{j}, row 1: no time column 'time_s' (given by --time)"
    with pytest.raises(ParameterError) as info:
        calib.read_measurements(j, robot, options=ReadOptions(join="nearest-time", time="t", max_gap=1))
    assert str(info.value) == ("--join nearest-time is for a tracker file joined to the joint file: "
                               "give it too (--tracker POSES.csv)")
    j, t = _log(tmp_path, ["10:00:00", "10:00:01"], [0, 1], ["10:00:00,5"], col="t")
    e = _err(lambda: calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="t", time_unit="s", max_gap=1)))
    assert str(e) == (f"{j}, row 2, column 't': --time-unit s is the unit of timestamps that are "
                      f"numbers; these are times of day ('10:00:00'): leave it out")
    e = _err(lambda: calib.read_measurements(j, robot, tracker=t, options=ReadOptions(
        join="nearest-time", time="t", max_gap=1)))       # 10:00:00.5 is as near 10:00:00 as 10:00:01
    assert (e.path, e.row) == (t, 2) and "are equally near '10:00:00,5'" in str(e)


# ====================================================================== CLI
def test_cli_join_errors_exit_2_with_one_line_and_nothing_written(tmp_path, smr, capsys):
    Q, meas = smr
    joints, tracker, _ = _write_pair(tmp_path, Q, meas)
    tracker.write_text(tracker.read_text().replace("P002_SMR3", "P002-SMR3"))
    out = tmp_path / "cal.urdf"
    base = ["calibrate", str(BUNDLED_URDF), str(joints), "--tracker", str(tracker), "-o", str(out)]
    cases = [
        (["--key", "Point", "--target-from", REGEX],
         f"calib: error: {tracker}, row 7, column 'Point': 'P002-SMR3' does not match --target-from"),
        (["--key", "Point", "--target-from", "(P.*)"], "calib: error: --target-from '(P.*)' has no named groups"),
        (["--join", "nearest-time", "--time", "time_s", "--max-gap", "-1"],
         "argument --max-gap: -1 must be a finite number >= 0"),
        (["--join", "nearest-time", "--time", "time_s"], "calib: error: --join nearest-time needs --max-gap S"),
    ]
    for extra, start in cases:
        code = main(base + extra)
        err = capsys.readouterr().err
        assert code == 2 and not out.exists(), err
        assert start in err and err.endswith("\n")
        assert err.count("\n") == (1 if err.startswith("calib: error") else 2)   # usage line first


def test_cli_bad_input_of_the_acceptance_exits_2_with_one_line_and_leaves_the_output(tmp_path, smr,
                                                                                      capsys):
    """Issue 25's bad-input cases through `calib calibrate`: a many-to-one join with a key missing
    on either side, two joint timestamps equally near a measured one, a preamble with no header.
    Each: exit 2, one line naming file, row and column, an existing output file left as it was."""
    joints, tracker, _ = _leica_kuka_pair(tmp_path, *smr)
    join = ["--convention", "kuka", "--key", "Point", "--target-from", REGEX]
    text = tracker.read_text()
    no_p004 = tmp_path / "no_p004.csv"
    no_p004.write_text("\n".join(l for l in text.splitlines() if not l.startswith("P004_")) + "\n")
    no_p007 = tmp_path / "no_p007.csv"
    no_p007.write_text("\n".join(l for l in joints.read_text().splitlines() if not l.startswith("P007,")) + "\n")
    log, trk = _log(tmp_path, ["0.00", "0.01", "0.02"], [0, 1, 2], ["0,01", "0,015"])
    bare = tmp_path / "bare.csv"
    bare.write_text("Leica Absolute Tracker AT960 export\nJob: cell 3\nUnits: mm\n"
                    + "".join(";".join(["1"] * 9) + "\n" for _ in range(5)))
    cases = [
        ([str(joints), "--tracker", str(no_p004)] + join,
         f"{joints}, row 5, column 'Point': key 'P004' is not in {no_p004}"),
        ([str(no_p007), "--tracker", str(tracker)] + join,
         f"{tracker}, row 23, column 'Point': key 'P007' (of 'P007_SMR1', by --target-from) is not in {no_p007}"),
        ([str(log), "--tracker", str(trk), "--join", "nearest-time", "--time", "time_s", "--max-gap", "0.006"],
         f"{trk}, row 3, column 'time_s': rows 3 and 4 of {log} ('0.01' and '0.02') are equally near '0,015'"),
        ([str(bare)], f"{bare}, row 4: no header line: lines 1-3 name no column calib knows"),
    ]
    out = tmp_path / "cal.urdf"
    for argv, start in cases:
        out.write_text("earlier calibration\n")
        code = main(["calibrate", str(BUNDLED_URDF)] + argv + ["-o", str(out), "--report", str(tmp_path / "r.json")])
        err = capsys.readouterr().err
        assert code == 2, err
        assert err.startswith(f"calib: error: {start}") and err.count("\n") == 1, err
        assert out.read_text() == "earlier calibration\n" and not (tmp_path / "r.json").exists()


def test_readme_join_examples_read_as_the_several_targets_example(tmp_path, robot):
    """docs/formats.md's worked examples of the joins: each command (as printed) reads its two files into
    the rows of the "several targets" example (tracker export) or two of them (by time)."""
    import re
    import shlex

    from calib.cli.args import read
    from calib.cli.main import build_parser

    section = (BUNDLED_URDF.parents[2] / "docs" / "formats.md").read_text()
    blocks = [body for info, body in re.findall(r"^```([^\n]*)\n(.*?)^```[ \t]*$", section, flags=re.S | re.M)
              if not info.strip()]     # (the examples: fences without an info string)
    names = [b.splitlines()[0].split()[1].rstrip(",") for b in blocks[8:12]]
    assert names == ["JOINTS.csv", "TRACKER.csv", "LOG.csv", "TIMED.csv"]
    for name, block in zip(names, blocks[8:12]):
        (tmp_path / name).write_text(block)
    (tmp_path / "own.csv").write_text(blocks[7])
    own = calib.read_measurements(tmp_path / "own.csv", robot)
    commands = [" ".join(c.split()) for c in re.findall(r"`(calib calibrate ROBOT\.urdf [^`]*)`", section)]
    assert len(commands) == 3
    parser = build_parser()
    for command, take in zip(commands[1:], (slice(None), [0, 4])):
        argv = [str(tmp_path / a) if a.endswith(".csv") else a for a in shlex.split(command)[1:]]
        args = parser.parse_args([str(BUNDLED_URDF) if a == "ROBOT.urdf" else a for a in argv])
        m = read(args.measurements, robot, args, args.tracker)
        ref = own.subset(take)
        np.testing.assert_allclose(m.q, ref.q, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(m.position, ref.position)
        assert m.target == ref.target
