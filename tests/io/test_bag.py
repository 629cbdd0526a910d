"""ROS bags in (calib.io.bag): a campaign recorded as a bag, in each of the three formats (ROS 1 .bag,
ROS 2 sqlite3 and MCAP, written here by rosbags' own writers), reads into the Measurements of the
equivalent CSV file and calibrates to the same numbers; still poses are found and moving samples
left out; the joints are taken at the instrument's stamps; bad bags are refused in one line naming
the bag, the topic and the message, exit 2, nothing written."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib.cli.main import main
from calib.errors import MeasurementFormatError, ParameterError
from calib.io.bag.reader import BagOptions, read_bag
from calib.io.bag.rows import joints_at, still_periods

from conftest import BUNDLED_URDF, urdf_numbers
from rosbag_writer import (FORMATS, T0_NS, bag_path, campaign, campaign_messages, joint_state, pose_stamped,
                           typestore, write_bag)

pytest.importorskip("rosbags", reason="the ros extra (pip install 'calib[ros]') is not installed")

N_POSES = 14


@pytest.fixture(scope="module")
def truth():
    """(nominal robot, true robot (1 mm-scale deviations), Q (N_POSES, 6))."""
    robot = calib.load_robot(BUNDLED_URDF)
    true = calib.apply_deviations(robot, calib.random_deviations(robot, 1e-3, rng=np.random.default_rng(5)))
    return robot, true, robot.random_configurations(N_POSES, 2)


def _campaign_bag(folder, fmt, truth, **kw):
    robot, true, Q = truth
    ts = typestore(fmt)
    joints, poses = campaign(robot, Q, T_of=true.T_meas_tool)
    return write_bag(bag_path(folder, fmt), fmt, campaign_messages(ts, robot, joints, poses, **kw), ts)


def _equivalent_csv(folder, truth):
    """The CSV file a user would write by hand for the campaign: one row per pose, its joints and
    the true tool pose (calib's own writer, full precision)."""
    robot, true, Q = truth
    T = np.array([true.T_meas_tool(q) for q in Q])
    meas = calib.Measurements.from_arrays(Q, T[:, :3, 3], T[:, :3, :3], joint_names=robot.joint_names)
    path = folder / "equivalent.csv"
    calib.write_measurements(path, meas, angle_unit="rad", length_unit="m")
    return path


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS)
def test_a_bag_calibrates_to_the_numbers_of_the_equivalent_csv(tmp_path, truth, fmt):
    """Each format: one row per held pose, at the pose's joints (1e-12 rad: the joints of a still
    robot) and tool pose (1e-12 m), in order; the calibration's parameters equal those of the
    CSV file's (1e-9 m / rad: the CSV's 17 digits) and predict the true robot's poses (1 um:
    noise-free data); rows are the pose topic's message numbers."""
    robot, true, Q = truth
    bag = _campaign_bag(tmp_path, fmt, truth)
    meas = read_bag(bag, robot, BagOptions(pose="/tracker/pose"))
    csv = calib.read_measurements(_equivalent_csv(tmp_path, truth), robot)
    assert meas.n_poses == N_POSES
    np.testing.assert_allclose(meas.q, csv.q, atol=1e-12, rtol=0)
    np.testing.assert_allclose(meas.position, csv.position, atol=1e-12, rtol=0)
    np.testing.assert_allclose(meas.rotation, csv.rotation, atol=1e-12, rtol=0)
    assert meas.rows[0] == 1 and np.all(np.diff(meas.rows) > 100)        # 50 Hz: 150 messages per pose
    assert meas.columns["unix_time_s"][0] == pytest.approx(T0_NS * 1e-9, abs=3.0)
    a, b = calib.calibrate(robot, meas), calib.calibrate(robot, csv)
    assert a.free == b.free
    np.testing.assert_allclose(a.x, b.x, atol=1e-9, rtol=0)
    Qr = robot.random_configurations(20, 9)                        # and it is the true robot (noise-free data)
    dp = max(np.abs(a.robot.T_meas_tool(q)[:3, 3] - true.T_meas_tool(q)[:3, 3]).max() for q in Qr)
    assert dp < 1e-6, dp


@pytest.mark.slow
def test_the_command_line_calibrates_a_bag_as_the_csv(tmp_path, truth, capsys):
    """calib calibrate --bag writes the URDF the CSV file gives (every number to 1e-9), and a report
    whose measurements input is the bag's data file."""
    bag = _campaign_bag(tmp_path, "mcap", truth)
    csv = _equivalent_csv(tmp_path, truth)
    code = main(["calibrate", str(BUNDLED_URDF), "--bag", str(bag), "--pose", "/tracker/pose",
                 "-o", str(tmp_path / "bag.urdf"), "--report", str(tmp_path / "bag.json")])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "samples of /tracker/pose were taken while the robot moved" in err
    assert main(["calibrate", str(BUNDLED_URDF), str(csv), "-o", str(tmp_path / "csv.urdf")]) == 0, capsys.readouterr()
    ta, a = urdf_numbers((tmp_path / "bag.urdf").read_text())
    tb, b = urdf_numbers((tmp_path / "csv.urdf").read_text())
    assert ta.count("#") == tb.count("#")
    np.testing.assert_allclose(a, b, atol=1e-9, rtol=0)
    import json

    report = json.loads((tmp_path / "bag.json").read_text())
    assert report["provenance"]["inputs"]["measurements"]["path"].endswith(".mcap")
    # evaluate takes the bag too: the calibrated model's accuracy on it, as on the CSV file (to 1e-9 mm)
    results = []
    capsys.readouterr()
    for data in (["--bag", str(bag), "--pose", "/tracker/pose"], [str(csv)]):
        assert main(["evaluate", str(tmp_path / "bag.urdf"), *data, "--json"]) == 0
        results.append(json.loads(capsys.readouterr().out))
    assert results[0]["measurements"] == str(bag) and results[0]["all"]["n_poses"] == 14
    for key in ("rms", "max"):
        assert results[0]["all"]["position_mm"][key] == pytest.approx(results[1]["all"]["position_mm"][key], abs=1e-9)


@pytest.mark.slow
def test_tf_transforms_read_as_the_pose_topic_either_way_round(tmp_path, truth):
    """--tf tracker:tool reads the /tf transforms tracker -> tool; recorded the other way round
    (tool -> tracker) they are inverted: the same rows (1e-12)."""
    robot = truth[0]
    for sub in "pab":
        (tmp_path / sub).mkdir()
    want = read_bag(_campaign_bag(tmp_path / "p", "ros1", truth), robot, BagOptions(pose="/tracker/pose"))
    direct = read_bag(_campaign_bag(tmp_path / "a", "sqlite3", truth, tf=("tracker", "tool")), robot,
                      BagOptions(tf="tracker:tool"))
    _, true, Q = truth
    ts = typestore("ros1")
    joints, poses = campaign(robot, Q, T_of=lambda q: np.linalg.inv(true.T_meas_tool(q)))
    bag = write_bag(bag_path(tmp_path / "b", "ros1"), "ros1",
                    campaign_messages(ts, robot, joints, poses, tf=("tool", "tracker")), ts)
    inverse = read_bag(bag, robot, BagOptions(tf="tracker:tool"))
    for m in (direct, inverse):
        np.testing.assert_allclose(m.position, want.position, atol=1e-12, rtol=0)
        np.testing.assert_allclose(m.rotation, want.rotation, atol=1e-12, rtol=0)
        np.testing.assert_allclose(m.q, want.q, atol=1e-12, rtol=0)


@pytest.mark.slow
def test_a_row_is_the_mean_of_a_still_poses_samples(tmp_path, truth):
    """With noise on each instrument sample (0.05 mm, 0.1 mrad), a row is the mean of its still
    period's samples: the position mean of exactly the samples taken within the period (1e-12),
    so its error is the noise over sqrt(samples)."""
    robot, true, Q = truth
    rng = np.random.default_rng(1)
    noisy = []

    def T_of(q):
        T = true.T_meas_tool(q).copy()
        T[:3, 3] += rng.normal(0, 0.05e-3, 3)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 1e-4, 3)).as_matrix() @ T[:3, :3]
        noisy.append(T)
        return T

    ts = typestore("mcap")
    joints, poses = campaign(robot, Q, T_of=T_of)
    meas = read_bag(write_bag(bag_path(tmp_path, "mcap"), "mcap", campaign_messages(ts, robot, joints, poses), ts),
                    robot, BagOptions(pose="/tracker/pose"))
    T_true = np.array([true.T_meas_tool(q) for q in Q])
    err = np.linalg.norm(meas.position - T_true[:, :3, 3], axis=1)
    assert err.max() < 4 * 0.05e-3 * math.sqrt(3 / 90)           # ~95 samples per pose
    P = np.array([T[:3, 3] for _, T in poses])
    for k in (0, 3, N_POSES - 1):
        first = int(meas.rows[k]) - 1                              # (rows: 1-based message numbers)
        counts = [c for c in range(1, min(200, len(P) - first + 1)) if np.allclose(P[first:first + c].mean(axis=0), meas.position[k],
                                                          atol=1e-12, rtol=0)]
        assert len(counts) == 1 and 85 <= counts[0] <= 150, counts
        for t, _ in poses[first:first + counts[0]]:
            np.testing.assert_array_equal(_q_at(joints, t * 1e-9), Q[k])


def _q_at(joints, t_s):
    """The joints of the latest joint sample at or before ``t_s`` (seconds since 1970)."""
    stamps = np.array([j[0] for j in joints]) * 1e-9
    return joints[max(int(np.searchsorted(stamps, t_s, "right")) - 1, 0)][1]


def test_still_periods_and_joint_sampling():
    """still_periods: a ramp, a 1 s hold, a ramp, a 0.3 s hold: with min 0.5 s the one hold is
    found (from one window after the stop to one window before the start); joints_at: linear between neighbours,
    nearest, and the first stamp without a neighbour within the gap."""
    t = np.arange(0, 4, 0.01)
    q = np.where(t < 1, t, np.where(t < 2, 1.0, np.where(t < 3, 1 + (t - 2), 2.0)))[:, None]
    q[t >= 3.3] += (t[t >= 3.3] - 3.3)[:, None]
    periods = still_periods(t, q, np.array([math.radians(0.1)]), 0.5)
    assert periods.shape == (1, 2)
    # (a window of 50 ms that sees motion marks every sample in it: one window is lost at each end)
    assert periods[0, 0] == pytest.approx(1.05, abs=1e-9) and periods[0, 1] == pytest.approx(1.95, abs=1e-9)
    ts = np.array([0.0, 1.0, 2.0, 10.0])
    qs = np.array([[0.0], [1.0], [4.0], [5.0]])
    got, far = joints_at(np.array([0.25, 1.5, 2.0]), ts, qs, 0.8, "linear")
    assert far is None and got[:, 0].tolist() == [0.25, 2.5, 4.0]
    got, far = joints_at(np.array([0.25, 1.6]), ts, qs, 0.6, "nearest")
    assert far is None and got[:, 0].tolist() == [0.0, 4.0]
    assert joints_at(np.array([1.0, 3.0]), ts, qs, 0.6, "linear")[1] == 1
    assert joints_at(np.array([0.25]), ts, qs, 0.6, "linear")[1] == 0          # (the next sample 0.75 s away)
    assert joints_at(np.array([2.5]), ts, qs, 0.6, "nearest")[1] is None


def _messages(ts, robot, Q, *, joint_rows=None, pose_rows=None):
    """A short bag's messages: joint states at 100 Hz for 2 s at Q[0], poses at 10 Hz; rows
    (bag time ns, header stamp ns, names / frame, q / T) replace either."""
    T = robot.T_meas_tool(Q[0])
    if joint_rows is None:
        joint_rows = [(T0_NS + 10_000_000 * i, T0_NS + 10_000_000 * i, robot.joint_names, Q[0]) for i in range(200)]
    if pose_rows is None:
        pose_rows = [(T0_NS + 100_000_000 * i + 5_000_000,) * 2 + ("tracker", T) for i in range(20)]
    out = [("/joint_states", t, joint_state(ts, stamp, names, q)) for t, stamp, names, q in joint_rows]
    out += [("/tracker/pose", t, pose_stamped(ts, stamp, frame, T_)) for t, stamp, frame, T_ in pose_rows]
    return sorted(((topic, msgtype, t, msg) for topic, t, (msgtype, msg) in out), key=lambda m: m[2])


def _bad(tmp_path, capsys, messages, *extra, fmt="ros1"):
    bag = write_bag(bag_path(tmp_path, fmt), fmt, messages)
    out = tmp_path / "cal.urdf"
    code = main(["calibrate", str(BUNDLED_URDF), "--bag", str(bag), "--pose", "/tracker/pose", "-o", str(out),
                 *map(str, extra)])
    _, err = capsys.readouterr()
    assert code == 2 and not out.exists(), err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"calib: error: {bag}"), err
    return lines[0]


def test_bad_bags_are_refused_in_one_line(tmp_path, capsys, truth):
    """Topic missing, wrong type, stamps out of order, a joint the URDF lacks, a joint of the chain
    missing, no joint sample within --max-gap, a corrupt file, no still pose: exit 2, one line
    naming the bag and what is wrong, nothing written."""
    robot, _, Q = truth
    ts = typestore("ros1")
    msgs = _messages(ts, robot, Q)
    cases = {
        "no topic /other (given by --joints); the bag has /joint_states": (msgs, ("--joints", "/other")),
        "carries geometry_msgs/msg/PoseStamped, expected sensor_msgs/msg/JointState": (msgs, ("--joints", "/tracker/pose")),
        "message 6: header stamp 1700000000.050000000 s is earlier than message 5's (1700000000.060000000 s)": (_messages(ts, robot, Q, joint_rows=[
            (T0_NS + 10_000_000 * i, T0_NS + 10_000_000 * (i if i != 4 else 6), robot.joint_names, Q[0])
            for i in range(200)]), ()),
        "joint 'elbow' is not a joint of the URDF": (_messages(ts, robot, Q, joint_rows=[
            (T0_NS + 10_000_000 * i,) * 2 + (list(robot.joint_names) + ["elbow"], np.append(Q[0], 0))
            for i in range(200)]), ()),
        f"but not {robot.joint_names[-1]}": (_messages(ts, robot, Q, joint_rows=[
            (T0_NS + 10_000_000 * i,) * 2 + (robot.joint_names[:-1], Q[0][:-1]) for i in range(200)]), ()),
        "no joint sample of /joint_states within --max-gap 0.001 s": (msgs, ("--max-gap", "0.001")),
        "no still pose": (msgs, ("--min-still", "5")),
        "topic /tracker/pose, message 1: header stamp 0 s": (_messages(ts, robot, Q, pose_rows=[
            (T0_NS, 0, "tracker", robot.T_meas_tool(Q[0]))]), ()),
    }
    for k, (want, (messages, extra)) in enumerate(cases.items()):
        (tmp_path / f"c{k}").mkdir()
        assert want in _bad(tmp_path / f"c{k}", capsys, messages, *extra), want
    corrupt = tmp_path / "corrupt.bag"
    good = write_bag(bag_path(tmp_path, "ros1", "good"), "ros1", msgs)
    corrupt.write_bytes(good.read_bytes()[:len(good.read_bytes()) // 2])
    code = main(["calibrate", str(BUNDLED_URDF), "--bag", str(corrupt), "--pose", "/tracker/pose", "-o",
                 str(tmp_path / "x.urdf")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"calib: error: {corrupt}: not a readable ROS bag") and len(err.splitlines()) == 1
    assert not (tmp_path / "x.urdf").exists()


@pytest.mark.parametrize("fmt", ["sqlite3", "mcap"])
def test_a_corrupt_ros2_bag_is_refused(tmp_path, capsys, truth, fmt):
    """A ROS 2 bag whose storage file is cut in half (or garbage): one line naming the bag."""
    robot, _, Q = truth
    bag = write_bag(bag_path(tmp_path, fmt), fmt, _messages(typestore(fmt), robot, Q))
    data = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    data.write_bytes(b"\x00garbage" * 64)
    code = main(["calibrate", str(BUNDLED_URDF), "--bag", str(bag), "--pose", "/tracker/pose", "-o",
                 str(tmp_path / "x.urdf")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"calib: error: {bag}: not a readable ROS bag"), err
    assert len(err.splitlines()) == 1 and not (tmp_path / "x.urdf").exists()


def test_bag_options_are_checked_once():
    """BagOptions: one of pose and tf; PARENT:CHILD; positive speeds; a known sampling."""
    for kw in ({}, {"pose": "/p", "tf": "a:b"}, {"tf": "ab"}, {"tf": "a:a"}, {"pose": "/p", "still_rad_s": 0},
               {"pose": "/p", "sampling": "cubic"}, {"pose": "/p", "max_gap_s": -1}, {"pose": "a b"}):
        with pytest.raises(ParameterError):
            BagOptions(**kw)
    assert BagOptions(pose="tracker/pose").pose == "/tracker/pose"
    with pytest.raises(MeasurementFormatError, match="file not found"):
        read_bag("/nonexistent.bag", calib.load_robot(BUNDLED_URDF), BagOptions(pose="/p"))


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS)
def test_messages_read_in_place_are_rosbags_own_decoding(tmp_path, truth, monkeypatch, fmt):
    """calib.io.bag.layout reads a message's stamp and numbers in place when its layout is one
    rosbags decoded: a campaign whose joint states alternate between two name orders (two
    layouts) reads to the same arrays, bit for bit, as with every message decoded by rosbags."""
    from calib.io.bag import stream
    from calib.io.bag.layout import Layouts

    robot, true, Q = truth
    ts = typestore(fmt)
    joints, poses = campaign(robot, Q[:4], T_of=true.T_meas_tool)
    order = np.arange(robot.n_joints)[::-1]
    messages = []
    for i, (t, q) in enumerate(joints):
        names, q = (robot.joint_names, q) if i % 2 else ([robot.joint_names[j] for j in order], np.asarray(q)[order])
        msgtype, msg = joint_state(ts, t, names, q)
        messages.append(("/joint_states", msgtype, t, msg))
    for t, T in poses:
        msgtype, msg = pose_stamped(ts, t, "tracker", T)
        messages.append(("/tracker/pose", msgtype, t, msg))
    bag = write_bag(bag_path(tmp_path, fmt), fmt, sorted(messages, key=lambda m: m[2]), ts)

    def streams():
        reader = stream.open_bag(bag)
        try:
            return stream.read_streams(bag, reader, joints="/joint_states", chain=tuple(robot.joint_names),
                                       urdf_joints=robot.joint_names, pose="/tracker/pose")
        finally:
            reader.close()

    learned = []
    original = Layouts.learn
    monkeypatch.setattr(Layouts, "learn", lambda self, *a, **k: (original(self, *a, **k), learned.append(len(self.known))))
    fast = streams()
    assert max(learned) == 2                       # (two joint layouts; the pose topic's one)
    monkeypatch.setattr(Layouts, "learn", lambda self, *a, **k: None)
    slow = streams()
    for a, b in ((fast[0].t_ns, slow[0].t_ns), (fast[0].q, slow[0].q), (fast[0].index, slow[0].index),
                 (fast[1].t_ns, slow[1].t_ns), (fast[1].position, slow[1].position),
                 (fast[1].quaternion, slow[1].quaternion)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(fast[0].q[-1], Q[3], atol=1e-15, rtol=0)


def test_calib_formats_lists_bags(capsys):
    """calib formats says how bags are read (topics, types, still poses, rows)."""
    assert main(["formats"]) == 0
    out = capsys.readouterr().out
    assert "ROS bags (calibrate --bag FILE" in out and "sensor_msgs/JointState" in out and "--still VEL" in out
    assert calib.read_bag is read_bag and calib.BagOptions is BagOptions


def test_bag_options_on_the_command_line_are_checked_first(tmp_path, capsys):
    """MEAS.csv or --bag, once; --pose / --tf only with --bag, one of them; CSV options refused
    with a bag: one line, exit 2, before the robot is read (a missing URDF is not the error)."""
    robot, out = tmp_path / "absent.urdf", tmp_path / "x.urdf"
    for extra, want in (([], "give the measurements: MEAS.csv, or a ROS bag"),
                        (["m.csv", "--bag", "b.bag", "--pose", "/p"], "give the measurements once"),
                        (["m.csv", "--pose", "/p"], "--pose is for a ROS bag"),
                        (["--bag", "b.bag"], "--bag b.bag: give the instrument's pose"),
                        (["--bag", "b.bag", "--pose", "/p", "--tf", "a:b"], "one of the two"),
                        (["--bag", "b.bag", "--pose", "/p", "--key", "P", "--euler", "ZYX"],
                         "--euler, --key are for CSV files, not a ROS bag")):
        assert main(["calibrate", str(robot), *extra, "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and want in err, (extra, err)
    assert not out.exists()


def test_without_the_ros_extra_the_error_names_it(tmp_path):
    """Without rosbags importable, calibrate --bag says which extra to install (exit 2, one line)."""
    import os
    import subprocess
    import sys

    from conftest import ROOT

    (tmp_path / "shadow" / "rosbags").mkdir(parents=True)
    (tmp_path / "shadow" / "rosbags" / "__init__.py").write_text("raise ImportError('no rosbags here')\n")
    (tmp_path / "b.bag").write_bytes(b"#ROSBAG V2.0\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path / 'shadow'}{os.pathsep}{ROOT}")
    run = subprocess.run([sys.executable, "-m", "calib", "calibrate", str(BUNDLED_URDF), "--bag", "b.bag", "--pose",
                          "/p", "-o", "x.urdf"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "b.bag: reading a ROS bag needs the optional 'ros' dependencies" in run.stderr
    assert "pip install 'calib[ros]'" in run.stderr and not (tmp_path / "x.urdf").exists()
