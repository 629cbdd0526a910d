"""Hostile input and faults (issue 13): a corpus of bad inputs, each refused cleanly.

Every CLI case asserts the exit code, the exact shape of stderr (one line ``calib: error: ...``;
usage errors: the usage line and that line) with a fragment naming what is wrong, and that no
file of the output folder changed (outputs from an earlier run are left as they were, no
temporary file is left behind). API cases assert a :class:`calib.CalibError` subclass naming the
argument. CLI cases run in-process through ``calib.cli.main.main`` (fast); signals need subprocesses.
"""
from __future__ import annotations

import errno
import os
import re
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import calib
from calib.cli.main import main
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations
from calib.solvers.lm import LMOptions

from conftest import BUNDLED_URDF, ROOT

URDF = str(BUNDLED_URDF)
OLD = b"output of an earlier run\n"


# ====================================================================== helpers
def _simulated_csv(tmp_path_factory, folder: str, name: str, n: int, seed: int):
    """(folder, robot, measurements): n noisy poses of the bundled robot with the paper's
    deviations, written to folder / name."""
    d = tmp_path_factory.mktemp(folder)
    robot = calib.load_robot(URDF)
    rng = np.random.default_rng(seed)
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = calib.simulate_measurements(true, robot.random_configurations(n, rng), rng=rng)
    calib.write_measurements(d / name, meas)
    return d, robot, meas


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """40 noisy poses of the bundled robot with the paper's deviations (seed 3), as a CSV."""
    return _simulated_csv(tmp_path_factory, "hostile_data", "cal.csv", 40, 3)


@pytest.fixture
def out(tmp_path):
    """An output folder holding the outputs of an earlier run."""
    folder = tmp_path / "out"
    folder.mkdir()
    for name in ("calibrated.urdf", "report.json", "poses.csv", "meas.csv"):
        (folder / name).write_bytes(OLD)
    return folder


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def run_cli(capfd, argv) -> tuple[int, str, str]:
    """main(argv) in-process; stdout and stderr captured at the file-descriptor level (so that
    what C code such as Pinocchio's parser prints is caught too)."""
    code = main([str(a) for a in argv])
    o, e = capfd.readouterr()
    return code, o, e


def assert_refused(code, err, fragment, *, usage=False):
    lines = err.splitlines()
    assert code == 2, err
    if usage:
        assert len(lines) == 2 and lines[0].startswith("usage: calib"), err
        lines = lines[1:]
    assert len(lines) == 1 and err.endswith("\n"), err
    assert lines[0].startswith("calib: error: "), err
    assert re.search(fragment, lines[0]), (fragment, lines[0])


# ====================================================================== CSV
def _csv_cases():
    def edit_field(lines, row, col, value):
        out = list(lines)
        fields = out[row].split(",")
        fields[col] = value
        out[row] = ",".join(fields)
        return out

    header = 0  # the header is line 1 (index 0); data from line 2
    return {
        "text in a number": (lambda L: edit_field(L, header + 3, 7, "abc"), r"row 4.*'y_mm'"),
        "NaN position": (lambda L: edit_field(L, header + 2, 6, "nan"), r"row 3.*'x_mm'"),
        "infinite joint": (lambda L: edit_field(L, header + 1, 0, "inf"), r"row 2.*'joint1_deg'"),
        "column missing": (lambda L: [",".join(l.split(",")[:6] + l.split(",")[7:]) if not
                                      l.startswith("#") else l for l in L], r"y_mm|x_mm|position"),
        "100 identical rows": (lambda L: L[:header + 2] + [L[header + 1]] * 99,
                               r"1 distinct configuration"),
        "positions x 1e9": (lambda L: L[:header + 1] + [",".join(f[:6] + [repr(float(v) * 1e9) for v in f[6:9]] + f[9:])
                                                        for f in (l.split(",") for l in L[header + 1:])],
                            r"row\(s\) 2, 3, 4.*farther than any tracker"),
        "one row at 1e12 mm": (lambda L: edit_field(L, header + 5, 6, "1e12"), r"row\(s\) 6: .*farther"),
        "header only": (lambda L: L[:header + 1], r"no data rows"),
        "empty file": (lambda L: [], r"file is empty"),
        "binary": (None, r"not UTF-8"),
    }


CSV_CASES = _csv_cases()


@pytest.mark.parametrize("case", list(CSV_CASES))
def test_bad_csv_refused_with_one_line_and_outputs_unchanged(case, sim, out, tmp_path, capfd):
    d, _, _ = sim
    edit, fragment = CSV_CASES[case]
    lines = (d / "cal.csv").read_text().splitlines()
    bad = tmp_path / "bad.csv"
    if edit is None:
        bad.write_bytes(b"joint1_deg,x_mm\n\xff\xfe\x00\x01garbage\n")
    else:
        bad.write_text("\n".join(edit(lines)) + ("\n" if edit(lines) else ""))
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["calibrate", URDF, bad, "-o", out / "calibrated.urdf",
                                   "--report", out / "report.json"])
    assert_refused(code, err, fragment)
    assert snapshot(out) == before


# ====================================================================== URDF
def _urdf_variant(name: str) -> str:
    text = BUNDLED_URDF.read_text()
    first_axis = re.compile(r'<axis xyz="[^"]*"/>')
    first_limit = re.compile(r'<limit lower="[^"]*" upper="[^"]*"')
    return {
        "zero axis": lambda: first_axis.sub('<axis xyz="0 0 0"/>', text, count=1),
        "NaN axis": lambda: first_axis.sub('<axis xyz="0 nan 1"/>', text, count=1),
        "lower > upper": lambda: first_limit.sub('<limit lower="2" upper="-2"', text, count=1),
        "zero range": lambda: first_limit.sub('<limit lower="0.5" upper="0.5"', text, count=1),
        "text origin": lambda: re.sub(r'rpy="[^"]*"', 'rpy="a b c"', text, count=1),
        "infinite origin": lambda: text.replace('<origin xyz="0 0 0" rpy="0 0 0"/>',
                                                '<origin xyz="0 0 inf" rpy="0 0 0"/>', 1),
        "no limits (Pinocchio refuses)": lambda: re.sub(r'<limit [^>]*/>', '', text, count=1),
    }[name]()


URDF_CASES = {
    "zero axis": r"joint 'joint1': <axis xyz=\"0 0 0\"> is a zero vector",
    "NaN axis": r"joint 'joint1': <axis xyz=\"0 nan 1\"> is not 3 finite numbers",
    "lower > upper": r"joint 'joint1': <limit lower=\"2\" upper=\"-2\"> has lower > upper",
    "zero range": r"joint 'joint1' .* limits lower = upper = 0.5: it cannot move",
    "text origin": r"<origin rpy=\"a b c\"> is not 3 finite numbers",
    "infinite origin": r"joint 'meas_to_base': <origin xyz=\"0 0 inf\"> is not 3 finite numbers",
    "no limits (Pinocchio refuses)": r"Pinocchio cannot build a model: Joint \[joint1\] is of type "
                                     r"REVOLUTE but it does not specify limits",
}


@pytest.mark.parametrize("case", list(URDF_CASES))
def test_bad_urdf_refused_with_one_line(case, sim, out, tmp_path, capfd):
    d, _, _ = sim
    urdf = tmp_path / "bad.urdf"
    urdf.write_text(_urdf_variant(case))
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["calibrate", urdf, d / "cal.csv", "-o", out / "calibrated.urdf"])
    assert_refused(code, err, URDF_CASES[case])    # nothing from Pinocchio's parser besides
    assert snapshot(out) == before
    code, stdout, err = run_cli(capfd, ["identifiability", urdf])
    assert_refused(code, err, URDF_CASES[case])
    assert stdout == ""


def test_pinocchio_parser_output_never_reaches_the_terminal(tmp_path, capfd):
    """A NaN in a visual origin: Pinocchio's parser prints an error and goes on (the visual does
    not matter to the kinematics); what it printed is captured, not shown."""
    urdf = tmp_path / "visual.urdf"
    urdf.write_text(BUNDLED_URDF.read_text().replace('<origin xyz="0 0 0.05"/>', '<origin xyz="nan 0 0.05"/>', 1))
    code, stdout, err = run_cli(capfd, ["identifiability", urdf])
    assert (code, err) == (0, "")
    assert "identifiable" in stdout


# ====================================================================== options
OPTION_CASES = {
    # (extra arguments of calibrate, fragment, usage error?)
    "sigma 1e-300": (["--sigma-pos-mm", "1e-300"], r"sigma_pos must be between 1e-12 and 1", False),
    "sigma nan": (["--sigma-pos-mm", "nan"], r"argument --sigma-pos-mm: nan must be a finite number", True),
    "sigma -1": (["--sigma-rot-rad", "-1"], r"argument --sigma-rot-rad: -1 must be a finite number > 0$", True),
    "sigma 0": (["--sigma-pos-mm", "0"], r"argument --sigma-pos-mm: 0 must be a finite number > 0$", True),
    "params empty": (["--params", ""], r"empty parameter list ''", False),
    "params comma": (["--params", ","], r"empty parameter list ','", False),
    "params unknown": (["--params", "d2,bogus"], r"bogus", False),
    "cv -1": (["--cv", "-1"], r"argument --cv: -1 must not be negative", True),
    "cv 1": (["--cv", "1"], r"cv must be 0 \(off\) or a number of folds >= 2", False),
    "outlier-k -1": (["--outlier-k", "-1"], r"argument --outlier-k", True),
    "outlier-k inf": (["--outlier-k", "inf"], r"argument --outlier-k", True),
    "method": (["--method", "newton"], r"argument --method: invalid choice: 'newton'", True),
    "loss": (["--loss", "bogus"], r"argument --loss: invalid choice: 'bogus'", True),
    "unknown option": (["--bogus"], r"unrecognized arguments: --bogus", True),
    "limit tolerance": (["--limit-tolerance", "2"], r"argument --limit-tolerance: 2 must be between 0 and 1", True),
    "euler": (["--euler", "XXY"], r"--euler 'XXY' is not an Euler sequence", True),
}


@pytest.mark.parametrize("case", list(OPTION_CASES))
def test_bad_option_refused(case, sim, out, capfd):
    d, _, _ = sim
    extra, fragment, usage = OPTION_CASES[case]
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", out / "calibrated.urdf", *extra])
    assert_refused(code, err, fragment, usage=usage)
    if usage:
        assert err.splitlines()[0] == ("usage: calib calibrate [options] ROBOT.urdf MEAS.csv -o "
                                       "CALIBRATED.urdf  (help: calib calibrate --help)")
    assert snapshot(out) == before


COMMAND_CASES = {
    "no command": ([], r"the following arguments are required: COMMAND"),
    "missing output": (["calibrate", URDF, "{cal}"], r"required: -o/--output"),
    "poses 0": (["identifiability", URDF, "--poses", "0"], r"argument --poses: 0 must be at least 1"),
    "simulate negative noise": (["simulate", URDF, "-o", "{out}/meas.csv", "--sigma-pos-mm", "-0.1"],
                                r"--sigma-pos-mm: -0.1 must be a finite number >= 0"),
    "select-poses n=0": (["select-poses", URDF, "-n", "0", "-o", "{out}/poses.csv"], r"-n.*0"),
}


@pytest.mark.parametrize("case", list(COMMAND_CASES))
def test_usage_errors_are_two_lines(case, sim, out, capfd):
    d, _, _ = sim
    argv, fragment = COMMAND_CASES[case]
    argv = [a.format(cal=d / "cal.csv", out=out) for a in argv]
    before = snapshot(out)
    code, _, err = run_cli(capfd, argv)
    assert_refused(code, err, fragment, usage=True)
    assert snapshot(out) == before


def test_simulate_deviations_out_of_range_is_one_line(out, capfd):
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["simulate", URDF, "-o", out / "meas.csv", "--deviations", "random:nan"])
    assert_refused(code, err, r"--deviations random:nan: expected random:SCALE_MM")
    assert snapshot(out) == before


# ====================================================================== outputs as a set
def test_unwritable_report_folder_leaves_the_urdf_unchanged(sim, out, capfd):
    """/proc exists and is a folder, but no file can be created in it (even as root)."""
    d, _, _ = sim
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", out / "calibrated.urdf",
                                   "--report", "/proc/calib-report.json", "--params", "paper", "--cv", "0"])
    assert_refused(code, err, r"^calib: error: /proc/calib-report.json: cannot write in folder /proc")
    assert snapshot(out) == before


@pytest.mark.parametrize("command", ["calibrate", "evaluate"])
@pytest.mark.parametrize("inside", [False, True])
def test_plots_naming_a_file_is_one_line_saying_it_takes_a_folder(command, inside, sim, out, capfd):
    """--plots FILE (an existing regular file, or a folder under one) printed
    '.../position_errors.png: cannot be inspected: Not a directory'."""
    d, _, _ = sim
    plots = out / "report.json" / "plots" if inside else out / "report.json"
    argv = ["calibrate", URDF, d / "cal.csv", "-o", out / "calibrated.urdf"] if command == "calibrate" \
        else ["evaluate", URDF, d / "cal.csv"]
    before = snapshot(out)
    code, _, err = run_cli(capfd, [*argv, "--plots", plots])
    where = f"{out / 'report.json'} is a file" if inside else "is a file"
    assert_refused(code, err, "^calib: error: " + re.escape(f"--plots {plots}: {where}, not a folder; --plots "
                                                            f"takes a folder, into which it writes position_errors.png"))
    assert snapshot(out) == before


def test_full_disk_on_the_second_output_changes_nothing(sim, out, capfd, monkeypatch):
    d, _, _ = sim
    import calib.io.fileio as fileio

    calls = []
    real_fsync = os.fsync

    def fsync(fd):
        calls.append(os.readlink(f"/proc/self/fd/{fd}"))
        if "report.json" in calls[-1]:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(fileio.os, "fsync", fsync)
    before = snapshot(out)
    code, _, err = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", out / "calibrated.urdf",
                                   "--report", out / "report.json", "--params", "paper", "--cv", "0"])
    assert_refused(code, err, r"/out/report.json: cannot be written: No space left on device")
    assert sum("report.json" in c for c in calls) == 1
    assert snapshot(out) == before           # calibrated.urdf not replaced, no temporary left


def test_failed_rename_puts_back_the_outputs_already_replaced(tmp_path, monkeypatch):
    import calib.io.fileio as fileio

    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"
    a.write_bytes(b"old a")
    c.write_bytes(b"old c")
    real_replace = os.replace
    done = []

    def replace_(src, dst):
        if str(dst) == str(c) and str(src).endswith(".tmp"):
            raise OSError(errno.EROFS, "Read-only file system")
        done.append(dst)
        return real_replace(src, dst)

    monkeypatch.setattr(fileio.os, "replace", replace_)
    outputs = fileio.OutputSet()
    for path in (a, b, c):
        outputs.stage(path, b"new")
    with pytest.raises(calib.OutputError, match=r"c.txt: cannot be replaced: Read-only file system"):
        outputs.commit()
    assert snapshot(tmp_path) == {"a.txt": b"old a", "c.txt": b"old c"}


def test_output_set_creates_its_folder_only_when_it_succeeds(tmp_path, monkeypatch):
    import calib.io.fileio as fileio

    outputs = fileio.OutputSet()
    outputs.make_folder(tmp_path / "plots")
    outputs.stage(tmp_path / "plots" / "p.png", b"png")
    outputs.stage(tmp_path / "missing" / "x.json", b"{}")
    with pytest.raises(calib.OutputError, match=r"x.json: folder .*missing does not exist"):
        outputs.commit()
    assert list(tmp_path.iterdir()) == []


# ====================================================================== signals
@pytest.fixture(scope="module")
def big_csv(tmp_path_factory):
    """20,000 poses: calibrate takes several seconds, long enough to be interrupted."""
    return _simulated_csv(tmp_path_factory, "hostile_big", "big.csv", 20_000, 5)[0] / "big.csv"


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_ends_with_one_line_and_no_partial_files(signum, code, big_csv, out):
    """A real signal to a real process, sent once it logs that the fit started (-v): the last
    stderr line says so, no traceback, no output created or changed."""
    before = snapshot(out)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # (SIGINT at its default disposition: a shell's background job inherits it ignored, and a
    # program rightly keeps it so)
    proc = subprocess.Popen([sys.executable, "-m", "calib", "calibrate", URDF, str(big_csv), "-o",
                             str(out / "calibrated.urdf"), "--report", str(out / "report.json"),
                             "--plots", str(out / "plots"), "-v"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    log = []
    for line in proc.stderr:
        log.append(line)
        if "calibrating (" in line:
            break
    time.sleep(0.5)
    assert proc.poll() is None, "calibrate ended before the signal"
    proc.send_signal(signum)
    stdout, rest = proc.communicate(timeout=60)
    lines = (log + rest.splitlines(keepends=True))
    assert proc.returncode == code, "".join(lines)
    assert lines[-1] == f"calib: interrupted by {signal.Signals(signum).name}\n"
    assert all(l.startswith("calib: ") for l in lines), "".join(lines)   # no traceback
    assert "wrote" not in stdout
    assert snapshot(out) == before


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_in_process_prints_exactly_one_line(signum, code, sim, out, capfd, monkeypatch):
    """The signal arrives in the middle of the fit (sent by the patched calibrate to its own
    process): exit 128 + signal, stderr exactly one line, nothing written."""
    # the commands call the API through the package: patch it there

    d, _, _ = sim
    real = calib.calibrate
    # Python's KeyboardInterrupt handler, as in a foreground process (a background job of a
    # shell inherits SIGINT ignored; the test is about what calib does with it)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)

    def interrupted(*args, **kwargs):
        os.kill(os.getpid(), signum)
        time.sleep(5)     # the handler raises at once; never reached
        return real(*args, **kwargs)

    monkeypatch.setattr(calib, "calibrate", interrupted)
    before = snapshot(out)
    try:
        code_, stdout, err = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", out / "calibrated.urdf"])
    finally:
        signal.signal(signal.SIGINT, previous)
    assert (code_, stdout, err) == (code, "", f"calib: interrupted by {signal.Signals(signum).name}\n")
    assert snapshot(out) == before


# ====================================================================== data that cannot identify the model
def test_gross_row_left_out_of_the_frame_estimate_and_flagged(sim):
    """One row 100 m off (within reach + tracker range, so not refused): the closed-form frame
    estimate leaves it out, the fit flags it, and the parameters are recovered as without it."""
    _, robot, meas = sim
    pos = meas.position.copy()
    pos[7] += [100.0, 0.0, 0.0]
    res = calib.calibrate(robot, replace(meas, position=pos), params="base", cv=0)
    clean = calib.calibrate(robot, meas, params="base", cv=0)
    assert res.status == "converged"
    assert [o.row for o in res.outliers] == [8]
    assert any("1 row(s) left out of the closed-form frame estimate" in n and "rows 8" in n
               for n in res.notes)
    # the other 39 rows determine the parameters: within 3 standard deviations of the clean fit
    for p, q in zip(res.parameters, clean.parameters):
        if np.isfinite(q.std) and q.std > 0:
            assert abs(p.identified - q.identified) < 3 * q.std + 1e-9, p.name


@pytest.mark.slow
def test_data_that_do_not_fit_the_robot_get_a_note_not_silence(sim):
    """Every joint value divided by 57.3 (a radian column named _deg): within the limits, so
    the reader cannot tell. The fit leaves errors of a third of a metre; it said only that it
    stopped at the iteration limit (UR5: converged, exit 0). A clean fit gets no such note.
    Quaternions in x, y, z, w order read as w, x, y, z: 1.4 rad RMS left (UR5: converged, exit 0,
    nothing said); the note names the orientation columns."""
    from calib.calibration.prepare import robot_reach

    _, robot, meas = sim
    res = calib.calibrate(robot, replace(meas, q=np.radians(meas.q)), params="base", cv=0,
                          outlier_k=None)
    pos_rms = res.after.position["rms"]
    assert pos_rms > 0.05                                   # metres: nothing like a calibration
    reach = robot_reach(robot)                                # metres: 1.225 m for this robot
    bad = [n for n in res.notes if n.startswith("the calibrated model does not describe")]
    assert bad == [f"the calibrated model does not describe these measurements: on the calibration "
                   f"rows it leaves a position RMS error of {pos_rms * 1e3:.4g} mm "
                   f"({100 * pos_rms / reach:.0f} % of the robot's reach {reach * 1e3:.0f} mm) and an "
                   f"orientation RMS error of {res.after.rotation['rms']:.3g} rad; check the joint "
                   f"units (degrees read as radians, or radians as degrees), the joint order and the "
                   f"robot, and the orientation columns (quaternion order w, x, y, z; --euler "
                   f"sequence; a rotation vector read as angles: --convention ur; angle units) and the "
                   f"tool frame"]
    clean = calib.calibrate(robot, meas, params="base", cv=0)
    assert not any("does not describe" in n for n in clean.notes)
    # quaternions written x, y, z, w and read as w, x, y, z: the note names the orientation
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(meas.rotation).as_quat()            # written x, y, z, w
    swapped = Rotation.from_quat(np.roll(xyzw, -1, axis=1)).as_matrix()   # read as w, x, y, z
    res = calib.calibrate(robot, replace(meas, rotation=swapped), params="base", cv=0)
    bad = [n for n in res.notes if n.startswith("the calibrated model does not describe")]
    assert len(bad) == 1 and res.after.rotation["rms"] > 0.1
    assert (f"an orientation RMS error of {res.after.rotation['rms']:.3g} rad; check " in bad[0]
            and bad[0].endswith("the orientation columns (quaternion order w, x, y, z; --euler sequence; "
                                "a rotation vector read as angles: --convention ur; angle units) and the "
                                "tool frame"))


@pytest.mark.slow
def test_positions_in_metres_named_mm_get_a_note(sim):
    """Positions in metres in _mm columns: 1000 times too small, the fit shrinks the robot (a2
    by 350 mm, d4 by 364 mm) and converges at 3e-5 mm, exit 0 and nothing said. The identified
    link lengths are now named; a clean fit names none."""
    from calib.calibration.prepare import robot_reach

    _, robot, meas = sim
    res = calib.calibrate(robot, replace(meas, position=meas.position / 1000), params="base", cv=0)
    reach = robot_reach(robot)
    far = [n for n in res.notes if n.startswith("identified link lengths far from the URDF's")]
    assert len(far) == 1 and far[0].endswith(
        f"(more than 10 % of the robot's reach {reach * 1e3:.0f} mm); check the length unit of the "
        f"positions (metres named _mm?) and that the URDF is this robot's")
    a2 = next(p for p in res.parameters if p.name == "a2")
    assert abs(a2.deviation) > 0.1 * reach and f"a2 {a2.deviation * 1e3:+.1f} mm" in far[0]
    clean = calib.calibrate(robot, meas, params="base", cv=0).notes
    assert not any("link lengths far" in n or n.startswith("parameters moved") for n in clean)


def test_copied_rows_get_a_note(sim):
    """Rows 1-10 pasted again as rows 31-40 (the last copy's y changed by 1 nm: a measurement,
    not a copy), and three calibration rows copied as validation rows. Copies made a UR5 fit's
    Cramer-Rao accuracy 10 times too optimistic (0.004 mm; true 0.039 mm) with nothing said."""
    _, robot, meas = sim
    m = meas.subset(np.r_[0:30, 0:10])
    pos = m.position.copy()
    pos[39, 1] += 1e-9
    m = replace(m, position=pos, rows=np.arange(1, 41))
    res = calib.calibrate(robot, m, params="base", cv=0)
    assert [n for n in res.notes if "repeat" in n] == [
        "9 calibration row(s) repeat an earlier row exactly (joints and measured pose; row = earlier "
        "row: 31 = 1, 32 = 2, 33 = 3, 34 = 4, 35 = 5, 36 = 6, 37 = 7, 38 = 8 and 1 more): a copy is "
        "not a new measurement, but the noise estimate, the standard deviations and the predicted "
        "errors count it as one and are too optimistic; remove the copies"]
    leak = replace(meas.subset(np.r_[0:30, 0:3]), rows=np.arange(1, 34),
                   sets=np.array(["cal"] * 30 + ["val"] * 3))
    res = calib.calibrate(robot, leak, params="base", cv=0)
    assert [n for n in res.notes if "repeat" in n] == [
        "3 validation row(s) repeat a calibration row exactly (validation row = calibration row: "
        "31 = 1, 32 = 2, 33 = 3): they are not held out, and the validation errors are too optimistic"]
    assert not any("repeat" in n for n in calib.calibrate(robot, meas, params="base", cv=0).notes)


def test_robust_frame_estimate_ignores_a_row_a_million_km_off(sim):
    from calib.calibration.frames import estimate_frames, estimate_frames_robust

    _, robot, meas = sim
    pos = meas.position.copy()
    pos[3] += 1e9
    est = estimate_frames_robust(robot, meas.q, pos, meas.rotation)
    X_clean, Y_clean = estimate_frames(robot, meas.q, meas.position, meas.rotation)
    assert np.flatnonzero(~est.inliers).tolist() == [3]
    # the same rows as the clean estimate without row 3: within the nominal structure's error (mm)
    assert np.linalg.norm(est.T_meas_base[:3, 3] - X_clean[:3, 3]) < 5e-3
    assert np.linalg.norm(est.T_flange_tool[:3, 3] - Y_clean[:3, 3]) < 5e-3


def test_data_that_do_not_move_a_joint_are_refused_naming_the_parameters(sim):
    _, robot, meas = sim
    q = meas.q.copy()
    q[:, 5] = 0.3
    with pytest.raises(calib.DataError, match=r"the 40 calibration rows \(40 distinct configurations\) "
                                              r"identify \d+ parameter combinations, random poses 30: "
                                              r"the rows cannot identify .*a6"):
        calib.calibrate(robot, replace(meas, q=q))


def test_distinct_configurations_counts_repeats_once():
    from calib.calibration.prepare import distinct_configurations

    Q = np.array([[0.1, 0.2], [0.1, 0.2], [0.1, 0.2 + 1e-12], [0.3, 0.2]])
    assert distinct_configurations(Q) == 2


def test_file_too_large_for_the_memory_is_refused_before_reading(sim, monkeypatch):
    import calib.io.csv.lines as layer     # (the text of files: calib.io.csv.lines)

    d, robot, _ = sim
    size = (d / "cal.csv").stat().st_size
    monkeypatch.setattr(layer, "available_memory", lambda: int(size * layer.READ_BYTES_PER_FILE_BYTE) - 1)
    with pytest.raises(calib.MeasurementFormatError, match=r"cal.csv: 0 MB: reading it needs about "
                                                           r"0.0 GB of memory"):
        calib.read_measurements(d / "cal.csv", robot)


# ====================================================================== quiet stderr
def test_zyx_parameters_at_gimbal_lock_warns_nothing():
    from calib.model.spatial import zyx_parameters, zyx_transform

    T = zyx_transform(0.1, 0.2, 0.3, 0.4, np.pi / 2, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        x = zyx_parameters(T)
    np.testing.assert_allclose(zyx_transform(*x), T, atol=1e-12)   # an equivalent triple


def test_library_warnings_do_not_reach_stderr(sim, capfd, monkeypatch):
    """Warnings raised inside a command (numpy's overflow, scipy's gimbal lock) are logged at
    debug level only: stderr stays empty."""
    # the commands call the API through the package: patch it there

    d, _, _ = sim
    real = calib.evaluate

    def noisy(robot, meas):
        np.float64(1e308) * np.float64(10.0)          # RuntimeWarning: overflow encountered
        warnings.warn("Gimbal lock detected. Setting third angle to zero", UserWarning)
        return real(robot, meas)

    monkeypatch.setattr(calib, "evaluate", noisy)
    with warnings.catch_warnings():
        # as outside pytest: warnings shown on stderr, each time
        warnings.simplefilter("always")
        monkeypatch.setattr(warnings, "showwarning", lambda message, category, filename, lineno, file=None,
                            line=None: sys.stderr.write(warnings.formatwarning(message, category, filename, lineno)))
        code, stdout, err = run_cli(capfd, ["evaluate", URDF, d / "cal.csv"])
    assert (code, err) == (0, "")
    assert "Accuracy of" in stdout


# ====================================================================== API
def _api_cases(robot, meas):
    return {
        "calibrate loss": (lambda: calib.calibrate(robot, meas, loss="bogus"), calib.ParameterError, r"unknown loss 'bogus'"),
        "calibrate params []": (lambda: calib.calibrate(robot, meas, params=[]), calib.ParameterError, r"params is an empty list"),
        "calibrate outlier_k": (lambda: calib.calibrate(robot, meas, outlier_k=-1), calib.ParameterError, r"outlier_k"),
        "calibrate init_frames": (lambda: calib.calibrate(robot, meas, init_frames="never"), calib.ParameterError, r"init_frames"),
        "calibrate sigma tiny": (lambda: calib.calibrate(robot, meas, sigma_pos=1e-300), calib.ParameterError, r"sigma_pos"),
        "calibrate robot str": (lambda: calib.calibrate("robot.urdf", meas), calib.ParameterError, r"robot must be a RobotModel"),
        "identifiability n_poses 0": (lambda: calib.analyze_identifiability(robot, n_poses=0), calib.ParameterError, r"n_poses must be at least 1"),
        "identifiability Q shape": (lambda: calib.analyze_identifiability(robot, np.zeros((3, 2))), calib.DataError, r"Q must have shape \(N, 6\)"),
        "identifiability tol": (lambda: calib.analyze_identifiability(robot, tol=float("nan")), calib.ParameterError, r"tol must be a finite number"),
        "read robot None": (lambda: calib.read_measurements(ROOT / "x.csv", None), calib.ParameterError, r"robot must be a RobotModel"),
        "read path int": (lambda: calib.read_measurements(3, robot), calib.ParameterError, r"csv_path must be a file path"),
        "read options": (lambda: calib.read_measurements(ROOT / "x.csv", robot, options={}), calib.ParameterError, r"options must be a ReadOptions"),
        "apply NaN": (lambda: calib.apply_deviations(robot, {"d2": float("nan")}), calib.ParameterError, r"deviations\['d2'\] must be a finite number"),
        "apply text": (lambda: calib.apply_deviations(robot, {"d2": "0.1"}), calib.ParameterError, r"deviations\['d2'\] must be a number"),
        "apply list": (lambda: calib.apply_deviations(robot, [("d2", 0.1)]), calib.ParameterError, r"deviations must be a mapping"),
        "load threshold NaN": (lambda: calib.load_robot(URDF, parallel_threshold=float("nan")), calib.ParameterError, r"parallel_threshold must be a finite number"),
        "load path None": (lambda: calib.load_robot(None), calib.ParameterError, r"urdf_path must be a file path"),
        "load frame int": (lambda: calib.load_robot(URDF, tool_frame=3), calib.ParameterError, r"tool_frame must be a frame name"),
        "evaluate str": (lambda: calib.evaluate(robot, "meas.csv"), calib.ParameterError, r"measurements must be a Measurements"),
        "simulate Q 1-D": (lambda: calib.simulate_measurements(robot, np.zeros(6)), calib.DataError, r"Q must have shape \(N, 6\)"),
        "simulate sigma": (lambda: calib.simulate_measurements(robot, np.zeros((2, 6)), sigma_pos=-1), calib.ParameterError, r"sigma_pos must be >= 0"),
        "simulate rng": (lambda: calib.simulate_measurements(robot, np.zeros((2, 6)), rng="seed"), calib.ParameterError, r"rng must be None, an integer seed"),
        "random scale": (lambda: calib.random_deviations(robot, float("inf")), calib.ParameterError, r"scale must be a finite number"),
        "select_poses seed": (lambda: calib.select_poses(robot, 10, seed=1.5), calib.ParameterError, r"seed must be None, an integer seed"),
        "select_poses sigma": (lambda: calib.select_poses(robot, 10, sigma_pos=float("nan")), calib.ParameterError, r"sigma_pos must be a finite number"),
        "compensate robot": (lambda: calib.compensate(robot, None, np.zeros((1, 6))), calib.ParameterError, r"nominal must be a RobotModel"),
        "jacobian measure": (lambda: calib.identification_jacobian(robot, np.zeros((1, 6)), "speed"), calib.ParameterError, r"measure must be one of pose, position"),
        "jacobian Q NaN": (lambda: calib.identification_jacobian(robot, np.full((2, 6), np.nan)), calib.DataError, r"Q row 0 holds NaN"),
        "write_calibrated_urdf path": (lambda: calib.write_calibrated_urdf(robot, None), calib.ParameterError, r"path must be a file path"),
        "write_measurements data": (lambda: calib.write_measurements(ROOT / "never.csv", "data"), calib.ParameterError, r"measurements must be a Measurements"),
        "write_poses q": (lambda: calib.write_poses(ROOT / "never.csv", robot, [[1, 2]]), calib.DataError, r"q must have shape \(N, 6\)"),
        "LMOptions ftol": (lambda: calib.calibrate(robot, meas, options=LMOptions(ftol=float("nan"))), calib.ParameterError, r"LMOptions.ftol must be a finite number"),
        "LMOptions lam": (lambda: LMOptions(lam=0.5), calib.ParameterError, r"LMOptions.lam must be > 1"),
        "robot_path int": (lambda: calib.robot_path(7), calib.ParameterError, r"robot must be a file path"),
    }


API_CASE_NAMES = list(_api_cases(None, None))


@pytest.mark.parametrize("case", API_CASE_NAMES)
def test_api_refuses_bad_arguments_with_a_calib_error(case, sim):
    _, robot, meas = sim
    call, exc, fragment = _api_cases(robot, meas)[case]
    with pytest.raises(exc, match=fragment):
        call()
    assert not (ROOT / "never.csv").exists()


# (the API fuzz: tests/scenarios/test_api_fuzz.py, over every public name)


def test_special_files_are_never_replaced_and_symlinks_are_written_through(sim, tmp_path, capfd):
    """A FIFO (like a device such as /dev/null) as an output is refused before any work; an
    output path that is a symbolic link writes the file it names and keeps the link."""
    import os
    import stat

    d, _, _ = sim
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    code, _, err = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", tmp_path / "c.urdf",
                                   "--report", fifo, "--params", "base"])
    assert_refused(code, err, "is not a regular file")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and not (tmp_path / "c.urdf").exists()
    target = tmp_path / "real.json"
    target.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    code, _, _ = run_cli(capfd, ["calibrate", URDF, d / "cal.csv", "-o", tmp_path / "c.urdf",
                                 "--report", link, "--params", "base"])
    assert code == 0 and link.is_symlink() and target.read_text().startswith("{")


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_while_importing_ends_with_one_line(signum, code, sim, out):
    """A signal during the command's start-up (numpy and Pinocchio still importing): the entry
    point's handlers give the same one line and 128 + signal, nothing written."""
    d, _, _ = sim
    before = snapshot(out)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # the entry point with calib.cli.main's import slowed down, so that the signal surely lands in it
    code_text = ("import sys, time, calib._entry as e\n"
                 "class Slow:\n"
                 "    def find_spec(self, name, path=None, target=None):\n"
                 "        if name == 'calib.cli.main':\n"
                 "            print('importing', file=sys.stderr, flush=True); time.sleep(3)\n"
                 "sys.meta_path.insert(0, Slow())\n"
                 "e.main()\n")
    proc = subprocess.Popen([sys.executable, "-c", code_text, "calibrate", URDF, str(d / "cal.csv"), "-o",
                             str(out / "calibrated.urdf")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT, text=True)
    assert proc.stderr.readline() == "importing\n"
    proc.send_signal(signum)
    stdout, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert err == f"calib: interrupted by {signal.Signals(signum).name}\n"
    assert snapshot(out) == before
