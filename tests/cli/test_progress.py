"""Progress lines on a terminal, nothing elsewhere; ETAs never "nan"; -v logs the stages."""
from __future__ import annotations

import io
import math

import pytest

from calib.cli.main import main
from calib.cli.progress import Progress, format_eta, working
from conftest import BUNDLED_URDF, ROOT


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_line_and_eta():
    out = _Terminal()
    with Progress(4, "rows", stream=out, show_after=0.0) as p:
        assert "estimating..." in p.line()             # nothing done yet: no estimate, no nan
        p._last_draw = -math.inf
        p.update(1)
        assert "rows: 1/4 (25%)" in out.getvalue() and "left" in out.getvalue()
    assert out.getvalue().endswith("\n") and "nan" not in out.getvalue()
    assert format_eta(10.0, 5, 10) == "~10 s left"
    assert format_eta(600.0, 1, 2) == "~10.0 min left"
    assert format_eta(float("nan"), 1, 2) == format_eta(1.0, 0, 2) == "estimating..."


def test_nothing_drawn_when_not_a_terminal():
    out = io.StringIO()
    with Progress(4, "rows", stream=out, show_after=0.0) as p:
        p.update(4)
    with working("fit", stream=out):
        pass
    assert out.getvalue() == ""


def test_verbose_calibrate_logs_each_stage(capsys, tmp_path):
    meas = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    code = main(["-v", "calibrate", str(BUNDLED_URDF), str(meas), "-o", str(tmp_path / "c.urdf")])
    err = capsys.readouterr().err
    assert code == 0
    for fragment in (f"calib: reading {meas}...", f"calib: reading {meas}: done in ",
                     "calib: calibrating (search-lm)...", "calib: calibrating (search-lm): done in ",
                     "calib: the calibrated URDF will hold tool frame 'tool' in base frame 'meas'",
                     f"calib: wrote {tmp_path / 'c.urdf'}"):
        assert fragment in err, fragment


@pytest.mark.slow
def test_every_imported_package_is_declared():
    """Item 5 of issue 12: each third-party module calib imports comes from a distribution
    listed in pyproject.toml's dependencies."""
    import ast
    import re
    import sys
    import tomllib
    from importlib.metadata import packages_distributions

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    declared = {re.split(r"[<>=!~ \[]", d)[0].lower().replace("_", "-") for d in deps}
    dists = packages_distributions()
    imported = set()
    for path in (ROOT / "calib").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imported.add(node.module.split(".")[0])
    third_party = sorted(m for m in imported if m not in sys.stdlib_module_names and m != "calib")
    # (xacro: the ros extra's, imported only by the child process of calib.io.urdf.xacro_worker; rospkg
    # and rosbags, the extra's others, are imported by name through calib.io.urdf.packages.ros_extra)
    assert third_party == ["coal", "example_robot_data", "jinja2", "lxml", "matplotlib", "mpl_toolkits", "numpy",
                           "pinocchio", "scipy", "threadpoolctl", "xacro", "yaml"]
    declared |= {re.split(r"[<>=!~ \[]", d)[0].lower() for d in
                 tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["ros"]}
    # cmeel wheels (Pinocchio, example-robot-data) install their modules under cmeel.prefix,
    # which packages_distributions() does not map
    cmeel = {"pinocchio": ["pin"], "example_robot_data": ["example-robot-data"], "coal": ["coal"]}
    for module in third_party:
        names = {d.lower().replace("_", "-") for d in dists.get(module) or cmeel.get(module, [])}
        assert names & declared, (module, names)


def test_progress_flag_draws_fractions_off_a_terminal(capsys, tmp_path, monkeypatch):
    """--progress: the report stage of calibrate and the steps of select-poses draw their
    fraction done and time left on a captured (non-terminal) stderr; without it, nothing."""
    import calib.cli.progress

    monkeypatch.setattr(calib.cli.progress, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(calib.cli.progress, "REDRAW_S", 0.0)
    meas = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    argv = ["calibrate", str(BUNDLED_URDF), str(meas), "-o", str(tmp_path / "c.urdf"), "--report",
            str(tmp_path / "r.json")]
    assert main(argv + ["--progress"]) == 0
    err = capsys.readouterr().err.replace("\r", "\n")
    steps = [l for l in err.splitlines() if l.startswith("writing the report: ")]
    assert steps and steps[-1].endswith("2/2 (100%), 0 s elapsed, ~0 s left") and "1/2 (50%)" in steps[0]
    assert "nan" not in err
    assert main(argv) == 0 and "writing the report" not in capsys.readouterr().err
    assert main(["select-poses", str(BUNDLED_URDF), "-n", "20", "--candidates", "200", "-o",
                 str(tmp_path / "p.csv"), "--progress"]) == 0
    err = capsys.readouterr().err.replace("\r", "\n")
    lines = [l for l in err.splitlines() if l.startswith("selecting 20 of 200 candidate poses, step: ")]
    assert lines and "12/12 (100%)" in lines[-1] and "1/12 (8%)" in lines[0]


def test_calibrate_reports_its_stages_as_a_rising_fraction(bundled_robot):
    """calibrate(progress=): each stage's start with the fraction of the work before it, in
    order, rising to 1.0 at the end; a non-callable is refused up front."""
    import pytest

    import calib
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    m = simulate_measurements(true, bundled_robot.random_configurations(60, 2), rng=3)
    calls = []
    calib.calibrate(bundled_robot, m, progress=lambda f, s: calls.append((f, s)))
    stages = [s for _, s in calls]
    # the joint terms are not judged on 60 rows (too few per parameter): their share is skipped
    assert stages == ["joint terms", "prepare", "fit", "statistics", "cross-validation", "done"]
    fractions = [f for f, _ in calls]
    assert fractions[0] == 0.0 and fractions[1] == 0.0 and fractions[-1] == 1.0
    assert all(b > a for a, b in zip(fractions[1:], fractions[2:]))
    assert abs(fractions[2] - 0.05 / 0.55) < 1e-12          # prepare's share of what ran
    for bad in (3, "x", len, lambda f: None):      # (not callable, or not with (fraction, stage))
        with pytest.raises(calib.CalibError, match="progress must be None or a function"):
            calib.calibrate(bundled_robot, m, progress=bad)


def test_a_fraction_line_shows_the_stage_percentage_and_time_left():
    out = _Terminal()
    with working("calibrating (search-lm)", stream=out) as line:
        line.show_after = 0.0
        line.fraction(0.25, "fit")
    text = out.getvalue()
    assert "calibrating (search-lm): fit, 25%, " in text and "left" in text and "nan" not in text
